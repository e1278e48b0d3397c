"""Moving-object IoU exactly as the SemanticKITTI MOS benchmark computes it.

Ground truth is mapped with :func:`ros2_mos.io.labels.to_moving_classes`; points whose
ground truth is ignored (0 unlabeled, 1 outlier) count for nothing.  Counts are
accumulated over all scans of a sequence (and over sequences) before dividing,
not averaged per scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.labels import IGNORE, MOVING


@dataclass
class MovingIoU:
    """Confusion counts of the moving class; add scans with :meth:`update`, then read :attr:`iou`."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def update(self, predicted_moving: np.ndarray, gt_classes: np.ndarray) -> "MovingIoU":
        """Add one scan: predicted bool/0-1 per point, ground truth in {-1 ignore, 0 static, 1 moving}."""
        pred = np.asarray(predicted_moving).astype(bool).reshape(-1)
        gt = np.asarray(gt_classes).reshape(-1)
        if pred.shape != gt.shape:
            raise DatasetError(f"{len(pred)} predictions for {len(gt)} ground-truth labels")
        counted = gt != IGNORE
        gt_moving = gt == MOVING
        self.tp += int(np.count_nonzero(pred & gt_moving & counted))
        self.fp += int(np.count_nonzero(pred & ~gt_moving & counted))
        self.fn += int(np.count_nonzero(~pred & gt_moving & counted))
        self.tn += int(np.count_nonzero(~pred & ~gt_moving & counted))
        return self

    def __add__(self, other: "MovingIoU") -> "MovingIoU":
        return MovingIoU(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    @property
    def iou(self) -> float:
        """TP / (TP + FP + FN); NaN when the class appears neither in predictions nor ground truth."""
        union = self.tp + self.fp + self.fn
        return self.tp / union if union else float("nan")

    @property
    def static_iou(self) -> float:
        union = self.tn + self.fn + self.fp
        return self.tn / union if union else float("nan")
