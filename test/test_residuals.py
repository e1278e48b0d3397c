"""Residual images: zero for a static scene under known motion, the expected value for a moved box."""

import numpy as np
import pytest

from ros2_mos.core.config import ResidualConfig, SensorConfig
from ros2_mos.core.residuals import past_range_image, residual_image, residual_images, transform_points

SENSOR = SensorConfig("t", 32, 256, 10.0, -20.0, 0.0, 100.0)

# Every test here runs on the compiled kernels and on the numpy code (conftest.geometry_code).
pytestmark = pytest.mark.usefixtures("geometry_code")
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


def _one_point_image(point: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) xyz and mask of an image holding one point (at its own pixel)."""
    from ros2_mos.core.projection import pixel_index

    pix = pixel_index(np.array([point], np.float32), SENSOR)
    xyz = np.zeros((SENSOR.height, SENSOR.width, 3), np.float32)
    mask = np.zeros((SENSOR.height, SENSOR.width), bool)
    xyz[pix.v[0], pix.u[0]] = point
    mask[pix.v[0], pix.u[0]] = True
    return xyz, mask


def test_free_space_asks_the_past_rays_with_hand_computed_values():
    from ros2_mos.core.projection import pixel_index
    from ros2_mos.core.residuals import free_space_image

    # The sensor moved 2 m forward along x since the past scan; a point now 8 m ahead was 10 m ahead then.
    xyz, mask = _one_point_image((8.0, 0.0, 0.0))
    to_past = translation(2.0)  # current frame -> past frame
    pix = pixel_index(np.array([[10.0, 0.0, 0.0]], np.float32), SENSOR)
    for seen, expected in [(15.0, 0.5), (10.0, 0.0), (6.0, -0.4), (0.0, 0.0), (60.0, 0.0)]:
        past_range = np.zeros((SENSOR.height, SENSOR.width), np.float32)
        past_range[pix.v[0], pix.u[0]] = seen
        out = free_space_image(xyz, mask, past_range, to_past, SENSOR, WINDOW)
        # (15 − 10) / 10 = +0.5: the past ray passed through where the point stands now (it moved in);
        # 10: the past scan saw it there; 6: something hid it ((6 − 10) / 10); empty or beyond 50 m: no evidence.
        assert out[mask][0] == pytest.approx(expected, abs=1e-6), seen
        assert (out[~mask] == 0).all()


def test_free_space_is_silent_on_a_static_scene_and_where_the_past_scan_saw_another_side():
    from ros2_mos.core.projection import project
    from ros2_mos.core.residuals import free_space_images

    world = room()
    past_pose, current_pose = np.eye(4), translation(1.5, 0.5) @ _yaw(0.2)
    past_scan = transform_points(world, np.linalg.inv(past_pose))
    current = project(transform_points(world, np.linalg.inv(current_pose)), np.zeros(len(world), np.float32), SENSOR)
    own = past_range_image(past_scan, np.eye(4), np.eye(4), SENSOR)
    out = free_space_images(current.xyz, current.mask, current_pose, [(own, past_pose)], (1, 2), SENSOR, WINDOW)
    assert out.shape == (2, SENSOR.height, SENSOR.width)
    # Static walls: a past ray lands within a pixel's footprint of the point (a few % at grazing pixels).
    assert np.median(np.abs(out[0][current.mask])) < 0.01
    assert (out[1] == 0).all()  # no scan two back: zero


def test_free_space_sees_a_box_that_moved_in_but_not_one_the_past_scan_saw_from_behind():
    from ros2_mos.core.projection import project
    from ros2_mos.core.residuals import free_space_image

    wall = np.column_stack([np.full(4000, 20.0), np.random.default_rng(1).uniform(-8, 8, (4000, 2))])
    ys, zs = np.meshgrid(np.linspace(-1, 1, 40), np.linspace(-1, 1, 40))
    box = np.column_stack([np.full(ys.size, 10.0), ys.ravel(), zs.ravel()])
    current = project(np.vstack([wall, box]).astype(np.float32), np.zeros(len(wall) + len(box), np.float32), SENSOR)
    on_box = current.mask & (np.abs(current.range - 10.0) < 0.2)
    # Past scan of the empty room (the box moved in): the past rays reached the wall at ~20 m.
    empty = past_range_image(wall, np.eye(4), np.eye(4), SENSOR)
    moved_in = free_space_image(current.xyz, current.mask, empty, np.eye(4), SENSOR, WINDOW)
    assert np.median(moved_in[on_box]) == pytest.approx(1.0, abs=0.1)  # (20 − 10) / 10
    # Past scan that saw the box's far side (a closer surface along those rays, 9.5 m): hidden, not free.
    behind = past_range_image(np.vstack([wall, box - [0.5, 0, 0]]), np.eye(4), np.eye(4), SENSOR)
    hidden = free_space_image(current.xyz, current.mask, behind, np.eye(4), SENSOR, WINDOW)
    assert (hidden[on_box] <= 0).mean() > 0.95
