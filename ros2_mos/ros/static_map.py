"""The node's cleaned local map (paper Sec. V-D online): every n-th scan's static points in a voxel map.

Pure (no rclpy), shared by the worker thread that adds scans and the timer that publishes the map.
"""

from __future__ import annotations

import threading

import numpy as np

from ros2_mos.apps.mapping import VoxelMap, VoxelMapConfig
from ros2_mos.ros.params import StaticMapSettings
from ros2_mos.ros.processor import ScanOutput


class StaticMap:
    """A thread-safe :class:`~ros2_mos.apps.mapping.VoxelMap` of static points in the odometry frame."""

    def __init__(self, settings: StaticMapSettings) -> None:
        self.settings = settings
        self._map = VoxelMap(VoxelMapConfig(settings.voxel_size, settings.max_radius, settings.max_points))
        self._lock = threading.Lock()
        self._scans = 0
        self._stamp_ns = 0

    def add(self, out: ScanOutput) -> None:
        """Every ``insert_every``-th scan's static points go in; a reset (a new odometry frame) clears the map."""
        if out.reset:
            with self._lock:
                self._map.clear()  # old points would not line up with the new frame
            self._scans = 0
        self._scans += 1
        if (self._scans - 1) % self.settings.insert_every == 0:
            with self._lock:
                self._map.insert_scan(out.static_points, out.result.pose, stamp=out.stamp_ns * 1e-9)
                self._stamp_ns = out.stamp_ns

    def snapshot(self) -> tuple[np.ndarray, int] | None:
        """(points (M, 3) float32, stamp of the last scan added in ns), or None while the map is empty."""
        with self._lock:
            if len(self._map) == 0:
                return None
            return np.array(self._map.points, dtype=np.float32), self._stamp_ns
