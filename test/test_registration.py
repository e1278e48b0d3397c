"""Scan-to-scan registration (core/registration.py): normals, the ICP sums, and poses recovered by hand.

Scans are made analytically: dense points on the surfaces of a room, moved into the sensor frame and projected
(the closest point wins each pixel, as for a real scan).
"""

import math

import numpy as np
import pytest

from ros2_mos.core import kernels
from ros2_mos.core.config import RegistrationConfig, SensorConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.projection import project
from ros2_mos.core.registration import (
    normal_planes,
    plane_icp_sums,
    refine_to_past,
    register_to_past,
    se3_exp,
)

SENSOR = SensorConfig("t", 32, 512, 10.0, -20.0, 0.0, 100.0)


def room(seed: int = 0, corridor: bool = False, n: int = 300000) -> np.ndarray:
    """World points on a floor, two long walls and (unless ``corridor``) end walls and pillars."""
    rng = np.random.default_rng(seed)
    parts = [np.stack([rng.uniform(-30, 30, n), rng.uniform(-8, 8, n), np.full(n, -1.7)], 1)]
    for y in (-8.0, 8.0):
        parts.append(np.stack([rng.uniform(-30, 30, n // 2), np.full(n // 2, y), rng.uniform(-1.7, 3, n // 2)], 1))
    if not corridor:
        for x in (-30.0, 30.0):
            parts.append(np.stack([np.full(n // 4, x), rng.uniform(-8, 8, n // 4), rng.uniform(-1.7, 3, n // 4)], 1))
        for cx, cy in [(6.0, 4.0), (-5.0, -3.0), (12.0, -5.0)]:  # square pillars, 1 m wide
            side = rng.integers(0, 4, n // 8)
            t = rng.uniform(-0.5, 0.5, n // 8)
            px = np.where(side < 2, cx + np.where(side == 0, -0.5, 0.5), cx + t)
            py = np.where(side < 2, cy + t, cy + np.where(side == 2, -0.5, 0.5))
            parts.append(np.stack([px, py, rng.uniform(-1.7, 3, n // 8)], 1))
    return np.concatenate(parts)


def pose(x: float, y: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    return se3_exp(np.array([x, y, 0.0, 0.0, 0.0, math.radians(yaw_deg)]))


def scan_at(world: np.ndarray, world_pose: np.ndarray):
    """The range image of the room seen from ``world_pose``."""
    inv = np.linalg.inv(world_pose)
    local = (world @ inv[:3, :3].T + inv[:3, 3]).astype(np.float32)
    local = local[np.linalg.norm(local, axis=1) > 0.5]
    return project(local, np.zeros(len(local), np.float32), SENSOR)


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = np.linalg.inv(a) @ b
    return float(np.linalg.norm(d[:3, 3])), math.degrees(math.acos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))


def test_normals_of_a_wall_point_at_the_wall_and_are_zero_where_there_is_no_plane(geometry_code):
    image = scan_at(room(), pose(0.0))
    normals = normal_planes(image.planes, image.range).reshape(3, SENSOR.height, SENSOR.width)
    length = np.linalg.norm(normals, axis=0)
    assert not normals[:, -1].any()  # no row below the last
    assert not normals[:, image.range == 0].any()
    np.testing.assert_allclose(length[length > 0], 1.0, atol=1e-6)
    # Column 0 looks backwards (-x) at the end wall x = -30: normal along x; a column looking left (+y, u = W/4)
    # and up (row 0, +10 deg) sees the wall y = 8: normal along y.
    assert abs(normals[0, 8, 0]) == pytest.approx(1.0, abs=1e-3)
    assert abs(normals[1, 0, SENSOR.width // 4]) == pytest.approx(1.0, abs=1e-3)


def scans_for_comparison(current_pose: np.ndarray, stride: int):
    """The current scan, the past one (at the origin), its normals and every ``stride``-th current pixel; fails
    where the compiled kernels are not in use (there is nothing to compare then)."""
    if not kernels.enabled():
        pytest.fail(kernels.status())
    world = room()
    current, past = scan_at(world, current_pose), scan_at(world, pose(0.0))
    points = np.flatnonzero(current.mask.reshape(-1))[::stride]
    return current, past, normal_planes(past.planes, past.range), points


def test_compiled_and_numpy_code_agree():
    current, past, normals, points = scans_for_comparison(pose(0.3, 0.1, 0.5), 3)
    with kernels.disabled():
        np.testing.assert_array_equal(normal_planes(past.planes, past.range), normals)
    guess = pose(0.25, 0.05, 0.3)
    got = plane_icp_sums(current.planes, points, guess, SENSOR, past.planes, normals, 0.3)
    with kernels.disabled():
        want = plane_icp_sums(current.planes, points, guess, SENSOR, past.planes, normals, 0.3)
    assert got[3] == want[3] > 1000
    np.testing.assert_allclose(got[0], want[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-9, atol=1e-9)
    assert got[2] == pytest.approx(want[2], rel=1e-9)


def test_compiled_gauss_newton_loop_matches_the_numpy_loop():
    current, past, normals, points = scans_for_comparison(pose(0.6, 0.1, 0.8), 4)
    start = pose(0.5, 0.15, 0.4)
    for iterations in (1, 3, 10):
        got = refine_to_past(start, current.planes, points, past.planes, normals, SENSOR, iterations, 0.3)
        with kernels.disabled():
            want = refine_to_past(start, current.planes, points, past.planes, normals, SENSOR, iterations, 0.3)
        assert got[1] and want[1]
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-9)


def test_a_wrong_relative_pose_is_corrected(geometry_code):
    world = room()
    past_pose, current_pose = pose(0.0), pose(0.8, 0.05, 1.0)
    current, past = scan_at(world, current_pose), scan_at(world, past_pose)
    truth = np.linalg.inv(past_pose) @ current_pose  # current frame -> past frame
    start = pose(-0.09, 0.04, -0.3) @ truth  # 10 cm and 0.3 deg off, like KISS-ICP at its worst
    points = np.flatnonzero(current.mask.reshape(-1))[::4]
    refined, taken = refine_to_past(start, current.planes, points, past.planes,
                                    normal_planes(past.planes, past.range), SENSOR, 10, 0.3)
    assert taken
    moved, turned = pose_error(refined, truth)
    assert moved < 0.01 and turned < 0.03, (moved, turned)
    assert pose_error(start, truth)[0] > 0.09


def test_a_corridor_keeps_the_unconstrained_direction_and_corrects_the_others(geometry_code):
    world = room(corridor=True)
    truth = pose(0.5)
    current, past = scan_at(world, truth), scan_at(world, pose(0.0))
    start = pose(0.07, 0.06) @ truth  # 7 cm along the corridor (nothing to see it), 6 cm across
    points = np.flatnonzero(current.mask.reshape(-1))[::4]
    refined, _ = refine_to_past(start, current.planes, points, past.planes, normal_planes(past.planes, past.range),
                                SENSOR, 10, 0.3)
    error = (np.linalg.inv(truth) @ refined)[:3, 3]
    assert abs(error[1]) < 0.01  # across: corrected
    assert abs(error[0] - 0.07) < 0.02  # along: stays about where the odometry put it, no runaway


def test_too_few_pairs_keep_the_odometry_pose(geometry_code):
    world = room()
    current, past = scan_at(world, pose(0.5)), scan_at(world, pose(0.0))
    start = pose(0.45)
    refined, taken = refine_to_past(start, current.planes, np.flatnonzero(current.mask.reshape(-1)), past.planes,
                                    np.zeros_like(past.planes), SENSOR, 5, 0.3)
    assert not taken and np.array_equal(refined, start)


def test_register_to_past_chains_the_previous_scan_and_refines_the_others(geometry_code):
    world = room()
    truths = [pose(0.0), pose(0.4, 0.0, 0.2), pose(0.8, 0.02, 0.4)]  # oldest first
    odometry = [truths[0], pose(0.35, 0.0, 0.2), pose(0.83, 0.0, 0.5)]  # centimetres and tenths of a degree off
    scans = [scan_at(world, p) for p in truths]
    past = [(scans[1].planes, normal_planes(scans[1].planes, scans[1].range), odometry[1], odometry[1]),
            (scans[0].planes, normal_planes(scans[0].planes, scans[0].range), odometry[0], odometry[0])]
    config = RegistrationConfig(iterations=10, other_iterations=3, point_stride=4)
    registered, to_past = register_to_past(odometry[2], scans[2].planes, scans[2].mask, past, SENSOR, config)
    for transform, k in zip(to_past, (1, 0)):
        truth = np.linalg.inv(truths[k]) @ truths[2]
        moved, turned = pose_error(transform, truth)
        assert moved < 0.015 and turned < 0.05, (k, moved, turned)
    # The registered pose continues the previous scan's registered one by the refined step.
    np.testing.assert_allclose(registered, odometry[1] @ to_past[0], atol=1e-12)


@pytest.mark.parametrize("bad", [{"iterations": -1}, {"point_stride": 0}, {"max_error": float("nan")},
                                 {"max_error": 0.0}, {"other_iterations": 51}, {"max_error": float("inf")}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ConfigError):
        RegistrationConfig(**bad)
