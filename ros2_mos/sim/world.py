"""One simulated sequence: street grid, ego route, static scene, traffic, and its scans one by one.

Everything random is drawn from one ``numpy`` Generator seeded by (seed, sequence
name), so a sequence is the same for the same seed whatever else is generated;
each scan's sensor noise comes from its own Generator seeded by (seed, name,
index), so any scan can be regenerated alone.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ros2_mos.core.config import SensorConfig, sensor_preset
from ros2_mos.core.errors import ConfigError
from ros2_mos.sim.lidar import Lidar, LidarScan
from ros2_mos.sim.presets import SimPreset, sim_preset
from ros2_mos.sim.raycast import SoupScene
from ros2_mos.sim.road import StreetGrid, random_route
from ros2_mos.sim.scene import Ground, StaticScene, build_static_scene
from ros2_mos.sim.terrain import BodyMotion, Terrain
from ros2_mos.sim.traffic import Traffic, build_ego, build_traffic


@dataclass
class SimScan:
    """One scan: its index, time (s), LiDAR pose in the sequence frame (first scan = identity), points and labels."""

    index: int
    time: float
    pose: np.ndarray
    scan: LidarScan


def resolve_settings(preset: str | SimPreset, sensor: str | SensorConfig) -> tuple[SimPreset, SensorConfig]:
    """The preset and sensor a simulation runs with, from their names or as given."""
    return (sim_preset(preset) if isinstance(preset, str) else preset,
            sensor_preset(sensor) if isinstance(sensor, str) else sensor)


class SequenceSimulator:
    """Builds a sequence's world up front, then renders its scans lazily (``for scan in sim``)."""

    def __init__(self, n_scans: int, preset: str | SimPreset = "benchmark", seed: int = 0,
                 sensor: str | SensorConfig = "hdl64", name: str = "00") -> None:
        if n_scans < 1:
            raise ConfigError(f"n_scans must be >= 1, got {n_scans}")
        if seed < 0:
            raise ConfigError(f"seed must be >= 0, got {seed}")
        self.preset, self.sensor = resolve_settings(preset, sensor)
        self.n_scans, self.seed, self.name = n_scans, seed, name
        self._key = [int(seed), zlib.crc32(name.encode())]
        rng = np.random.default_rng(self._key)
        p = self.preset
        self.lidar = Lidar(self.sensor, p.effects)
        reach = self.lidar.max_range
        period = p.scan_period
        self.times = period * np.arange(-1, n_scans)

        drive = p.ego.speed[1] * (n_scans * period + 40.0)
        s_start = reach + 150.0
        route_length = s_start + drive + reach + 200.0
        road = 2.0 * (p.street.half_road_width + p.street.sidewalk_width)
        n_lines = int(2.0 * route_length / (p.street.block_size[0] + road)) + 5
        self.grid = StreetGrid.generate(rng, p.street, n_lines)
        self.terrain = Terrain.random(rng, p.scene.ground_rms)
        ground = Ground(self.terrain, self.grid, p.street)
        self.route = random_route(rng, self.grid, p.street, route_length)
        ego = build_ego(rng, p, self.route, s_start, float(self.times[-1]))

        ex, ey, _ = ego.pose_at(self.times)
        steps = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(ex), np.diff(ey)))])
        thin = np.unique(np.searchsorted(steps, np.arange(0.0, steps[-1] + 5.0, 5.0)).clip(0, len(ex) - 1))
        self.static: StaticScene = build_static_scene(
            rng, self.grid, p.street, p.scene, self.terrain, np.column_stack([ex[thin], ey[thin]]), reach + 10.0
        )
        self.traffic: Traffic = build_traffic(rng, p, ground, ego, self.times, reach, self.static.next_instance)
        if self.traffic.agents and self.traffic.agents[-1].inst > 0xFFFF:
            raise ConfigError("too many objects for 16-bit instance ids; simulate shorter sequences")
        self._body = BodyMotion.random(rng, p.ego.body_vibration_deg)
        self._origin = np.array([ex[1], ey[1], 0.0])
        self._static_scene = SoupScene(self.static.soup, self._origin)
        self._first_inv = np.linalg.inv(self.world_pose(0))

    def __len__(self) -> int:
        return self.n_scans

    def world_pose(self, k: int) -> np.ndarray:
        """The LiDAR's 4x4 pose at scan k in the world frame of the simulation."""
        return self.poses_at(np.array([self.times[k + 1]]))[0]

    def poses_at(self, t: np.ndarray) -> np.ndarray:
        """The LiDAR's (N, 4, 4) world poses at times ``t``: on the ego lane, pitched and rolled by the ground."""
        t = np.asarray(t, float)
        x, y, yaw = self.traffic.ego.pose_at(t)
        pitch, roll = self._body.at(t, self.traffic.ego.profile)
        return self.terrain.vehicle_pose(x, y, yaw, self.preset.effects.sensor_height, pitch, roll)

    def scan(self, k: int) -> SimScan:
        """Render scan k (0-based)."""
        if not 0 <= k < self.n_scans:
            raise IndexError(f"scan {k} out of range 0..{self.n_scans - 1}")
        t = float(self.times[k + 1])
        dynamic = SoupScene(self.traffic.dynamic_soup(k, self.lidar.max_range + 10.0), self._origin)
        rng = np.random.default_rng(self._key + [k])
        if self.preset.effects.intra_sweep_motion:
            poses = self.poses_at(t + self.lidar.column_phase * self.preset.scan_period)
        else:
            poses = self.world_pose(k)
        scan = self.lidar.scan([self._static_scene, dynamic], poses, rng)
        return SimScan(k, t - float(self.times[1]), self._first_inv @ self.world_pose(k), scan)

    def __iter__(self) -> Iterator[SimScan]:
        for k in range(self.n_scans):
            yield self.scan(k)
