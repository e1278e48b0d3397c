"""ErrorBreakdown: per-mover recall, range and speed, and false positives by range and class, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros2_mos.core.errors import DatasetError
from ros2_mos.scoring.breakdown import ErrorBreakdown, _median_speed

CAR, PERSON, ROAD, PARKED, UNLABELED = 252, 254, 40, 10, 0


def raw(semantic: int, instance: int = 0) -> int:
    return semantic | (instance << 16)


def translation(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def car_scan(centre_x: float) -> np.ndarray:
    """Four points of a car around (centre_x, 0, 0)."""
    return np.array([[centre_x - 1, 0, 0], [centre_x + 1, 0, 0], [centre_x, 1, 0], [centre_x, -1, 0]], np.float32)


def test_a_mover_s_recall_range_and_world_speed():
    """Car 7 moves 1 m in 0.5 s in the world (2 m/s) while the ego moves 1 m too: in the sensor frame it stands
    still at 10 m, so only the poses give its speed. 3 of 4 points found, then 1 of 4: recall 4 / 8."""
    b = ErrorBreakdown()
    labels = np.full(4, raw(CAR, 7), np.uint32)
    b.update("s", car_scan(10.0), labels, [1, 1, 1, 0], translation(0.0), 0.0)
    b.update("s", car_scan(10.0), labels, [0, 0, 1, 0], translation(1.0), 0.5)
    (car,) = b.movers()
    assert (car.sequence, car.instance, car.label, car.scans, car.points, car.found) == ("s", 7, "moving-car", 2, 8, 4)
    assert car.recall == 0.5 and car.missed == 4
    assert car.median_range == pytest.approx(10.0)
    assert car.speed == pytest.approx(2.0)


def test_movers_are_listed_most_missed_first_and_keyed_by_sequence_instance_and_class():
    b = ErrorBreakdown()
    points = np.array([[5, 0, 0], [5, 0.1, 0], [30, 0, 0], [30, 0.1, 0], [30, 0.2, 0]], np.float32)
    labels = np.array([raw(PERSON, 1), raw(PERSON, 1), raw(CAR, 2), raw(CAR, 2), raw(CAR, 2)], np.uint32)
    b.update("a", points, labels, [0, 0, 1, 0, 0], None, 0.0)
    b.update("b", points, labels, [0, 0, 1, 1, 1], None, 0.0)
    names = [(m.sequence, m.instance, m.missed) for m in b.movers()]
    assert names == [("a", 1, 2), ("a", 2, 2), ("b", 1, 2), ("b", 2, 0)]  # ties: by sequence, then instance
    assert all(math.isnan(m.speed) for m in b.movers())  # no poses, no speeds


def test_range_bands_and_false_positives_by_class_count_what_the_benchmark_counts():
    """Ranges 5, 15, 25 and 50 m fall in the four default bands; unlabeled points count for nothing."""
    b = ErrorBreakdown()
    points = np.array([[5, 0, 0], [0, 15, 0], [25, 0, 0], [0, 0, 50], [25, 0, 0], [5, 0, 0], [50, 0, 0]], np.float32)
    labels = np.array([raw(CAR, 1), raw(CAR, 1), raw(PERSON, 2), raw(PERSON, 3), raw(ROAD), raw(PARKED, 9),
                       raw(UNLABELED)], np.uint32)
    predicted = np.array([1, 0, 0, 1, 1, 1, 1])
    b.update("s", points, labels, predicted, None, 0.0)
    bands = [(band.name, band.moving, band.found, band.false_positives) for band in b.by_range()]
    assert bands == [("0-10 m", 1, 1, 1), ("10-20 m", 1, 0, 0), ("20-40 m", 1, 0, 1), (">= 40 m", 1, 1, 0)]
    assert b.by_range()[2].recall == 0.0
    assert b.false_positives_by_class() == [(PARKED, 1), (ROAD, 1)]
    assert b.scans == 1


def test_a_band_without_movers_has_no_recall():
    b = ErrorBreakdown(bands=(0.0, 100.0))
    b.update("s", np.array([[1, 0, 0]], np.float32), np.array([raw(ROAD)], np.uint32), [0], None, 0.0)
    assert math.isnan(b.by_range()[0].recall) and b.movers() == []


def test_speed_takes_pairs_half_a_second_apart_and_skips_long_gaps():
    # 1 m/s for the first second, then a 5 s gap (occluded) and a 100 m jump that no pair spans.
    times = [0.0, 0.25, 0.5, 0.75, 1.0, 6.0]
    centroids = [np.array([t, 0.0, 0.0]) for t in times[:5]] + [np.array([100.0, 0.0, 0.0])]
    assert _median_speed(times, centroids) == pytest.approx(1.0)
    assert math.isnan(_median_speed([0.0, 0.1], [np.zeros(3), np.ones(3)]))  # never 0.5 s apart
    assert math.isnan(_median_speed([0.0], [np.zeros(3)]))


@pytest.mark.parametrize("bad", [(), (1.0, 2.0), (0.0, 5.0, 5.0), (0.0, float("nan")), (0.0, float("inf"))])
def test_bad_range_bands_are_refused(bad):
    with pytest.raises(ValueError, match="range bands"):
        ErrorBreakdown(bands=bad)


def test_mismatched_or_bad_scans_are_refused_with_a_clear_error():
    b = ErrorBreakdown()
    pts = car_scan(10.0)
    labels = np.full(4, raw(CAR, 1), np.uint32)
    with pytest.raises(DatasetError, match="4 points, 4 labels and 3 predictions"):
        b.update("s", pts, labels, [1, 0, 1], None, 0.0)
    with pytest.raises(DatasetError, match="4 x 4"):
        b.update("s", pts, labels, [1, 0, 1, 0], np.eye(3), 0.0)
    with pytest.raises(DatasetError, match="not finite"):
        b.update("s", pts, labels, [1, 0, 1, 0], None, float("nan"))
    assert b.scans == 0


def test_points_with_a_non_finite_coordinate_are_left_out():
    b = ErrorBreakdown()
    points = np.array([[10, 0, 0], [np.nan, 0, 0], [0, np.inf, 0]], np.float32)
    labels = np.full(3, raw(CAR, 4), np.uint32)
    b.update("s", points, labels, [1, 1, 1], None, 0.0)
    (car,) = b.movers()
    assert (car.points, car.found, car.median_range) == (1, 1, 10.0)
    assert [band.moving for band in b.by_range()] == [0, 1, 0, 0]  # 10 m opens the 10-20 m band
