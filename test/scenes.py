"""Small synthetic scenes for core tests: a walled street with a box that moves.

The simulator (``ros2_mos.sim``) makes realistic sequences; these scenes are
tiny, analytic and instant, so the math tests need no ray casting.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.io.semantic_kitti import write_calib, write_label, write_poses, write_scan, write_times


def yaw_pose(x: float, y: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = [x, y]
    return t


def street_world(seed: int = 0, n: int = 40000) -> np.ndarray:
    """World points: ground, two facades with recesses, and poles, so ICP has structure."""
    rng = np.random.default_rng(seed)
    k = n // 4
    ground = np.column_stack([rng.uniform(-40, 80, k), rng.uniform(-12, 12, k), np.full(k, -1.7)])
    xs = rng.uniform(-40, 80, k)
    left = np.column_stack([xs, 12.0 + 2.0 * (np.floor(xs / 7) % 2), rng.uniform(-1.7, 8, k)])
    xs = rng.uniform(-40, 80, k)
    right = np.column_stack([xs, -12.0 - 3.0 * (np.floor(xs / 11) % 2), rng.uniform(-1.7, 8, k)])
    m = n - 3 * k
    pole_x = rng.choice(np.arange(-35, 80, 9.0), m)
    ang = rng.uniform(0, 2 * np.pi, m)
    poles = np.column_stack([pole_x + 0.2 * np.cos(ang), 9.0 + 0.2 * np.sin(ang), rng.uniform(-1.7, 4, m)])
    return np.vstack([ground, left, right, poles])


def box_points(centre: np.ndarray, size=(4.0, 1.8, 1.5), n: int = 3000, seed: int = 0) -> np.ndarray:
    """Points on the surface of an axis-aligned box standing on the ground."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.5, 0.5, size=(n, 3))
    axis = rng.integers(0, 3, n)
    pts[np.arange(n), axis] = rng.choice([-0.5, 0.5], n)
    pts *= size
    pts[:, 2] += size[2] / 2 - 1.7
    return pts + np.asarray(centre)


def visible(points_sensor: np.ndarray, max_range: float = 60.0) -> np.ndarray:
    r = np.linalg.norm(points_sensor, axis=1)
    return (r > 1.0) & (r < max_range)


def street_sequence(n_scans: int = 6, ego_speed: float = 1.0, car_speed: float = 1.5, seed: int = 0):
    """(points in sensor frame, remission, moving gt 0/1, world pose) per scan, 10 Hz.

    The ego drives along +x; a car drives along +x at 5 m lateral offset faster than the ego.
    """
    world = street_world(seed)
    scans = []
    for i in range(n_scans):
        pose = yaw_pose(ego_speed * i, 0.0, 0.0)
        car = box_points(np.array([8.0 + car_speed * i, 5.0, 0.0]), seed=seed + 1)
        pts_world = np.vstack([world, car])
        moving = np.r_[np.zeros(len(world), np.uint8), np.ones(len(car), np.uint8)]
        inv = np.linalg.inv(pose)
        pts = pts_world @ inv[:3, :3].T + inv[:3, 3]
        keep = visible(pts)
        rem = np.where(moving[keep] == 1, 0.8, 0.3).astype(np.float32)
        scans.append((pts[keep].astype(np.float32), rem, moving[keep], pose))
    return scans


def write_sequence(root, name: str, n_scans: int = 5, seed: int = 0):
    """A SemanticKITTI sequence folder of :func:`street_sequence` (moving box 252, the rest 40)."""
    seq = root / "sequences" / name
    poses = []
    for i, (pts, rem, moving, pose) in enumerate(street_sequence(n_scans, seed=seed)):
        write_scan(seq / "velodyne" / f"{i:06d}.bin", pts, rem)
        write_label(seq / "labels" / f"{i:06d}.label", np.where(moving == 1, 252, 40).astype(np.uint32))
        poses.append(pose)
    write_calib(seq / "calib.txt")
    write_poses(seq / "poses.txt", np.asarray(poses))
    write_times(seq / "times.txt", np.arange(n_scans) * 0.1)
    return seq
