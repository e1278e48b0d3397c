"""Odometry errors exactly as the KITTI odometry devkit (``evaluate_odometry.cpp``) computes them.

The devkit's relative errors, reproduced step by step:

* ``trajectoryDistances``: cumulative path length of the *ground-truth* trajectory;
* every 10th frame is a first frame; for each segment length 100, 200, ..., 800 m the
  last frame is the first one whose distance *exceeds* ``dist[first] + length``
  (segments that run past the end are skipped);
* ``pose_error = inv(inv(E_first) E_last) @ inv(G_first) G_last``; the translational
  error is ``|t(pose_error)| / length``, the rotational error the angle of its rotation
  (``acos(clip((trace - 1) / 2))``) divided by ``length``;
* the reported numbers are plain means over all segments (of all sequences pooled):
  translation in % and rotation in deg/100 m, as the benchmark's web page shows them.

The devkit works on camera poses (``poses.txt``); :func:`to_camera_frame` converts LiDAR
poses with the calibration so that our numbers are comparable with published ones.

The absolute trajectory error (not in the devkit) is the RMSE of the position
differences after a rigid (SE(3), no scale) Umeyama alignment of the estimated
positions to the ground truth, or after aligning the first poses (``alignment='first'``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ros2_mos.core.errors import DatasetError

SEGMENT_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
STEP_SIZE = 10  # every 10th frame starts a segment (the devkit's step_size)
ALIGNMENTS = ("se3", "first", "none")


@dataclass(frozen=True)
class SegmentErrors:
    """One entry per evaluated segment (the devkit's ``errors`` struct), as arrays."""

    first_frame: np.ndarray  # (S,) int
    length: np.ndarray  # (S,) segment length in m
    t_err: np.ndarray  # (S,) translational error per metre (fraction)
    r_err: np.ndarray  # (S,) rotational error in rad per metre

    def __len__(self) -> int:
        return len(self.length)

    @staticmethod
    def concatenate(parts: list["SegmentErrors"]) -> "SegmentErrors":
        """Pool the segments of several sequences (the devkit averages over all of them)."""
        if not parts:
            return SegmentErrors(np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros(0))
        return SegmentErrors(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in ("first_frame", "length", "t_err", "r_err"))
        )

    @property
    def translation_pct(self) -> float:
        """Mean relative translational error in % (NaN when no segment fits the trajectory)."""
        return float(100.0 * self.t_err.mean()) if len(self) else float("nan")

    @property
    def rotation_deg_per_100m(self) -> float:
        """Mean relative rotational error in deg / 100 m (NaN when no segment fits)."""
        return float(np.degrees(self.r_err.mean()) * 100.0) if len(self) else float("nan")


@dataclass(frozen=True)
class OdometryErrors:
    """The numbers one trajectory gets: KITTI relative errors and ATE."""

    translation_pct: float
    rotation_deg_per_100m: float
    ate_rmse: float  # m
    alignment: str
    n_segments: int
    path_length: float  # m, of the ground truth
    segments: SegmentErrors = field(repr=False)


def _check_pair(gt: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gt = np.asarray(gt, dtype=np.float64)
    est = np.asarray(est, dtype=np.float64)
    if gt.ndim != 3 or gt.shape[1:] != (4, 4) or est.shape != gt.shape:
        raise DatasetError(f"need two (N, 4, 4) pose arrays of equal length, got {gt.shape} and {est.shape}")
    if len(gt) < 2:
        raise DatasetError(f"need at least 2 poses to evaluate a trajectory, got {len(gt)}")
    return gt, est


def to_camera_frame(lidar_poses: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """LiDAR poses to KITTI camera poses ``Tr @ L @ inv(Tr)`` (what ``poses.txt`` holds)."""
    tr = np.asarray(tr, dtype=np.float64)
    return tr @ np.asarray(lidar_poses, dtype=np.float64) @ np.linalg.inv(tr)


def trajectory_distances(poses: np.ndarray) -> np.ndarray:
    """Cumulative path length at every pose (``dist[0] = 0``), the devkit's ``trajectoryDistances``."""
    t = np.asarray(poses, dtype=np.float64)[:, :3, 3]
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(t, axis=0), axis=1))])


def last_frames(dist: np.ndarray, first: np.ndarray, length: float) -> np.ndarray:
    """The devkit's ``lastFrameFromSegmentLength`` for many first frames: -1 where the path ends first.

    The first index ``i`` with ``dist[i] > dist[first] + length``; ``dist`` never decreases,
    so a right-sided binary search finds it.
    """
    last = np.searchsorted(dist, dist[first] + length, side="right")
    return np.where(last < len(dist), last, -1)


def rotation_angles(rotations: np.ndarray) -> np.ndarray:
    """Angle of each (..., 3, 3) rotation, as the devkit's ``rotationError``."""
    d = 0.5 * (np.trace(rotations, axis1=-2, axis2=-1) - 1.0)
    return np.arccos(np.clip(d, -1.0, 1.0))


def segment_errors(
    gt: np.ndarray, est: np.ndarray, lengths: tuple[float, ...] = SEGMENT_LENGTHS, step: int = STEP_SIZE
) -> SegmentErrors:
    """Every segment's error (the devkit's ``calcSequenceErrors``), vectorised over first frames."""
    gt, est = _check_pair(gt, est)
    if step < 1 or not lengths or min(lengths) <= 0:
        raise DatasetError(f"segment step must be >= 1 and lengths positive, got step {step}, lengths {lengths}")
    dist = trajectory_distances(gt)
    firsts = np.arange(0, len(gt), step)
    out_first, out_len, out_t, out_r = [], [], [], []
    for length in lengths:
        last = last_frames(dist, firsts, length)
        ok = last >= 0
        f, last_ok = firsts[ok], last[ok]
        if len(f) == 0:
            continue
        delta_gt = np.linalg.inv(gt[f]) @ gt[last_ok]
        delta_est = np.linalg.inv(est[f]) @ est[last_ok]
        err = np.linalg.inv(delta_est) @ delta_gt
        out_first.append(f)
        out_len.append(np.full(len(f), float(length)))
        out_t.append(np.linalg.norm(err[:, :3, 3], axis=1) / length)
        out_r.append(rotation_angles(err[:, :3, :3]) / length)
    if not out_first:
        return SegmentErrors.concatenate([])
    return SegmentErrors(
        np.concatenate(out_first), np.concatenate(out_len), np.concatenate(out_t), np.concatenate(out_r)
    )


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``R, t, s`` with ``target ~ s R source + t`` (Umeyama 1991) for (N, 3) point sets."""
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / xs.var(axis=0).sum()) if with_scale else 1.0
    return rot, mu_d - scale * rot @ mu_s, scale


def ate_rmse(gt: np.ndarray, est: np.ndarray, alignment: str = "se3") -> float:
    """Absolute trajectory error: RMSE of positions after ``alignment`` ('se3', 'first' or 'none')."""
    gt, est = _check_pair(gt, est)
    if alignment not in ALIGNMENTS:
        raise DatasetError(f"ATE alignment must be one of {ALIGNMENTS}, got {alignment!r}")
    if alignment == "first":
        est = gt[0] @ np.linalg.inv(est[0]) @ est
    p_gt, p_est = gt[:, :3, 3], est[:, :3, 3]
    if alignment == "se3":
        rot, t, _ = umeyama(p_est, p_gt)
        p_est = p_est @ rot.T + t
    return float(np.sqrt(np.mean(np.sum((p_gt - p_est) ** 2, axis=1))))


def evaluate_trajectory(
    gt: np.ndarray,
    est: np.ndarray,
    lengths: tuple[float, ...] = SEGMENT_LENGTHS,
    step: int = STEP_SIZE,
    alignment: str = "se3",
) -> OdometryErrors:
    """KITTI relative errors plus ATE for one trajectory (poses in the same frame convention)."""
    seg = segment_errors(gt, est, lengths, step)
    return OdometryErrors(
        translation_pct=seg.translation_pct,
        rotation_deg_per_100m=seg.rotation_deg_per_100m,
        ate_rmse=ate_rmse(gt, est, alignment),
        alignment=alignment,
        n_segments=len(seg),
        path_length=float(trajectory_distances(gt)[-1]),
        segments=seg,
    )
