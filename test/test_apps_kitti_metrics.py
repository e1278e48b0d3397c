"""KITTI odometry metrics against hand-made trajectories with a known drift, and a loop port of the devkit."""

import math

import numpy as np
import pytest

from ros2_mos.apps.kitti_metrics import (
    ate_rmse,
    evaluate_trajectory,
    last_frames,
    segment_errors,
    to_camera_frame,
    trajectory_distances,
    umeyama,
)
from ros2_mos.core.errors import DatasetError
from ros2_mos.io.semantic_kitti import KITTI_TR


def straight(n: int, step: float, scale: float = 1.0) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = scale * step * np.arange(n)
    return poses


def rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def integrate(steps: list[np.ndarray]) -> np.ndarray:
    poses = [np.eye(4)]
    for d in steps:
        poses.append(poses[-1] @ d)
    return np.array(poses)


def devkit_reference(gt, est, lengths=(100, 200, 300, 400, 500, 600, 700, 800), step=10):
    """evaluate_odometry.cpp's calcSequenceErrors, loop for loop."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[i, :3, 3] - gt[i - 1, :3, 3])))
    t_errs, r_errs = [], []
    for first in range(0, len(gt), step):
        for length in lengths:
            last = -1
            for i in range(first, len(dist)):
                if dist[i] > dist[first] + length:
                    last = i
                    break
            if last == -1:
                continue
            dg = np.linalg.inv(gt[first]) @ gt[last]
            de = np.linalg.inv(est[first]) @ est[last]
            e = np.linalg.inv(de) @ dg
            d = 0.5 * (e[0, 0] + e[1, 1] + e[2, 2] - 1.0)
            r_errs.append(math.acos(max(min(d, 1.0), -1.0)) / length)
            t_errs.append(float(np.linalg.norm(e[:3, 3])) / length)
    return 100 * np.mean(t_errs), np.degrees(np.mean(r_errs)) * 100, len(t_errs)


def test_one_percent_scale_drift_on_a_straight_1000m_path_is_one_percent():
    gt = straight(10001, 0.1)  # 1000 m at 0.1 m per frame
    res = evaluate_trajectory(gt, straight(10001, 0.1, scale=1.01))
    # The devkit's last frame is the first one *past* the segment length, so each segment
    # overshoots by less than one step (0.1 m): the error is 1 % to within 0.1 m / 100 m * 1 %.
    assert res.translation_pct == pytest.approx(1.0, abs=1e-3)
    assert res.rotation_deg_per_100m == pytest.approx(0.0, abs=1e-9)
    assert res.path_length == pytest.approx(1000.0)


def test_scale_drift_matches_the_devkit_overshoot_exactly():
    seg = segment_errors(straight(1001, 1.0), straight(1001, 1.0, scale=1.02))
    # With 1 m steps every segment of length L spans L + 1 m: error 0.02 (L + 1) / L.
    np.testing.assert_allclose(seg.t_err, 0.02 * (seg.length + 1) / seg.length, rtol=1e-9)
    # Segments: first frames 0, 10, ... whose segment fits: L = 100 has firsts 0..890 -> 90 of them.
    assert np.count_nonzero(seg.length == 100) == 90 and np.count_nonzero(seg.length == 800) == 20


def test_constant_yaw_drift_gives_the_known_degrees_per_100m():
    kappa = math.radians(1.0) / 100.0  # 1 deg per 100 m of heading drift
    step = 0.1
    move = np.eye(4)
    move[0, 3] = step
    gt = integrate([move] * 9000)
    est = integrate([move @ rz(kappa * step)] * 9000)
    res = evaluate_trajectory(gt, est)
    assert res.rotation_deg_per_100m == pytest.approx(1.0, rel=1e-3)
    # The estimate drives a polygon turning by kappa * step after every step: over a segment of
    # n steps its end is step * sum_j (cos j d, sin j d), while the ground truth ends at (n step, 0).
    seg = res.segments
    dist = trajectory_distances(gt)
    n = np.array([last_frames(dist, np.array([f]), length)[0] - f for f, length in zip(seg.first_frame, seg.length)])
    assert ((n * step > seg.length - 1e-6) & (n * step <= seg.length + 2 * step)).all()
    end = np.array([step * np.exp(1j * kappa * step * np.arange(k)).sum() for k in n])
    expected = np.abs(end - n * step) / seg.length
    np.testing.assert_allclose(seg.t_err, expected, rtol=1e-6)


def test_vectorised_segments_match_a_loop_port_of_the_devkit():
    rng = np.random.default_rng(3)
    steps_gt, steps_est = [], []
    for _ in range(1500):
        d = rz(rng.normal(0, 0.01))
        d[:3, 3] = [rng.uniform(0.3, 1.2), rng.normal(0, 0.05), rng.normal(0, 0.01)]
        noise = rz(rng.normal(0, 0.002))
        noise[:3, 3] = rng.normal(0, 0.01, 3)
        steps_gt.append(d)
        steps_est.append(d @ noise)
    gt, est = integrate(steps_gt), integrate(steps_est)
    t_ref, r_ref, n_ref = devkit_reference(gt, est)
    seg = segment_errors(gt, est)
    assert len(seg) == n_ref
    assert seg.translation_pct == pytest.approx(t_ref, rel=1e-9)
    assert seg.rotation_deg_per_100m == pytest.approx(r_ref, rel=1e-9)


def test_a_perfect_trajectory_in_another_world_frame_has_no_error():
    rng = np.random.default_rng(0)
    gt = integrate([rz(0.01) @ straight(2, 1.0)[1] for _ in range(1200)])
    offset = rz(1.0)
    offset[:3, 3] = rng.normal(0, 10, 3)
    res = evaluate_trajectory(gt, offset @ gt)
    assert res.translation_pct == pytest.approx(0.0, abs=1e-9)
    assert res.rotation_deg_per_100m == pytest.approx(0.0, abs=1e-6)
    assert res.ate_rmse == pytest.approx(0.0, abs=1e-6)
    assert ate_rmse(gt, offset @ gt, "first") == pytest.approx(0.0, abs=1e-6)
    assert ate_rmse(gt, offset @ gt, "none") > 1.0


def test_short_trajectories_have_no_segment_and_report_nan():
    res = evaluate_trajectory(straight(500, 0.1), straight(500, 0.1, 1.1))
    assert res.n_segments == 0 and math.isnan(res.translation_pct)
    short = segment_errors(straight(500, 0.1), straight(500, 0.1, 1.1), lengths=(10.0, 20.0))
    assert short.translation_pct == pytest.approx(10.0, rel=2e-2)


def test_last_frame_is_the_first_past_the_length_and_minus_one_past_the_end():
    dist = trajectory_distances(straight(11, 1.0))
    np.testing.assert_array_equal(last_frames(dist, np.array([0, 3, 9]), 5.0), [6, 9, -1])


def test_umeyama_recovers_a_rigid_motion_and_ate_measures_noise():
    rng = np.random.default_rng(1)
    src = rng.normal(0, 5, (200, 3))
    true = rz(0.7)
    true[:3, 3] = [3, -2, 1]
    rot, t, s = umeyama(src, src @ true[:3, :3].T + true[:3, 3])
    np.testing.assert_allclose(rot, true[:3, :3], atol=1e-9)
    np.testing.assert_allclose(t, true[:3, 3], atol=1e-9)
    assert s == 1.0
    gt = straight(1000, 1.0)
    est = gt.copy()
    est[:, 1, 3] += np.where(np.arange(1000) % 2, 0.5, -0.5)
    assert ate_rmse(gt, est) == pytest.approx(0.5, rel=1e-5)


def test_camera_frame_keeps_rotation_errors_and_inverts_the_dataset_convention():
    lidar = integrate([rz(0.02) @ straight(2, 1.0)[1] for _ in range(50)])
    cam = to_camera_frame(lidar, KITTI_TR)
    np.testing.assert_allclose(np.linalg.inv(KITTI_TR) @ cam @ KITTI_TR, lidar, atol=1e-9)


def test_mismatched_trajectories_are_refused():
    with pytest.raises(DatasetError, match="equal length"):
        evaluate_trajectory(straight(10, 1.0), straight(11, 1.0))
    with pytest.raises(DatasetError, match="alignment"):
        ate_rmse(straight(10, 1.0), straight(10, 1.0), "sim3")
