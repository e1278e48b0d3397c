"""Online odometry (KISS-ICP) and the ring buffer of past scans the residuals need.

KISS-ICP's ``register_frame`` (version 1.3.0, pinned in setup.py and requirements.txt)
registers a scan and adds it to its local map in one step.  We split the two so that
the map can be updated with the *static* points of the MOS decision for the same scan
(``map_update='static'``): the pose of scan t is estimated before its labels exist (the
residuals need it), so this is the causal way to keep moving objects out of the
registration of every later scan.

The registration runs in slices of a few ICP iterations (:meth:`KissIcpOdometry._align`): KISS-ICP's
C++ holds the GIL for the whole of a call, and an ICP that does not converge (a scattered cloud against a
scattered map took 9-27 s, issue 13) would otherwise freeze every other Python thread of the process with
it, the node's diagnostics timer included.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ros2_mos.core.config import OdometryConfig
from ros2_mos.core.errors import ConfigError

#: ICP iterations of the first call into KISS-ICP, then of each further call; other threads get the GIL between
#: calls. Nearly every scan converges within the first call (iteration counts: benchmarks/reliability.md, round 4,
#: item 8); one that does not runs on in short slices, up to KISS-ICP's own cap (500 iterations) as before.
ICP_FIRST_SLICE = 32
ICP_SLICE = 8
#: Seconds the registration sleeps between slices once it has not converged in its first call: without it, a thread
#: that needs the GIL several times for one task (the diagnostics timer: wait, callback, publish) gets it once per
#: slice and finishes one task per few slices (gaps of 0.6-1.1 s seen between diagnostics with 0.06 s slices).
ICP_YIELD_S = 0.002


class KissIcpOdometry:
    """KISS-ICP on each incoming scan; ``last_pose`` is the 4x4 world pose of the newest scan."""

    def __init__(self, config: OdometryConfig = OdometryConfig()) -> None:
        from kiss_icp.config import load_config
        from kiss_icp.kiss_icp import KissICP
        from kiss_icp.pybind import kiss_icp_pybind

        cfg = load_config(None)
        cfg.data.max_range = config.max_range
        cfg.data.min_range = config.min_range
        cfg.data.deskew = config.deskew
        cfg.mapping.voxel_size = config.voxel_size if config.voxel_size is not None else config.max_range / 100.0
        cfg.mapping.max_points_per_voxel = config.max_points_per_voxel
        cfg.registration.convergence_criterion = config.convergence_criterion
        cfg.registration.max_num_threads = config.threads  # its preprocessing's too
        self.config = config
        self._kiss_config = cfg
        self._kiss_class = KissICP
        self._kiss = KissICP(cfg)
        self._pending_frame: np.ndarray | None = None
        #: How long each call into KISS-ICP held the GIL, for the last scan registered.
        self.last_slice_seconds: list[float] = []
        reg = cfg.registration
        self._pybind = kiss_icp_pybind
        first = min(ICP_FIRST_SLICE, int(reg.max_num_iterations))
        self._slices = [kiss_icp_pybind._Registration(max_num_iterations=n, max_num_threads=reg.max_num_threads,
                                                      convergence_criterion=reg.convergence_criterion)
                        for n in (first, ICP_SLICE)]
        self._more_slices = -(-(int(reg.max_num_iterations) - first) // ICP_SLICE)
        self._convergence = float(reg.convergence_criterion)

    @property
    def last_pose(self) -> np.ndarray:
        return self._kiss.last_pose.copy()

    def reset(self) -> None:
        """Forget the map and the motion model (after a time jump or a detected failure)."""
        self._kiss = self._kiss_class(self._kiss_config)
        self._pending_frame = None

    def assume_motion(self, delta: np.ndarray) -> None:
        """Start the motion model at ``delta`` (4x4, the motion from one scan to the next) instead of at rest."""
        delta = np.asarray(delta, np.float64)
        if delta.shape != (4, 4) or not np.isfinite(delta).all():
            raise ConfigError(f"assume_motion needs a finite 4x4 transform, got shape {delta.shape}")
        self._kiss.last_delta = delta.copy()

    def estimate(self, points: np.ndarray, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Register a scan against the local map and return its world pose, without updating the map.

        Call :meth:`update_map` afterwards (with all or only static points) before the next scan.
        """
        kiss = self._kiss
        source, frame_downsample = self._frames(points, timestamps)
        sigma = kiss.adaptive_threshold.get_threshold()
        initial_guess = kiss.last_pose @ kiss.last_delta
        new_pose = self._align(source, initial_guess, sigma)
        kiss.adaptive_threshold.update_model_deviation(np.linalg.inv(initial_guess) @ new_pose)
        kiss.last_delta = np.linalg.inv(kiss.last_pose) @ new_pose
        kiss.last_pose = new_pose
        self._pending_frame = frame_downsample
        #: the scan as KISS-ICP keeps it (thinned, range-filtered, one point per half voxel): registered again with
        #: ``point_stride`` 1 it registers like the scan (autolabel's backward pass keeps these, not whole scans)
        self.last_frame = frame_downsample
        return new_pose.copy()

    def kept_frame(self, points: np.ndarray) -> np.ndarray:
        """The scan as :meth:`estimate` keeps it (``last_frame``), without registering it: without per-point times
        that depends on the scan alone (autolabel's backward pass keeps each scan so while the forward one runs)."""
        return self._frames(points, None)[1]

    def _frames(self, points: np.ndarray, timestamps: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """KISS-ICP's (source, frame_downsample) of a scan: thinned by ``point_stride``, preprocessed (range
        filter; deskewed with the motion model where per-point times are given) and voxelised."""
        kiss = self._kiss
        stride = self.config.point_stride
        frame = np.asarray(points[::stride], dtype=np.float64)
        stamps = np.asarray([] if timestamps is None else np.asarray(timestamps)[::stride], dtype=np.float64)
        return kiss.voxelize(kiss.preprocessor.preprocess(frame, stamps, kiss.last_delta))

    def _align(self, source: np.ndarray, initial_guess: np.ndarray, sigma: float) -> np.ndarray:
        """KISS-ICP's ``align_points_to_map`` in slices (``ICP_FIRST_SLICE``, then ``ICP_SLICE`` iterations each).

        Each slice starts where the last one stopped, and the GIL is free in between. A slice cannot say
        whether it converged or ran out of iterations, so the next one tells: from a converged pose its
        first step is below the convergence criterion and it returns at once (one iteration, the price of
        the slicing: benchmarks/design_figures.md). The pose returned is then the converged slice's, as one
        call returned it.
        (Where the step after convergence exceeds the criterion, which is rarer the smaller the criterion, the
        slices iterate on where one call would have stopped.)
        """
        points = self._pybind._Vector3dVector(source)
        voxel_map = self._kiss.local_map._internal_map
        first, more = self._slices

        self.last_slice_seconds = []

        def align(registration: Any, guess: np.ndarray) -> np.ndarray:
            start = time.perf_counter()
            pose = registration._align_points_to_map(points=points, voxel_map=voxel_map, initial_guess=guess,
                                                     max_correspondance_distance=3 * sigma, kernel=sigma)
            self.last_slice_seconds.append(time.perf_counter() - start)
            return pose

        pose = align(first, np.asarray(initial_guess, dtype=np.float64))
        for index in range(self._more_slices):
            if index:  # not before the check that the first call converged (nearly every scan stops there)
                time.sleep(ICP_YIELD_S)
            new = align(more, pose)
            if _step(pose, new) < self._convergence:
                return pose
            pose = new
        return pose

    def update_map(self, static_points: np.ndarray | None = None) -> None:
        """Add the last estimated scan to the local map: all its points, or only ``static_points``.

        ``static_points`` are in the scan's own sensor frame; they are thinned by ``point_stride`` and
        downsampled like KISS-ICP does, as the scan was in :meth:`estimate`.
        """
        kiss = self._kiss
        if static_points is None:
            if self._pending_frame is None:
                return
            frame = self._pending_frame
        else:
            _, frame = kiss.voxelize(np.asarray(static_points[:: self.config.point_stride], dtype=np.float64))
        kiss.local_map.update(frame, kiss.last_pose)
        self._pending_frame = None

    def register(self, points: np.ndarray, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Estimate the pose and update the map with the whole scan (plain KISS-ICP)."""
        pose = self.estimate(points, timestamps)
        self.update_map()
        return pose


def _step(before: np.ndarray, after: np.ndarray) -> float:
    """Size of the rigid motion from ``before`` to ``after`` as KISS-ICP measures an ICP step: the norm of
    (translation, rotation angle in rad), exact to first order for the small steps it is used on."""
    delta = after @ np.linalg.inv(before)
    angle = float(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.hypot(np.linalg.norm(delta[:3, 3]), angle))


@dataclass
class BufferedScan:
    points: np.ndarray  # (N, 3) float32 in the scan's own sensor frame
    remission: np.ndarray  # (N,) float32
    pose: np.ndarray  # (4, 4) world pose
    timestamp: float
    range_image: np.ndarray | None = None  # (H, W) its own range image (free-space inputs need it)
    xyz_planes: np.ndarray | None = None  # (3, H*W) its own points per pixel (registration)
    normals: np.ndarray | None = None  # (3, H*W) the normals at those points (registration)
    registered_pose: np.ndarray | None = None  # (4, 4) its pose on the scan-to-scan registered trajectory


class ScanBuffer:
    """The last ``capacity`` scans with their world poses, newest first."""

    def __init__(self, capacity: int) -> None:
        if capacity < 0:
            raise ConfigError(f"scan buffer capacity must be >= 0, got {capacity}")
        self.capacity = capacity
        self._scans: deque[BufferedScan] = deque(maxlen=capacity) if capacity > 0 else deque(maxlen=0)

    def __len__(self) -> int:
        return len(self._scans)

    def push(self, scan: BufferedScan) -> None:
        if self.capacity > 0:
            self._scans.appendleft(scan)

    def newest_first(self) -> list[BufferedScan]:
        return list(self._scans)

    def clear(self) -> None:
        self._scans.clear()

    @property
    def full(self) -> bool:
        return len(self._scans) >= self.capacity
