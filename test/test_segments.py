"""Segment consistency by hand: a partly moving car fills, a wall with one moving pixel and the ground do not."""

import numpy as np
import pytest

from ros2_mos.core.config import PostprocessConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.segments import _tenth_percentile, connected_regions, drop_small_regions, fill_segments, ground_mask


def scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = 8, 64
    rng = np.full((h, w), 30.0, np.float32)  # a wall at 30 m
    z = np.full((h, w), 1.0, np.float32)
    rng[6:], z[6:] = 8.0, -1.7  # two ground rows (low z)
    rng[2:6, 10:20] = 10.0  # a car at 10 m: 4 x 10 pixels, its own segment (range jump 20 m)
    z[2:6, 10:20] = -0.8
    prob = np.zeros((h, w), np.float32)
    prob[2:6, 10:13] = 0.9  # its front edge is moving: 12 of 40 pixels
    prob[0, 40] = 0.95  # one pixel of the wall
    prob[7, 50] = 0.9  # one ground pixel
    return prob, rng, z


def test_a_segment_mostly_enough_moving_is_filled_and_nothing_else_changes():
    prob, rng, z = scene()
    out = fill_segments(prob, rng, z, threshold=0.5, fill_fraction=0.25)
    assert (out[2:6, 10:20] >= 0.5).all()  # 30 % of the car moved: all of it is labelled moving
    np.testing.assert_array_equal(out[2:6, 10:13], prob[2:6, 10:13])  # probabilities above the threshold are kept
    changed = out != prob
    changed[2:6, 10:20] = False
    assert not changed.any()  # the wall (1 of ~400 pixels) and the ground pixel stay as they were
    assert not (fill_segments(prob, rng, z, 0.5, 0.35)[2:6, 13:20] >= 0.5).any()  # 30 % < 35 %: no fill
    assert fill_segments(np.zeros_like(prob), rng, z, 0.5, 0.25) is not None


def test_segments_join_across_the_azimuth_seam_and_split_at_range_jumps():
    rng = np.zeros((2, 8), np.float32)
    rng[0, [0, 7]] = 10.0
    rng[0, 3] = 10.0
    rng[1, 3] = 20.0
    lab = connected_regions(rng > 0, rng, rel=0.05)
    assert lab[0, 0] == lab[0, 7]  # column 0 and 7 are neighbours on a 360-degree image
    assert lab[0, 3] != lab[1, 3] and lab[0, 3] != lab[0, 0]


def test_segment_fill_is_checked():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ConfigError):
            PostprocessConfig(segment_fill=bad)


def test_small_moving_regions_are_dropped_and_objects_kept():
    prob, rng, z = scene()
    prob[2:6, 10:20] = 0.9  # the whole car moving: 40 pixels
    prob[0, 40:42] = 0.8  # a 2-pixel speck on the wall
    out = drop_small_regions(prob, rng, threshold=0.5, min_pixels=30)
    assert (out[2:6, 10:20] == 0.9).all()  # 40 >= 30: kept as it was
    assert (out[0, 40:42] == 0).all() and out[7, 50] == 0  # the specks (2 and 1 pixels) are gone
    unchanged = np.ones_like(prob, bool)
    unchanged[0, 40:42] = unchanged[7, 50] = False
    np.testing.assert_array_equal(out[unchanged], prob[unchanged])
    assert drop_small_regions(prob, rng, 0.5, 41)[2:6, 10:20].max() == 0  # 40 < 41: the car goes too
    assert drop_small_regions(prob, rng, 0.5, 0) is prob  # 0 = off


def test_moving_pixels_across_a_range_jump_are_separate_regions():
    rng = np.full((4, 16), 10.0, np.float32)
    rng[:, 8:] = 30.0  # two surfaces side by side, 20 m apart
    prob = np.zeros_like(rng)
    prob[:, 6:10] = 0.9  # 8 moving pixels on each: one region of 16 without the range test
    out = drop_small_regions(prob, rng, 0.5, 10)
    assert out.max() == 0  # each side alone is 8 < 10 pixels
    assert drop_small_regions(prob, rng, 0.5, 8).max() == np.float32(0.9)


def test_min_region_pixels_is_checked():
    for bad in (-1, 10001, 2.5, float("nan"), True):
        with pytest.raises(ConfigError):
            PostprocessConfig(min_region_pixels=bad)


def test_the_ground_is_below_the_tenth_percentile_of_near_z_plus_the_margin():
    assert _tenth_percentile(np.arange(11, dtype=np.float32)) == 1.0  # hand: position 0.1 * 10 = 1
    assert _tenth_percentile(np.array([4.0, 0.0, 2.0], np.float32)) == pytest.approx(0.4)  # 0 + (2 - 0) * 0.2
    values = np.random.default_rng(0).normal(size=1001).astype(np.float32)
    assert _tenth_percentile(values) == pytest.approx(float(np.percentile(values, 10)), abs=1e-6)
    _, rng, z = scene()
    ground = ground_mask(rng, z)
    assert ground[6:].all() and not ground[:6].any()  # z -1.7 (10th percentile of the near pixels) + 0.3
    assert not ground_mask(np.full((2, 2), 30.0, np.float32), np.zeros((2, 2), np.float32)).any()  # none near
