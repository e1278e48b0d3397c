"""The paper's heuristic baselines (Table II): ``Residual`` and ``Residual + RG``.

* **Residual**: a pixel is moving when its newest residual d_1 exceeds τ.  The
  paper reports how poorly this does (1.9 IoU on SemanticKITTI): residuals light up
  twice for every moving object (where it is and where it was) and on every
  occlusion edge.
* **Residual + RG** (after Yoon et al. 2019): *free-space check* + *region growing*.
  Seeds are pixels whose current point lies where both past scans saw free space
  (r_j − r_0 > 0, i.e. the ray passed farther: something moved *in*) with residuals
  d_1, d_2 > τ_seed; the "where it was" ghost fails that sign test.  Seeds are then
  grown over connected non-ground regions of the range image (4-neighbours, range
  jumps below ``max(0.3 m, δ·r)``), and a region is moving when at least a fraction
  ρ of it is seeds.  Ground is removed by height (z below the scan's ground level
  + 0.3 m), as geometric pipelines do.

Thresholds are tuned on the validation sequences by grid search, as the paper
"fix[es] the threshold based on the best MOS performance on the validation set".
Both baselines work on the cached components, so they see exactly the network's inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import Sequence

import numpy as np

from ros2_mos.training.dataset import SequenceCache


@dataclass(frozen=True)
class ResidualThreshold:
    tau: float

    def predict(self, cache: SequenceCache, index: int) -> np.ndarray:
        return np.asarray(cache.residual[index, 0], np.float32) > self.tau


def ground_mask(raw: np.ndarray, margin: float = 0.3) -> np.ndarray:
    """Pixels on the ground: z below the 10th percentile of near points' z, plus a margin."""
    r, z = raw[0], raw[3]
    near = (r > 0) & (r < 20.0)
    if not near.any():
        return np.zeros_like(r, bool)
    ground_z = float(np.percentile(z[near], 10))
    return (r > 0) & (z < ground_z + margin)


def connected_regions(valid: np.ndarray, rng: np.ndarray, rel: float, min_jump: float = 0.3) -> np.ndarray:
    """Connected components of ``valid`` pixels linked where neighbouring ranges are close.

    Union-find in numpy (no scipy): hook every edge's larger root onto its smaller
    one, compress paths by pointer jumping, repeat until no edge joins two roots
    (a few rounds).  The image wraps around in azimuth.  Returns an (H, W) int64
    label (-1 where not valid); pixels of one region share the smallest pixel id.
    """
    h, w = valid.shape
    ids = np.arange(h * w, dtype=np.int64).reshape(h, w)
    right_r = np.roll(rng, -1, axis=1)
    link_right = valid & np.roll(valid, -1, axis=1)
    link_right &= np.abs(rng - right_r) < np.maximum(min_jump, rel * np.minimum(rng, right_r))
    link_down = valid[:-1] & valid[1:]
    link_down &= np.abs(rng[:-1] - rng[1:]) < np.maximum(min_jump, rel * np.minimum(rng[:-1], rng[1:]))
    a = np.concatenate([ids[link_right], ids[:-1][link_down]])
    b = np.concatenate([np.roll(ids, -1, axis=1)[link_right], ids[1:][link_down]])
    parent = ids.reshape(-1).copy()
    while len(a):
        pa, pb = parent[a], parent[b]
        differ = pa != pb
        if not differ.any():
            break
        a, b, pa, pb = a[differ], b[differ], pa[differ], pb[differ]
        np.minimum.at(parent, np.maximum(pa, pb), np.minimum(pa, pb))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    return np.where(valid, parent.reshape(h, w), -1)


@dataclass(frozen=True)
class ResidualRegionGrowing:
    tau_seed: float
    rel_jump: float = 0.05
    seed_fraction: float = 0.2

    def seeds(self, cache: SequenceCache, index: int) -> np.ndarray:
        res = np.asarray(cache.residual[index, :2], np.float32)
        sign = np.asarray(cache.residual_sign[index, :2])
        return (res[0] > self.tau_seed) & (sign[0] > 0) & (res[1] > self.tau_seed) & (sign[1] > 0)

    def predict(self, cache: SequenceCache, index: int, regions: np.ndarray | None = None) -> np.ndarray:
        raw = np.asarray(cache.frame[index], np.float32)
        seeds = self.seeds(cache, index)
        if regions is None:
            valid = (raw[0] > 0) & ~ground_mask(raw)
            regions = connected_regions(valid, raw[0], self.rel_jump)
        seeds &= regions >= 0
        if not seeds.any():
            return np.zeros(seeds.shape, bool)
        lab = regions[regions >= 0]
        size = np.bincount(lab, minlength=regions.size)
        hits = np.bincount(regions[seeds], minlength=regions.size)
        moving_region = hits >= self.seed_fraction * np.maximum(size, 1)
        moving_region &= hits > 0
        out = np.zeros(seeds.shape, bool)
        out[regions >= 0] = moving_region[lab]
        return out


def _pixel_iou(pred: np.ndarray, label: np.ndarray) -> tuple[int, int, int]:
    counted = label >= 0
    gt = label == 1
    return int((pred & gt).sum()), int((pred & ~gt & counted).sum()), int((~pred & gt).sum())


def tune_residual_threshold(caches: Sequence[SequenceCache], taus: Sequence[float], stride: int = 2) -> tuple[ResidualThreshold, dict[float, float]]:
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
    counts: dict[tuple[float, float, float], np.ndarray] = {k: np.zeros(3, np.int64) for k in product(taus, rel_jumps, fractions)}
    for cache in caches:
        for i in range(0, len(cache), stride):
            raw = np.asarray(cache.frame[i], np.float32)
            valid = (raw[0] > 0) & ~ground_mask(raw)
            label = np.asarray(cache.label[i])
            for rel in rel_jumps:
                regions = connected_regions(valid, raw[0], rel)
                for tau, frac in product(taus, fractions):
                    pred = ResidualRegionGrowing(tau, rel, frac).predict(cache, i, regions)
                    counts[(tau, rel, frac)] += _pixel_iou(pred, label)
    scores = {k: float(v[0] / max(v.sum(), 1)) for k, v in counts.items()}
    best = max(scores, key=scores.get)
    return ResidualRegionGrowing(*best), scores
