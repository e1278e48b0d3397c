"""Tuning the heuristic baselines (:mod:`ros2_mos.scoring.baselines`) on cached validation sequences.

Thresholds are tuned on the validation sequences by grid search, as the paper
"fix[es] the threshold based on the best MOS performance on the validation set".
The baselines work on the cached components, so they see exactly the network's inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import Sequence

import numpy as np

from ros2_mos.core.segments import connected_regions, ground_mask
from ros2_mos.scoring.baselines import (
    free_space_seeds,
    grow_regions,
    residual_threshold,
)
from ros2_mos.training.dataset import SequenceCache

__all__ = ["ResidualThreshold", "ResidualRegionGrowing", "connected_regions", "ground_mask",
           "tune_residual_threshold", "tune_region_growing"]


@dataclass(frozen=True)
class ResidualThreshold:
    tau: float

    def predict(self, cache: SequenceCache, index: int) -> np.ndarray:
        return residual_threshold(np.asarray(cache.residual[index, 0], np.float32), self.tau)


@dataclass(frozen=True)
class ResidualRegionGrowing:
    tau_seed: float
    rel_jump: float = 0.05
    seed_fraction: float = 0.2

    def seeds(self, cache: SequenceCache, index: int) -> np.ndarray:
        return free_space_seeds(np.asarray(cache.residual[index, :2], np.float32), self.tau_seed)

    def predict(self, cache: SequenceCache, index: int, regions: np.ndarray | None = None) -> np.ndarray:
        raw = np.asarray(cache.frame[index], np.float32)
        if regions is None:
            valid = (raw[0] > 0) & ~ground_mask(raw[0], raw[3])
            regions = connected_regions(valid, raw[0], self.rel_jump)
        return grow_regions(self.seeds(cache, index), regions, self.seed_fraction)


def _pixel_iou(pred: np.ndarray, label: np.ndarray) -> tuple[int, int, int]:
    counted = label >= 0
    gt = label == 1
    return int((pred & gt).sum()), int((pred & ~gt & counted).sum()), int((~pred & gt).sum())


def tune_residual_threshold(
    caches: Sequence[SequenceCache], taus: Sequence[float], stride: int = 2
) -> tuple[ResidualThreshold, dict[float, float]]:
    """The τ of best pixel IoU on the validation caches."""
    scores: dict[float, float] = {}
    for tau in taus:
        tp = fp = fn = 0
        for cache in caches:
            for i in range(0, len(cache), stride):
                a, b, c = _pixel_iou(ResidualThreshold(tau).predict(cache, i), np.asarray(cache.label[i]))
                tp, fp, fn = tp + a, fp + b, fn + c
        scores[tau] = tp / max(tp + fp + fn, 1)
    best = max(scores, key=scores.get)
    return ResidualThreshold(best), scores


def tune_region_growing(
    caches: Sequence[SequenceCache],
    taus: Sequence[float],
    rel_jumps: Sequence[float],
    fractions: Sequence[float],
    stride: int = 4,
) -> tuple[ResidualRegionGrowing, dict[tuple[float, float, float], float]]:
    """Grid search of (τ_seed, δ, ρ) by pixel IoU on the validation caches."""
    counts: dict[tuple[float, float, float], np.ndarray] = {
        k: np.zeros(3, np.int64) for k in product(taus, rel_jumps, fractions)
    }
    for cache in caches:
        for i in range(0, len(cache), stride):
            raw = np.asarray(cache.frame[i], np.float32)
            valid = (raw[0] > 0) & ~ground_mask(raw[0], raw[3])
            label = np.asarray(cache.label[i])
            for rel in rel_jumps:
                regions = connected_regions(valid, raw[0], rel)
                for tau, frac in product(taus, fractions):
                    pred = ResidualRegionGrowing(tau, rel, frac).predict(cache, i, regions)
                    counts[(tau, rel, frac)] += _pixel_iou(pred, label)
    scores = {k: float(v[0] / max(v.sum(), 1)) for k, v in counts.items()}
    best = max(scores, key=scores.get)
    return ResidualRegionGrowing(*best), scores
