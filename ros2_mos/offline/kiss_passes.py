"""Autolabel's KISS-ICP passes over a drive: forwards, backwards, and the restart of each pass's first scans.

KISS-ICP starts from rest and falls behind where the sensor stood and moved off; backwards, that moment is a stop,
which it follows (:mod:`~ros2_mos.offline.trajectory` chooses between the passes). Where the drive allows it, the
backward pass runs in a process of its own (:class:`BackwardPass`) beside the forward one, on the core the forward
pass leaves idle: it reads the drive itself and keeps each scan as KISS-ICP keeps it, and registers them last
scan first as soon as the forward pass has seen the sensor stand and move off (where it never does, the process is
stopped at the end, having only read the drive). Its poses are the ones the same pass run here after the forward
one gives, to the bit (one thread each, the same clouds).
"""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from ros2_mos.core.config import OdometryConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.worker import Worker

#: The first RESTART_FROM scans' poses come from a second KISS-ICP pass over the first RESTART_SCANS scans that
#: starts with the velocity the first pass found at scan RESTART_FROM (:func:`restart`).
RESTART_FROM = 8
RESTART_SCANS = 14
#: :class:`BackwardPass`'s requests to its process: keep the drive's scans; register them backwards.
KEEP, REGISTER = "keep", "register"


def restart(clouds: Iterator[np.ndarray], poses: np.ndarray, config: OdometryConfig) -> np.ndarray:
    """Register a pass's first scans again (``clouds`` in the pass's order), knowing how fast it moved.

    KISS-ICP starts from rest: when the drive starts under way, the first scans are registered a step or more
    off (0.7-1.2 m measured on a simulated drive starting at 7.7 m/s) and would see through everything that
    stands. They are registered again from a start with the velocity of scans :data:`RESTART_FROM` on, and
    chained to the first pass's poses there. (Backwards, the drive's end is that pass's start.)
    """
    from ros2_mos.core.odometry import KissIcpOdometry

    n = len(poses)
    if n <= RESTART_SCANS:
        return poses
    odometry = KissIcpOdometry(config)
    odometry.assume_motion(np.linalg.inv(poses[RESTART_FROM]) @ poses[RESTART_FROM + 1])
    again = []
    for cloud in clouds:
        if len(again) >= RESTART_SCANS:
            break
        again.append(odometry.register(cloud))
    again = np.asarray(again)
    anchor = poses[RESTART_FROM] @ np.linalg.inv(again[RESTART_FROM])
    out = poses.copy()
    out[:RESTART_FROM] = anchor @ again[:RESTART_FROM]
    return out


def frame_path(folder: Path, index: int) -> Path:
    """Where scan ``index`` is kept as KISS-ICP keeps it (:attr:`KissIcpOdometry.last_frame`) for the backward
    pass."""
    return Path(folder) / f"kiss{index:06d}.npy"


def backward_poses(folder: Path, n: int, config: OdometryConfig,
                   progress: Callable[[int], None] = lambda done: None) -> np.ndarray:
    """KISS-ICP over the ``n`` scans kept in ``folder`` (:func:`frame_path`), last scan first, with ``config`` (the
    forward pass's); poses in scan order. ``progress`` is told each scan registered."""
    from ros2_mos.core.odometry import KissIcpOdometry

    config = dataclasses.replace(config, point_stride=1)  # the kept clouds are thinned already
    paths = [frame_path(folder, k) for k in range(n - 1, -1, -1)]
    odometry = KissIcpOdometry(config)
    poses = []
    for path in paths:
        poses.append(odometry.register(np.load(path)))
        progress(1)
    poses = restart((np.load(path) for path in paths), np.asarray(poses), config)
    return poses[::-1].copy()


def keep_frames(scans: Iterable[np.ndarray], folder: Path, config: OdometryConfig) -> int:
    """Keep each of ``scans`` (sensor-frame points, in drive order) in ``folder`` as KISS-ICP with ``config`` keeps
    it when it registers the scan (:meth:`KissIcpOdometry.kept_frame`); returns how many."""
    from ros2_mos.core.odometry import KissIcpOdometry

    odometry = KissIcpOdometry(config)
    kept = 0
    for points in scans:
        np.save(frame_path(folder, kept), odometry.kept_frame(points))
        kept += 1
    return kept


class BackwardPass:
    """The backward pass in a process of its own: the process reads ``drive`` itself at once (so the drive must
    pickle: :meth:`start` says where it does not) and keeps its scans in ``folder``; it registers them backwards once
    told the pass is wanted (:meth:`go`, as soon as the forward pass shows the sensor stood and moved off), so that a
    drive that never stood costs it only the reading. :meth:`poses` waits for them; :meth:`close` stops the process
    (at once where its poses were not asked for)."""

    def __init__(self, drive: Any, config: OdometryConfig, folder: Path) -> None:
        self.scans = len(drive)
        self._worker = Worker("ros2_mos.offline.kiss_passes:backward_server", (drive, config, Path(folder)),
                              "backward KISS-ICP pass")
        self._worker.send(KEEP)
        self.going = False
        self._done = False

    def go(self) -> None:
        """Register the kept scans backwards (once they are all kept); returns at once."""
        if not self.going:
            self._worker.send(REGISTER)
            self.going = True

    @classmethod
    def start(cls, drive: Any, config: OdometryConfig, folder: Path) -> "BackwardPass | None":
        """The pass in its process, or None where ``drive`` cannot go to another process (it does not pickle: a
        drive of the caller's own making); the caller then runs it after the forward pass."""
        try:
            pickle.dumps(drive, protocol=pickle.HIGHEST_PROTOCOL)
        except (pickle.PicklingError, TypeError, AttributeError):
            return None
        return cls(drive, config, folder)

    def poses(self) -> np.ndarray:
        """(N, 4, 4) the backward pass's poses in scan order (:meth:`go` where not yet); raises the process's
        error."""
        self.go()
        poses = self._worker.receive()
        self._done = True
        if len(poses) != self.scans:
            raise ConfigError(f"backward KISS-ICP pass: {len(poses)} poses for {self.scans} scans")
        return poses

    def close(self) -> None:
        self._worker.close(kill=not self._done)


def backward_server(setup: tuple[Any, OdometryConfig, Path]) -> Callable[[str], list[Any]]:
    """The backward pass's process (:class:`~ros2_mos.core.worker.Worker`): :data:`KEEP` keeps the drive's scans,
    :data:`REGISTER` registers them backwards and answers the poses."""
    drive, config, folder = setup
    kept = []

    def handle(request: str) -> list[Any]:
        if request == KEEP:
            kept.append(keep_frames((scan.points for scan in drive), folder, config))
            return []
        if request == REGISTER and kept:
            return [backward_poses(folder, kept[0], config)]
        raise ConfigError(f"backward KISS-ICP pass: unexpected request {request!r}")

    return handle
