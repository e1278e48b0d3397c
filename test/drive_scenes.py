"""Hand-made drives for the offline labeller: a flat street, walls, and boxes that move as a test says.

Each scene is ray cast with the simulator's LiDAR (a small 32 x 720 sensor, no noise) and written as a
SemanticKITTI sequence with poses and labels in both conventions (``labels/``: SemanticKITTI's, an object that
moves at any scan is moving in every scan; ``labels_instant/``: moving in the scans where it moved since the last).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.io.conventions import write_convention_file
from ros2_mos.io.semantic_kitti import write_calib, write_label, write_poses, write_scan, write_times
from ros2_mos.sim.geometry import TriangleSoup, box, quad
from ros2_mos.sim.lidar import Lidar
from ros2_mos.sim.presets import SensorEffects
from ros2_mos.sim.raycast import SoupScene

SENSOR = SensorConfig("scene32", 32, 720, 3.0, -25.0, 0.0, 60.0)
SENSOR_HEIGHT = 1.73
#: Label ids of the scene's surfaces.
GROUND, WALL, CAR, CAR_MOVING = 40, 50, 10, 252


@dataclass
class Mover:
    """A box of ``size`` whose centre (x, y) at scan k is ``path(k)``; ``inst`` is its instance id."""

    size: tuple[float, float, float]
    path: Callable[[int], tuple[float, float]]
    inst: int

    def centre(self, k: int) -> np.ndarray:
        return np.asarray(self.path(k), float)

    def moving(self, k: int) -> bool:
        return k > 0 and bool(np.linalg.norm(self.centre(k) - self.centre(k - 1)) > 1e-6)


def static_street(walls: list[tuple[float, float, float, float]]) -> TriangleSoup:
    """Ground from x -80..200, y -40..40, and wall boxes (x0, x1, y0, y1), 4 m high."""
    parts = [TriangleSoup.labelled(quad(-80, -40, 200, 40, 0.0), GROUND)]
    for x0, x1, y0, y1 in walls:
        parts.append(TriangleSoup.labelled(box((x1 - x0, y1 - y0, 4.0), ((x0 + x1) / 2, (y0 + y1) / 2, 2.0)), WALL))
    return TriangleSoup.concat(parts)


def write_drive(root: Path, n_scans: int, ego: Callable[[int], float], movers: list[Mover],
                walls: list[tuple[float, float, float, float]], name: str = "scene", upper_noise: float = 0.0,
                sensor: SensorConfig = SENSOR) -> Path:
    """Render and write the drive (ego at (ego(k), 0), heading +x) as ``sensor`` sees it; returns the sequence
    folder.

    ``upper_noise``: the range of every return above -5 deg elevation gets Gaussian noise of this sigma (m), drawn
    anew in every scan (a sensor whose upper beams are noisier than the simulator's).
    """
    folder = root / "sequences" / name
    lidar = Lidar(sensor, SensorEffects(range_sigma=0.0, dropout=0.0, grazing_dropout=0.0, far_dropout=0.0,
                                        remission_sigma=0.0, ego_clearance=1.0))
    origin = np.zeros(3)
    static = SoupScene(static_street(walls), origin)
    ever = {m.inst for m in movers if any(m.moving(k) for k in range(n_scans))}
    poses = []
    for k in range(n_scans):
        parts = []
        for m in movers:
            cx, cy = m.centre(k)
            sem = CAR_MOVING if m.moving(k) else CAR
            parts.append(TriangleSoup.labelled(box(m.size, (cx, cy, m.size[2] / 2 + 0.05)), sem, m.inst))
        dynamic = SoupScene(TriangleSoup.concat(parts), origin)
        pose = np.eye(4)
        pose[0, 3], pose[2, 3] = ego(k), SENSOR_HEIGHT
        scan = lidar.scan([static, dynamic], pose, np.random.default_rng(k))
        points = scan.points
        if upper_noise > 0:
            r = np.linalg.norm(points, axis=1)
            upper = points[:, 2] > r * np.sin(np.radians(-5.0))
            noise = np.random.default_rng(1000 + k).normal(0.0, upper_noise, len(points))
            points = np.where(upper[:, None], points * ((r + noise) / r)[:, None], points).astype(np.float32)
        write_scan(folder / "velodyne" / f"{k:06d}.bin", points, scan.remission)
        instant = scan.labels
        inst = instant >> np.uint32(16)
        semantickitti = np.where(np.isin(inst, list(ever)), (inst << np.uint32(16)) | CAR_MOVING, instant)
        write_label(folder / "labels_instant" / f"{k:06d}.label", instant)
        write_label(folder / "labels" / f"{k:06d}.label", semantickitti.astype(np.uint32))
        poses.append(pose)
    write_convention_file(folder, "semantickitti")
    write_calib(folder / "calib.txt")
    write_poses(folder / "poses.txt", np.asarray(poses))
    write_times(folder / "times.txt", np.arange(n_scans) * 0.1)
    return folder
