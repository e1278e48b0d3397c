"""Range projection: hand-computed pixels for known angles, edges, fov limits, closest-wins."""

import math

import numpy as np
import pytest

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import ScanError
from ros2_mos.core.postprocess import nearest_backproject
from ros2_mos.core.projection import (
    azimuth,
    closest_point_image,
    finite_mask,
    pixel_index,
    project,
    project_range,
)

# 10 rows of 1 degree each from +5 to -5 deg, 8 columns of 45 degrees.
SENSOR = SensorConfig("test", height=10, width=8, fov_up_deg=5.0, fov_down_deg=-5.0, min_range=0.0, max_range=100.0)

# Every test here runs on the compiled kernels and on the numpy code (conftest.geometry_code).
pytestmark = pytest.mark.usefixtures("geometry_code")


def at(azimuth_deg: float, elevation_deg: float, r: float = 10.0) -> list[float]:
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return [r * math.cos(e) * math.cos(a), r * math.cos(e) * math.sin(a), r * math.sin(e)]


@pytest.mark.parametrize(
    "azimuth, elevation, row, col",
    [
        (0.0, 0.0, 5, 4),  # straight ahead: u = ½·8 = 4, v = (1 − 5/10)·10 = 5
        (90.0, 0.0, 5, 2),  # left (+y): u = ½(1 − ½)·8 = 2
        (-90.0, 0.0, 5, 6),  # right (−y): u = ½(1 + ½)·8 = 6
        (180.0, 0.0, 5, 0),  # behind, yaw = +π: u = 0 (left image edge)
        (-179.999, 0.0, 5, 7),  # behind, yaw → −π: u → 8, clamped to the last column
        (0.0, 4.9, 0, 4),  # just under the top of the fov: row 0
        (0.0, -4.9, 9, 4),  # just above the bottom: last row
        (0.0, 2.5, 2, 4),  # v = (1 − 7.5/10)·10 = 2.5 -> 2
    ],
)
def test_known_angles_land_on_known_pixels(azimuth, elevation, row, col):
    pix = pixel_index(np.array([at(azimuth, elevation)]), SENSOR)
    assert (pix.v[0], pix.u[0]) == (row, col)
    assert pix.in_image[0]
    assert pix.range[0] == pytest.approx(10.0, rel=1e-6)


@pytest.mark.parametrize("elevation", [5.5, -5.5, 30.0, -60.0])
def test_points_outside_the_vertical_fov_are_left_out_of_the_image(elevation):
    image = project(np.array([at(0.0, elevation)]), np.array([0.5]), SENSOR)
    assert not image.pixels.in_image[0]
    assert not image.mask.any()
    # Their pixel index is clamped into the image so that labels can still reach them.
    assert 0 <= image.pixels.v[0] < SENSOR.height


def test_range_limits_leave_points_out():
    sensor = SensorConfig("t", 10, 8, 5.0, -5.0, min_range=2.0, max_range=50.0)
    pts = np.array([at(0, 0, 1.0), at(90, 0, 60.0), at(-90, 0, 10.0)])
    pix = pixel_index(pts, sensor)
    assert pix.in_image.tolist() == [False, False, True]


def test_closest_point_wins_its_pixel_whatever_the_input_order():
    far, near = at(-0.2, -0.2, 20.0), at(-0.1, -0.1, 5.0)
    for order in ([far, near], [near, far]):
        pts = np.array(order)
        image = project(pts, np.array([0.1, 0.9]), SENSOR)
        near_index = 0 if order[0] is near else 1
        assert image.range[5, 4] == pytest.approx(5.0, rel=1e-6)
        assert image.point_index[5, 4] == near_index
        assert image.remission[5, 4] == pytest.approx([0.1, 0.9][near_index])
        np.testing.assert_allclose(image.xyz[5, 4], pts[near_index], rtol=1e-6)
        assert image.mask.sum() == 1


def test_closest_point_image_holds_each_pixels_closest_point_and_minus_one_elsewhere():
    far, near, other = at(-0.2, -0.2, 20.0), at(-0.1, -0.1, 5.0), at(90.0, 2.5, 7.0)
    for order in ([far, near, other], [near, other, far]):
        image = closest_point_image(np.array(order), SENSOR)
        assert image.shape == (10, 8)
        assert image[5, 4] == order.index(near) and image[2, 2] == order.index(other)
        assert (image >= 0).sum() == 2


def test_project_range_equals_full_projection_range():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2000, 3)) * [10, 10, 0.3]
    full = project(pts, np.zeros(len(pts)), SENSOR)
    np.testing.assert_array_equal(project_range(pts, SENSOR), full.range)


def test_label_round_trip_points_to_pixels_to_points():
    rng = np.random.default_rng(1)
    sensor = SensorConfig("t", 16, 64, 15.0, -15.0, 0.0, 100.0)
    pts = rng.normal(size=(3000, 3)) * [10, 10, 1]
    image = project(pts, np.zeros(len(pts)), sensor)
    pixel_ids = np.arange(sensor.height * sensor.width, dtype=np.float32).reshape(sensor.height, sensor.width)
    back = nearest_backproject(pixel_ids, image.pixels)
    expected = image.pixels.v * sensor.width + image.pixels.u
    np.testing.assert_array_equal(back, expected)
    # Every pixel's own point gets back exactly the pixel it won.
    winners = image.point_index[image.mask]
    np.testing.assert_array_equal(back[winners], pixel_ids[image.mask])


def test_finite_mask_drops_nan_inf_and_zero_range():
    pts = np.array([[1, 2, 3], [np.nan, 0, 0], [np.inf, 1, 1], [0, 0, 0], [0, 0, -1]], dtype=np.float32)
    assert finite_mask(pts).tolist() == [True, False, False, False, True]


@pytest.mark.parametrize("bad", [np.zeros((5, 4)), np.zeros(3), np.zeros((2, 3), dtype=np.int32)])
def test_wrong_shapes_and_dtypes_raise_scan_error(bad):
    with pytest.raises(ScanError, match="points"):
        pixel_index(bad, SENSOR)


@pytest.mark.parametrize(
    "x, y, expected",
    [
        (1.0, 0.0, 0.0),
        (1.0, 1.0, math.pi / 4),  # the octant boundary |y| = |x|
        (0.0, 2.0, math.pi / 2),
        (-1.0, 1.0, 3 * math.pi / 4),
        (-1.0, 0.0, math.pi),  # +0 y: +π, as arctan2
        (-1.0, -0.0, -math.pi),  # -0 y: -π, as arctan2
        (-1.0, -1.0, -3 * math.pi / 4),
        (0.0, -3.0, -math.pi / 2),
        (2.0, -1.0, math.atan2(-1.0, 2.0)),
        (1e-30, 1e-30, math.pi / 4),  # tiny but non-zero coordinates
        (0.0, 0.0, 0.0),  # the origin (never projected): 0, not NaN
    ],
)
def test_azimuth_matches_atan2_by_hand(x, y, expected):
    got = azimuth(np.array([x], np.float32), np.array([y], np.float32))[0]
    assert got == pytest.approx(expected, abs=2e-7)
    assert math.copysign(1.0, got) == math.copysign(1.0, expected)


def test_azimuth_is_as_accurate_as_float32_arctan2():
    rng = np.random.default_rng(0)
    xy = (rng.normal(size=(2, 200_000)) * rng.choice([1e-3, 1.0, 80.0], size=(1, 200_000))).astype(np.float32)
    exact = np.arctan2(xy[1].astype(np.float64), xy[0].astype(np.float64))
    float32_error = np.abs(np.arctan2(xy[1], xy[0]) - exact).max()  # ~1.2e-7: rounding to float32 near ±π
    # A pixel of a 2048-column image is 3e-3 rad wide: 4e-7 rad moves one point in ~10^4 by a column at most.
    assert np.abs(azimuth(xy[0], xy[1]) - exact).max() <= float32_error + 2.5e-7


def test_pixels_agree_with_the_reference_formula_on_a_dense_scan():
    """The fast trigonometry must put (almost) every point on the pixel eq. 1 gives in float64."""
    rng = np.random.default_rng(1)
    n = 100_000
    az = rng.uniform(-np.pi, np.pi, n)
    el = np.radians(rng.uniform(-6.0, 6.0, n))
    r = rng.uniform(1.0, 80.0, n)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1).astype(np.float32)
    p64 = pts.astype(np.float64)
    rr = np.linalg.norm(p64, axis=1)
    u_ref = np.clip(np.floor(0.5 * (1 - np.arctan2(p64[:, 1], p64[:, 0]) / np.pi) * SENSOR.width), 0, SENSOR.width - 1)
    v_ref = np.floor((1 - (np.arcsin(p64[:, 2] / rr) - SENSOR.fov_down) / SENSOR.fov) * SENSOR.height)
    inside = (v_ref >= 0) & (v_ref < SENSOR.height)
    pix = pixel_index(pts, SENSOR)
    assert (pix.in_image == inside).mean() > 0.9999
    assert (pix.u == u_ref).mean() > 0.9999
    assert (pix.v[inside] == v_ref[inside]).mean() > 0.9999
