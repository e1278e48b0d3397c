"""The moving threshold of a model, calibrated per point after the kNN vote on validation sequences.

One pass over the sequences: every point's moving probability from the *full* kNN
vote (threshold-free; at any threshold t its label equals what the pipeline's
shortcut vote gives at t) goes into a histogram of static and of moving points, from
which the moving IoU at every threshold follows exactly (to the bin width).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.core.postprocess import backproject
from ros2_mos.core.projection import finite_mask, pixel_index
from ros2_mos.io.labels import IGNORE, MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence

BINS = 100


@dataclass
class ThresholdCurve:
    """Point counts per probability bin; IoU, precision and recall at each bin edge."""

    moving: np.ndarray  # (BINS,) moving points whose probability falls in each bin
    static: np.ndarray  # (BINS,) static points likewise

    @property
    def thresholds(self) -> np.ndarray:
        return np.arange(BINS) / BINS

    def counts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tp, fp, fn) when labelling moving at probability >= each threshold."""
        tp = np.cumsum(self.moving[::-1])[::-1]
        fp = np.cumsum(self.static[::-1])[::-1]
        fn = self.moving.sum() - tp
        return tp, fp, fn

    def iou(self) -> np.ndarray:
        tp, fp, fn = self.counts()
        return tp / np.maximum(tp + fp + fn, 1)

    def iou_at(self, threshold: float) -> float:
        """IoU at the bin edge nearest ``threshold`` (a threshold in (0, 1); above the last edge, the last)."""
        return float(self.iou()[min(int(round(threshold * BINS)), BINS - 1)])

    def best(self, low: float = 0.05, high: float = 0.95) -> tuple[float, float]:
        """(threshold, IoU) of the best IoU with the threshold in [low, high]."""
        t, iou = self.thresholds, self.iou()
        allowed = (t >= low) & (t <= high)
        k = int(np.flatnonzero(allowed)[np.argmax(iou[allowed])])
        return float(t[k]), float(iou[k])


def threshold_curve(pipeline: MosPipeline, sequences: Iterable[SemanticKittiSequence], use_dataset_poses: bool = False,
                    progress: Callable[[], None] | None = None) -> ThresholdCurve:
    """Run the pipeline over labelled sequences and histogram per-point probabilities by ground truth."""
    moving = np.zeros(BINS, np.int64)
    static = np.zeros(BINS, np.int64)
    post = pipeline.config.postprocess
    for sequence in sequences:
        if not sequence.has_labels:
            raise DatasetError(f"{sequence.root}: no labels/ to calibrate on")
        if use_dataset_poses:
            sequence.require_poses("--use-poses")
        pipeline.reset()
        for frame in sequence:
            result = pipeline.process(frame.points, frame.remission, frame.timestamp,
                                      pose=frame.pose if use_dataset_poses else None)
            valid = finite_mask(frame.points)
            pixels = pixel_index(np.ascontiguousarray(frame.points[valid], np.float32), pipeline.sensor)
            prob = backproject(result.probability_image, result.range_image, pixels, post, None)
            gt = to_moving_classes(frame.labels)[valid]
            bins = np.clip((prob * BINS).astype(np.int64), 0, BINS - 1)
            moving += np.bincount(bins[gt == MOVING], minlength=BINS)
            static += np.bincount(bins[(gt != MOVING) & (gt != IGNORE)], minlength=BINS)
            if progress is not None:
                progress()
    return ThresholdCurve(moving, static)
