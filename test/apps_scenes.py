"""A tiny labelled SemanticKITTI folder from the analytic street scene, for the apps tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scenes import street_sequence

from ros2_mos.io.semantic_kitti import KITTI_TR, write_calib, write_label, write_poses, write_scan, write_times

MOVING_CAR = 252
BUILDING = 50


def write_street_sequence(root: Path, n_scans: int = 12, car_speed: float = 1.5, seed: int = 0) -> Path:
    """``root/velodyne``, ``labels`` (moving car 252, the rest 50), ``poses.txt`` + ``calib.txt``, ``times.txt``."""
    scans = street_sequence(n_scans, ego_speed=1.0, car_speed=car_speed, seed=seed)
    poses = []
    for i, (pts, rem, moving, pose) in enumerate(scans):
        write_scan(root / "velodyne" / f"{i:06d}.bin", pts, rem)
        write_label(root / "labels" / f"{i:06d}.label", np.where(moving == 1, MOVING_CAR, BUILDING))
        poses.append(pose)
    write_calib(root / "calib.txt", KITTI_TR)
    write_poses(root / "poses.txt", np.array(poses), KITTI_TR)
    write_times(root / "times.txt", 0.1 * np.arange(n_scans))
    return root
