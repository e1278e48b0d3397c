"""SemanticKITTI sequence folders: the format real MOS users have, read and written.

Layout of one sequence::

    XX/velodyne/NNNNNN.bin   float32 x, y, z, remission
    XX/labels/NNNNNN.label   uint32, semantic id in the low 16 bits, instance in the high 16
    XX/poses.txt             3x4 camera poses per line (row-major)
    XX/calib.txt             'Tr:' the 3x4 LiDAR -> camera transform (among others)
    XX/times.txt             one timestamp in seconds per scan

Poses in ``poses.txt`` are in the camera frame; :func:`read_poses` returns LiDAR
poses ``inv(Tr) @ P @ Tr`` as LiDAR-MOS does, and :func:`write_poses` inverts that.
A bare folder of ``velodyne/*.bin`` (a user's own recording) is a valid sequence too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ros2_mos.core.atomic import atomic_open
from ros2_mos.core.errors import DatasetError

KITTI_TR = np.array(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


#: How far (the largest entry of R^T R - I) a pose file's rotation may be off a rotation matrix: rounding to a few
#: digits is mended (:func:`nearest_rigid`), more is refused.
ROTATION_TOLERANCE = 1e-3


def read_scan(path: str | Path) -> np.ndarray:
    """Read a ``.bin`` scan as an (N, 4) float32 array: x, y, z, remission."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"scan file not found: {path}")
    size = path.stat().st_size
    if size % 16:
        raise DatasetError(f"{path}: size {size} bytes is not a multiple of 16 (x, y, z, remission float32)")
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)


def write_scan(path: str | Path, points: np.ndarray, remission: np.ndarray | None = None) -> None:
    """Write x, y, z (+ remission, zeros if None) as a KITTI ``.bin``."""
    pts = np.asarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] not in (3, 4):
        raise DatasetError(f"write_scan: expected (N, 3) or (N, 4) points, got {pts.shape}")
    if pts.shape[1] == 3:
        rem = np.zeros(len(pts), np.float32) if remission is None else np.asarray(remission, np.float32)
        pts = np.column_stack([pts, rem])
    with atomic_open(path) as f:  # whole or not at all (a full disk: OutputError, no truncated scan)
        f.write(memoryview(np.ascontiguousarray(pts, dtype=np.float32)).cast("B"))


def read_label(path: str | Path, expected_points: int | None = None) -> np.ndarray:
    """Read a ``.label`` file as uint32; check it has one label per point when told how many."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"label file not found: {path}")
    size = path.stat().st_size
    if size % 4:
        raise DatasetError(f"{path}: size {size} bytes is not a multiple of 4 (uint32 labels): a damaged file")
    labels = np.fromfile(path, dtype=np.uint32)
    if expected_points is not None and len(labels) != expected_points:
        raise DatasetError(f"{path}: {len(labels)} labels for {expected_points} points")
    return labels


def write_label(path: str | Path, labels: np.ndarray) -> None:
    """Write uint32 labels as a ``.label`` file, whole or not at all (a full disk: OutputError, no truncated file)."""
    with atomic_open(path) as f:
        f.write(memoryview(np.ascontiguousarray(labels, dtype=np.uint32)).cast("B"))


def read_calib(path: str | Path) -> np.ndarray:
    """The 4x4 LiDAR -> camera transform ``Tr`` of a ``calib.txt``."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"calib file not found: {path}")
    for line in _read_text(path).splitlines():
        key, _, values = line.partition(":")
        if key.strip() == "Tr":
            try:
                numbers = [float(v) for v in values.split()]
            except ValueError:
                raise DatasetError(f"{path}: 'Tr' holds text that is not a number") from None
            if not all(np.isfinite(numbers)):
                raise DatasetError(f"{path}: 'Tr' holds non-finite numbers")
            if len(numbers) != 12:
                raise DatasetError(f"{path}: 'Tr' needs 12 numbers, got {len(numbers)}")
            tr = np.eye(4)
            tr[:3, :4] = np.reshape(numbers, (3, 4))
            return tr
    raise DatasetError(f"{path}: no 'Tr:' line")


def write_calib(path: str | Path, tr: np.ndarray = KITTI_TR) -> None:
    """Write a calib.txt with identity projections P0..P3 and the given ``Tr``."""
    p = " ".join(f"{v:.12e}" for v in np.eye(4)[:3, :4].ravel())
    t = " ".join(f"{v:.12e}" for v in np.asarray(tr)[:3, :4].ravel())
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write("".join(f"P{i}: {p}\n" for i in range(4)) + f"Tr: {t}\n")


def read_poses(path: str | Path, tr: np.ndarray | None = None) -> np.ndarray:
    """Read ``poses.txt`` as (M, 4, 4) LiDAR poses (camera poses if ``tr`` is None)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"poses file not found: {path}")
    rows = _load_numbers(path, 2)
    if rows.shape[1] != 12:
        raise DatasetError(f"{path}: each pose line needs 12 numbers, got {rows.shape[1]}")
    bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if len(bad):
        raise DatasetError(f"{path}: line {bad[0] + 1} holds a non-finite number")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    poses = nearest_rigid(poses, path)
    if tr is not None:
        poses = nearest_rigid(np.linalg.inv(tr) @ poses @ tr, path)
    return poses


def nearest_rigid(poses: np.ndarray, path: str | Path) -> np.ndarray:
    """``poses`` (M, 4, 4) with each rotation replaced by the nearest rotation matrix (SVD).

    A file's digits round its rotations off orthonormal (SemanticKITTI's own ``poses.txt`` has seven significant
    digits), and KISS-ICP's Sophus aborts the process on a rotation off by 1e-10. A rotation farther off than
    ``ROTATION_TOLERANCE``, or a reflection, is no rigid pose: a DatasetError naming the line.
    """
    rotations = poses[:, :3, :3]
    off = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((off > ROTATION_TOLERANCE) | (np.linalg.det(rotations) <= 0))
    if len(bad):
        raise DatasetError(f"{path}: line {bad[0] + 1} is no rigid pose (its 3x3 part is not a rotation)")
    u, _, vt = np.linalg.svd(rotations)
    out = poses.copy()
    out[:, :3, :3] = u @ vt
    return out


def write_poses(path: str | Path, lidar_poses: np.ndarray, tr: np.ndarray | None = KITTI_TR) -> None:
    """Write LiDAR poses as KITTI camera poses ``Tr @ P @ inv(Tr)``."""
    poses = np.asarray(lidar_poses, dtype=np.float64)
    if tr is not None:
        poses = tr @ poses @ np.linalg.inv(tr)
    with atomic_open(path, "w", encoding="utf-8") as f:
        np.savetxt(f, poses[:, :3, :4].reshape(-1, 12), fmt="%.12e")


def read_times(path: str | Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"times file not found: {path}")
    times = _load_numbers(path, 1)
    if times.ndim != 1:
        raise DatasetError(f"{path}: expected one time per line, got {times.shape[1]} columns")
    if not np.isfinite(times).all():
        raise DatasetError(f"{path}: line {int(np.flatnonzero(~np.isfinite(times))[0]) + 1} is not a finite time")
    back = np.flatnonzero(np.diff(times) <= 0)
    if len(back):
        k = int(back[0])
        raise DatasetError(f"{path}: times must increase, but line {k + 2} ({times[k + 1]:g} s) does not come "
                           f"after line {k + 1} ({times[k]:g} s)")
    return times


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not a UTF-8 text file") from None


def _load_numbers(path: Path, ndmin: int) -> np.ndarray:
    """A whitespace-separated table of numbers; text, ragged rows or binary content are one-line errors."""
    import warnings

    text = _read_text(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: checked below
            rows = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=ndmin)
    except ValueError as exc:
        raise DatasetError(f"{path}: not a table of numbers ({str(exc).splitlines()[0]})") from None
    if rows.size == 0:
        raise DatasetError(f"{path}: empty")
    return rows


def write_times(path: str | Path, times: np.ndarray) -> None:
    with atomic_open(path, "w", encoding="utf-8") as f:
        np.savetxt(f, np.asarray(times, dtype=np.float64), fmt="%.6e")


@dataclass
class Frame:
    """One scan of a sequence with what the folder has for it (labels/pose may be None)."""

    index: int
    points: np.ndarray  # (N, 3) float32
    remission: np.ndarray  # (N,) float32
    labels: np.ndarray | None  # (N,) uint32 raw SemanticKITTI labels
    pose: np.ndarray | None  # (4, 4) LiDAR pose in the sequence's world frame
    timestamp: float


class SemanticKittiSequence:
    """One sequence folder; needs only ``velodyne/*.bin``, uses labels/poses/times when present."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        velodyne = self.root / "velodyne"
        if not velodyne.is_dir():
            raise DatasetError(f"{self.root}: no velodyne/ folder (expected a SemanticKITTI sequence folder)")
        self.scan_files = sorted(velodyne.glob("*.bin"))
        if not self.scan_files:
            raise DatasetError(f"{velodyne}: no .bin scans")
        self.name = self.root.name
        label_dir = self.root / "labels"
        self.has_labels = label_dir.is_dir() and any(label_dir.glob("*.label"))
        # Poses are only needed by some uses (--use-poses, training, the applications): a bad
        # poses.txt is reported when they are asked for (require_poses), not when the folder opens.
        try:
            self.poses, self.poses_problem = self._load_poses(), ""
        except DatasetError as exc:
            self.poses, self.poses_problem = None, str(exc)
        times_file = self.root / "times.txt"
        self.times = read_times(times_file) if times_file.is_file() else np.arange(len(self.scan_files)) * 0.1
        if len(self.times) < len(self.scan_files):
            raise DatasetError(f"{times_file}: {len(self.times)} times for {len(self.scan_files)} scans")

    def _load_poses(self) -> np.ndarray | None:
        poses_file = self.root / "poses.txt"
        if not poses_file.is_file():
            return None
        calib_file = self.root / "calib.txt"
        tr = read_calib(calib_file) if calib_file.is_file() else None
        poses = read_poses(poses_file, tr)
        if len(poses) < len(self.scan_files):
            raise DatasetError(f"{poses_file}: {len(poses)} poses for {len(self.scan_files)} scans")
        return poses

    def __len__(self) -> int:
        return len(self.scan_files)

    def require_poses(self, why: str = "the dataset's poses") -> np.ndarray:
        """The (N, 4, 4) LiDAR poses, or a DatasetError saying why there are none."""
        if self.poses is None:
            reason = self.poses_problem or f"no {self.root / 'poses.txt'}"
            raise DatasetError(f"{why} need poses.txt: {reason}")
        return self.poses[: len(self)]

    def scan_place(self, index: int) -> str:
        """Where scan ``index`` is, for a message: ``"08 scan 5 (000005.bin)"``."""
        return f"{self.name} scan {index} ({self.scan_files[index].name})"

    def label_path(self, index: int) -> Path:
        return self.root / "labels" / (self.scan_files[index].stem + ".label")

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"scan {index} out of range 0..{len(self) - 1}")
        scan = read_scan(self.scan_files[index])
        labels = read_label(self.label_path(index), len(scan)) if self.has_labels else None
        pose = None if self.poses is None else self.poses[index]
        return Frame(index, scan[:, :3], scan[:, 3], labels, pose, float(self.times[index]))

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]


def sequence_dirs(root: str | Path, names: list[str] | None = None) -> list[Path]:
    """Sequence folders under ``root`` (``root/sequences/XX`` or ``root/XX``), optionally only ``names``."""
    root = Path(root)
    base = root / "sequences" if (root / "sequences").is_dir() else root
    if (base / "velodyne").is_dir():
        return [base]
    if names is None:
        found = sorted(p for p in base.iterdir() if (p / "velodyne").is_dir()) if base.is_dir() else []
    else:
        found = [base / n for n in names]
        missing = [str(p) for p in found if not (p / "velodyne").is_dir()]
        if missing:
            raise DatasetError(f"sequence folders not found: {', '.join(missing)}")
    if not found:
        raise DatasetError(f"{root}: no sequence folders with velodyne/ found")
    return found
