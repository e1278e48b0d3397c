"""A drive to label offline: the scans of a SemanticKITTI sequence folder or of a bag's PointCloud2 topic.

Both behind one interface (:class:`Drive`): its name, its length, and its scans in order, each read anew when asked
for, so that a pass over a 2,000-scan drive holds one scan at a time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.sweep import read_sweep_file


@dataclass
class DriveScan:
    index: int
    stamp: float  # seconds since the drive's first scan
    points: np.ndarray  # (N, 3) float32, the finite points with a range > 0
    intensity: np.ndarray  # (N,) float32
    kept: np.ndarray  # (N,) their indices among the scan's points as stored (a label is due for each of those)
    stored: int  # how many points the scan has as stored
    #: (N,) each point's firing time within the sweep, -0.5 to 0.5, from the cloud's own per-point times (a bag's);
    #: None where the scan has none (its azimuth tells it: :func:`~ros2_mos.core.deskew.sweep_phase`)
    phase: np.ndarray | None = None


class Drive(Protocol):
    name: str
    poses: np.ndarray | None  # (N, 4, 4) LiDAR poses where the drive has them
    skewed: bool | None  # its sweeps are skewed (True) or compensated (False), where the drive says (sweep.txt)
    scan_names: list[str]  # per scan, the stem of its label file (a folder's scan files; a bag's 000000, 000001, ...)

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[DriveScan]: ...


def scan_place(drive: Drive, index: int) -> str:
    """Where scan ``index`` of ``drive`` is, for a message: ``"DRIVE scan 5 (000005)"``."""
    return f"{drive.name} scan {index} ({drive.scan_names[index]})"


def _scan(index: int, stamp: float, points: np.ndarray, intensity: np.ndarray) -> DriveScan:
    """The finite points with a range > 0, and where they sit among the stored ones (a point whose squared range
    overflows float32, 1.8e19 m, is not finite either)."""
    with np.errstate(over="ignore", invalid="ignore"):
        squared = np.einsum("ij,ij->i", points, points)  # NaN or inf where a coordinate is
        finite = (squared > 0) & (squared < np.inf)
    if finite.all():  # the usual case: no fancy-index copy
        return DriveScan(index, stamp, np.ascontiguousarray(points, np.float32),
                         np.ascontiguousarray(intensity, np.float32), np.arange(len(points)), len(points))
    keep = np.flatnonzero(finite)
    return DriveScan(index, stamp, np.ascontiguousarray(points[keep], np.float32),
                     np.ascontiguousarray(intensity[keep], np.float32), keep, len(points))


class FolderDrive:
    """A SemanticKITTI sequence folder (``velodyne/*.bin``; poses and times used where present)."""

    def __init__(self, root: str | Path) -> None:
        from ros2_mos.io.semantic_kitti import SemanticKittiSequence

        self.sequence = SemanticKittiSequence(root)
        self.name = self.sequence.name
        self.poses = self.sequence.poses[: len(self.sequence)] if self.sequence.poses is not None else None
        self.scan_names = [f.stem for f in self.sequence.scan_files]
        self.skewed = read_sweep_file(root)

    def __len__(self) -> int:
        return len(self.sequence)

    def __iter__(self) -> Iterator[DriveScan]:
        from ros2_mos.io.semantic_kitti import read_scan

        t0 = float(self.sequence.times[0])
        for i, path in enumerate(self.sequence.scan_files):
            scan = read_scan(path)
            yield _scan(i, float(self.sequence.times[i]) - t0, scan[:, :3], scan[:, 3])


class BagDrive:
    """The PointCloud2 messages of one topic of a rosbag2 bag (the only one unless ``topic`` is given)."""

    def __init__(self, path: str | Path, topic: str | None = None) -> None:
        from ros2_mos.io.bags import iter_pointclouds, pointcloud_topic
        from ros2_mos.io.pointcloud2 import decode_xyz_intensity, sweep_phases

        self.path = Path(path)
        self.topic = pointcloud_topic(self.path, topic)  # raises when the bag has none
        self.name = self.path.name
        self.poses = None
        self.stamps = []
        #: A driver that stamps each point with its own time (Ouster's ``t``, Velodyne's ``time``) publishes the
        #: sweep as measured, skewed: the time field is there for whoever deskews it. None where it has none.
        self.skewed: bool | None = None
        for stamp, msg in iter_pointclouds(self.path, self.topic):
            if not self.stamps:
                _, _, valid = decode_xyz_intensity(msg)
                self.skewed = True if sweep_phases(msg, valid) is not None else None
            self.stamps.append(stamp)
        self.scan_names = [f"{i:06d}" for i in range(len(self.stamps))]

    def __len__(self) -> int:
        return len(self.stamps)

    def __iter__(self) -> Iterator[DriveScan]:
        from ros2_mos.io.bags import iter_pointclouds
        from ros2_mos.io.pointcloud2 import decode_xyz_intensity, sweep_phases

        t0 = self.stamps[0] if self.stamps else 0
        for i, (stamp, msg) in enumerate(iter_pointclouds(self.path, self.topic)):
            points, intensity, valid = decode_xyz_intensity(msg)
            scan = _scan(i, (stamp - t0) * 1e-9, points, intensity)
            phase = sweep_phases(msg, valid)
            scan.phase = phase[scan.kept] if phase is not None else None
            # labels are due for every point of the message, in its order (decode drops the non-finite ones)
            scan.kept = valid[scan.kept]
            scan.stored = int(msg.width) * int(msg.height)
            yield scan


def given_poses(drive: Drive, why: str) -> np.ndarray:
    """The drive's own poses, or a one-line DatasetError saying ``why`` they were asked for (a folder's says what is
    wrong with its poses.txt)."""
    if isinstance(drive, FolderDrive):
        return drive.sequence.require_poses(why)
    if drive.poses is None:
        raise DatasetError(f"{drive.name}: {why} needs its poses.txt")
    return drive.poses


def open_drive(path: str | Path, topic: str | None = None) -> FolderDrive | BagDrive:
    """A sequence folder (with ``velodyne/``) or a bag folder/file (``metadata.yaml``, ``.mcap``, ``.db3``)."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"drive not found: {path}")
    if (path / "velodyne").is_dir():
        return FolderDrive(path)
    is_bag = (path / "metadata.yaml").is_file() or path.suffix in (".mcap", ".db3") or any(
        path.glob("*.mcap")) or any(path.glob("*.db3"))
    if not is_bag:
        raise DatasetError(f"{path}: neither a SemanticKITTI sequence folder (velodyne/*.bin) nor a rosbag2 bag")
    return BagDrive(path, topic)
