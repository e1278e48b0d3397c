"""Where a model's errors sit: recall per ground-truth mover, and moving recall and false positives by range and class.

The moving IoU says how much is wrong, not what. Error analysis (benchmarks/experiments.md, rows 22 and 24) needs
the missed movers one by one, each with how far away it was and how fast it moved, and the false positives by
class and range. :class:`ErrorBreakdown` takes scans one at a time, as :class:`~ros2_mos.scoring.metrics.MovingIoU`
does, and counts only points the benchmark counts (ground truth 0 unlabeled and 1 outlier are left out).

A mover is one (sequence, instance id, semantic id) of SemanticKITTI labels: moving points without an instance id
form one mover per class and sequence. Its speed is that of the centroid of its labelled points in the world frame
(the sequence's poses), over about :data:`SPEED_BASELINE` seconds; the median over its scans. The centroid of what
a sensor sees of an object shifts as the view changes, so the speed is an estimate; without poses it is not given
(NaN). Points with a non-finite coordinate are left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.labels import IGNORE, MOVING, SEMANTIC_NAMES, instance_ids, semantic_ids, to_moving_classes

#: Range bands (m) of :meth:`ErrorBreakdown.by_range`; the last one is open.
RANGE_BANDS: tuple[float, ...] = (0.0, 10.0, 20.0, 40.0)
#: Seconds between the two centroids of a mover's speed estimate (at least this, at most 3x).
SPEED_BASELINE = 0.5
_MAX_SEMANTIC = 1 << 16


def class_name(semantic_id: int) -> str:
    return SEMANTIC_NAMES.get(semantic_id, f"id {semantic_id}")


@dataclass(frozen=True)
class MoverScore:
    """One ground-truth mover over every scan it appears in."""

    sequence: str
    instance: int
    semantic: int
    scans: int
    points: int
    found: int
    median_range: float  # m, of its per-scan centroid from the sensor
    speed: float  # m/s, median; NaN without poses or with too few scans

    @property
    def recall(self) -> float:
        return self.found / self.points

    @property
    def missed(self) -> int:
        return self.points - self.found

    @property
    def label(self) -> str:
        return class_name(self.semantic)


@dataclass(frozen=True)
class RangeBand:
    """Moving points, those found, and false positives (static points labelled moving) from ``low`` to ``high`` m."""

    low: float
    high: float
    moving: int
    found: int
    false_positives: int

    @property
    def recall(self) -> float:
        return self.found / self.moving if self.moving else float("nan")

    @property
    def name(self) -> str:
        return f"{self.low:g}-{self.high:g} m" if math.isfinite(self.high) else f">= {self.low:g} m"


@dataclass
class _Track:
    times: list[float] = field(default_factory=list)
    world_centroids: list[np.ndarray] = field(default_factory=list)
    ranges: list[float] = field(default_factory=list)
    points: int = 0
    found: int = 0


def _median_speed(times: list[float], centroids: list[np.ndarray]) -> float:
    """Median of |c_j - c_i| / (t_j - t_i) over pairs i < j whose gap is the first one >= SPEED_BASELINE (<= 3x)."""
    if len(times) < 2 or not centroids:
        return float("nan")
    t = np.asarray(times)
    c = np.asarray(centroids)
    j = np.searchsorted(t, t + SPEED_BASELINE - 1e-9)
    ok = j < len(t)
    i, j = np.flatnonzero(ok), j[ok]
    gap = t[j] - t[i]
    keep = gap <= 3 * SPEED_BASELINE
    if not keep.any():
        return float("nan")
    i, j, gap = i[keep], j[keep], gap[keep]
    return float(np.median(np.linalg.norm(c[j] - c[i], axis=1) / gap))


class ErrorBreakdown:
    """Accumulates scans; read :meth:`movers`, :meth:`by_range` and :meth:`false_positives_by_class`."""

    def __init__(self, bands: tuple[float, ...] = RANGE_BANDS) -> None:
        edges = np.asarray(bands, np.float64)
        if len(edges) < 1 or not np.all(np.isfinite(edges)) or edges[0] != 0 or np.any(np.diff(edges) <= 0):
            raise ValueError(f"range bands must start at 0 and increase, got {bands}")
        self._edges = edges
        self._band_moving = np.zeros(len(edges), np.int64)
        self._band_found = np.zeros(len(edges), np.int64)
        self._band_fp = np.zeros(len(edges), np.int64)
        self._fp_by_class = np.zeros(_MAX_SEMANTIC, np.int64)
        self._tracks: dict[tuple[str, int, int], _Track] = {}
        self.scans = 0

    def update(self, sequence: str, points: np.ndarray, raw_labels: np.ndarray, predicted_moving: np.ndarray,
               pose: np.ndarray | None, timestamp: float) -> None:
        """Add one scan: (N, 3) points in the sensor frame, raw uint32 labels, bool/0-1 predictions per point, the
        sensor's (4, 4) pose in the world frame (None: no speeds) and the scan's time in seconds."""
        xyz = np.asarray(points, np.float64).reshape(-1, 3)
        raw = np.asarray(raw_labels).reshape(-1)
        pred = np.asarray(predicted_moving).astype(bool).reshape(-1)
        if not len(xyz) == len(raw) == len(pred):
            raise DatasetError(f"{sequence}: {len(xyz)} points, {len(raw)} labels and {len(pred)} predictions")
        if pose is not None and np.shape(pose) != (4, 4):
            raise DatasetError(f"{sequence}: a pose must be 4 x 4, got {np.shape(pose)}")
        if not math.isfinite(timestamp):
            raise DatasetError(f"{sequence}: scan time {timestamp} is not finite")
        self.scans += 1
        finite = np.isfinite(xyz).all(axis=1)
        if not finite.all():
            xyz, raw, pred = xyz[finite], raw[finite], pred[finite]
        gt = to_moving_classes(raw)
        counted = gt != IGNORE
        moving = gt == MOVING
        rng = np.linalg.norm(xyz, axis=1)
        band = np.clip(np.searchsorted(self._edges, rng, side="right") - 1, 0, len(self._edges) - 1)
        n_bands = len(self._edges)
        self._band_moving += np.bincount(band[moving], minlength=n_bands)
        self._band_found += np.bincount(band[moving & pred], minlength=n_bands)
        fp = pred & ~moving & counted
        self._band_fp += np.bincount(band[fp], minlength=n_bands)
        self._fp_by_class += np.bincount(semantic_ids(raw[fp]), minlength=_MAX_SEMANTIC)
        if not moving.any():
            return
        mover_raw, mover_xyz = raw[moving], xyz[moving]
        keys, which = np.unique(np.stack([instance_ids(mover_raw), semantic_ids(mover_raw)], axis=1), axis=0,
                                return_inverse=True)
        which = which.reshape(-1)
        counts = np.bincount(which, minlength=len(keys))
        found = np.bincount(which, weights=pred[moving], minlength=len(keys))
        centroids = np.stack([np.bincount(which, weights=mover_xyz[:, k], minlength=len(keys)) for k in range(3)],
                             axis=1) / counts[:, None]
        world = None if pose is None else np.asarray(pose, np.float64)
        for k, (instance, semantic) in enumerate(keys):
            track = self._tracks.setdefault((sequence, int(instance), int(semantic)), _Track())
            track.points += int(counts[k])
            track.found += int(found[k])
            track.ranges.append(float(np.linalg.norm(centroids[k])))
            track.times.append(float(timestamp))
            if world is not None:
                track.world_centroids.append(world[:3, :3] @ centroids[k] + world[:3, 3])

    def movers(self) -> list[MoverScore]:
        """Every mover, most missed points first."""
        out = []
        for (sequence, instance, semantic), track in self._tracks.items():
            order = np.argsort(track.times, kind="stable")
            times = [track.times[i] for i in order]
            # Speeds need a pose for every scan of the mover.
            centroids = ([track.world_centroids[i] for i in order]
                         if len(track.world_centroids) == len(track.times) else [])
            out.append(MoverScore(sequence, instance, semantic, len(track.times), track.points, track.found,
                                  float(np.median(track.ranges)), _median_speed(times, centroids)))
        return sorted(out, key=lambda m: (-m.missed, m.sequence, m.instance, m.semantic))

    def by_range(self) -> list[RangeBand]:
        highs = list(self._edges[1:]) + [math.inf]
        return [RangeBand(float(lo), float(hi), int(m), int(f), int(fp)) for lo, hi, m, f, fp in
                zip(self._edges, highs, self._band_moving, self._band_found, self._band_fp)]

    def false_positives_by_class(self) -> list[tuple[int, int]]:
        """(semantic id, static points labelled moving), most first; classes with none are left out."""
        ids = np.flatnonzero(self._fp_by_class)
        return sorted(((int(i), int(self._fp_by_class[i])) for i in ids), key=lambda x: (-x[1], x[0]))
