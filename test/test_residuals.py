"""Residual images: zero for a static scene under known motion, the expected value for a moved box."""

import numpy as np
import pytest

from ros2_mos.core.config import ResidualConfig, SensorConfig
from ros2_mos.core.residuals import past_range_image, residual_image, residual_images, transform_points

SENSOR = SensorConfig("t", 32, 256, 10.0, -20.0, 0.0, 100.0)
WINDOW = ResidualConfig(2.0, 50.0)


def translation(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = [x, y, z]
    return t


def room(size: float = 20.0, n: int = 60000, seed: int = 0) -> np.ndarray:
    """Points on the walls, floor and ceiling of a box room centred at the origin."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-size, size, size=(n, 3))
    axis = rng.integers(0, 3, n)
    side = rng.choice([-size, size], n)
    pts[np.arange(n), axis] = side
    pts[:, 2] = np.where(axis == 2, np.where(side > 0, 3.0, -1.7), np.clip(pts[:, 2], -1.7, 3.0))
    return pts


def test_static_scene_under_a_known_rigid_motion_has_zero_residual():
    world = room()
    past_pose = np.eye(4)
    current_pose = translation(1.0, 0.5) @ _yaw(0.1)
    past_scan = transform_points(world, np.linalg.inv(past_pose))
    current_scan = transform_points(world, np.linalg.inv(current_pose))
    current_range = past_range_image(current_scan, np.eye(4), np.eye(4), SENSOR)
    res = residual_images(current_range, current_pose, [(past_scan, past_pose)], 1, SENSOR, WINDOW)
    valid = res[0] > 0
    assert np.median(res[0][current_range > 0]) < 1e-5
    assert res.max() < 1e-4, f"{valid.sum()} pixels with residual up to {res.max()}"


def test_box_moved_away_by_one_metre_gives_the_hand_computed_residual():
    # A wall patch straight ahead at x = 10 in the past scan and at x = 11 now; the sensor stands still.
    ys, zs = np.meshgrid(np.linspace(-1, 1, 80), np.linspace(-1, 1, 80))
    patch = np.column_stack([np.zeros(ys.size), ys.ravel(), zs.ravel()])
    past = patch + [10.0, 0, 0]
    current = patch + [11.0, 0, 0]
    current_range = past_range_image(current, np.eye(4), np.eye(4), SENSOR)
    res = residual_images(current_range, np.eye(4), [(past, np.eye(4))], 1, SENSOR, WINDOW)[0]
    both = (current_range > 0) & (past_range_image(past, np.eye(4), np.eye(4), SENSOR) > 0)
    # At the centre pixel the ranges are ~11 and ~10: |11 − 10| / 11, normalised by the *current* range.
    centre = np.unravel_index(np.argmin(np.where(both, current_range, np.inf)), current_range.shape)
    assert current_range[centre] == pytest.approx(11.0, abs=0.02)
    assert res[centre] == pytest.approx(1.0 / 11.0, abs=0.003)
    assert res[both].min() > 0.07 and res[both].max() < 0.11
    assert (res[~both] == 0).all()


def test_residual_uses_current_range_and_window():
    current = np.array([[10.0, 1.0, 10.0, 60.0]], np.float32)
    past = np.array([[5.0, 1.5, 0.0, 40.0]], np.float32)
    out = residual_image(current, past, WINDOW)
    # |10 − 5| / 10; below 2 m: 0; past empty: 0; current beyond 50 m: 0.
    np.testing.assert_allclose(out, [[0.5, 0.0, 0.0, 0.0]])


def test_signed_residual_says_which_way_the_range_changed():
    current = np.array([[10.0, 10.0, 1.0, 10.0]], np.float32)
    past = np.array([[15.0, 5.0, 1.5, 0.0]], np.float32)
    # (15 − 10) / 10 = +0.5: the past ray went farther (free space now occupied); (5 − 10) / 10 = −0.5.
    np.testing.assert_allclose(residual_image(current, past, WINDOW, signed=True), [[0.5, -0.5, 0.0, 0.0]])
    np.testing.assert_allclose(residual_image(current, past, WINDOW), [[0.5, 0.5, 0.0, 0.0]])


def test_offsets_pick_the_past_scans_and_leave_missing_ones_zero():
    """Residual k compares with the scan offsets[k] back; scans not yet seen give zero channels."""
    current = np.full((SENSOR.height, SENSOR.width), 10.0, np.float32)
    walls = [(room(n=20000, seed=s) * f, np.eye(4)) for s, f in ((1, 0.5), (2, 0.6), (3, 0.7), (4, 0.8))]
    expected = {o: residual_image(current, past_range_image(walls[o - 1][0], np.eye(4), np.eye(4), SENSOR), WINDOW,
                                  signed=True) for o in (1, 2, 4)}
    res = residual_images(current, np.eye(4), walls, 3, SENSOR, WINDOW, offsets=(1, 2, 4), signed=True)
    for k, o in enumerate((1, 2, 4)):
        np.testing.assert_array_equal(res[k], expected[o])
    short = residual_images(current, np.eye(4), walls[:3], 3, SENSOR, WINDOW, offsets=(1, 2, 4), signed=True)
    np.testing.assert_array_equal(short[:2], res[:2])
    assert not short[2].any()  # 4 scans back does not exist yet
    with pytest.raises(ValueError):
        residual_images(current, np.eye(4), walls, 3, SENSOR, WINDOW, offsets=(1, 2))


def test_missing_past_scans_give_zero_channels():
    current_range = np.full((SENSOR.height, SENSOR.width), 10.0, np.float32)
    res = residual_images(current_range, np.eye(4), [], 3, SENSOR, WINDOW)
    assert res.shape == (3, SENSOR.height, SENSOR.width)
    assert not res.any()


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    return t
