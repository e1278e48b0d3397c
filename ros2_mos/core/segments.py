"""Range-image segments: connected regions of non-ground pixels, and labels made consistent over them.

A moving car's body often has no residual of its own: when it drives parallel to
the sensor its side slides along itself and keeps its range, and only its front and
back edges light up.  Its points still form one connected segment of the range image
(neighbours whose ranges differ by less than a few percent).  :func:`fill_segments`
labels a whole segment moving when enough of it is, the "a segment moves as a whole"
consistency that geometric MOS methods use.  The baselines' region growing uses the
same segments (:mod:`ros2_mos.scoring.baselines`).  The connected regions run in the compiled kernels
where they are built (the same labels; :mod:`ros2_mos.core.kernels`), else in numpy.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core import kernels


def ground_mask(range_image: np.ndarray, z_image: np.ndarray, margin: float = 0.3) -> np.ndarray:
    """Pixels on the ground: z below the 10th percentile of near points' z, plus a margin."""
    near = (range_image > 0) & (range_image < 20.0)
    if not near.any():
        return np.zeros(range_image.shape, bool)
    return (range_image > 0) & (z_image < _tenth_percentile(z_image[near]) + margin)


def _tenth_percentile(values: np.ndarray) -> float:
    """``np.percentile(values, 10)`` (linear interpolation) from one partial sort and a minimum: a tenth of its
    time (a partial sort at two places costs as much as the percentile)."""
    position = 0.1 * (len(values) - 1)
    lo = int(position)
    part = np.partition(values, lo)
    a = float(part[lo])
    b = float(part[lo + 1:].min()) if lo + 1 < len(values) else a
    return a + (b - a) * (position - lo)


def connected_regions(valid: np.ndarray, rng: np.ndarray, rel: float, min_jump: float = 0.3) -> np.ndarray:
    """Connected components of ``valid`` pixels linked where neighbouring ranges are close.

    Union-find in numpy (no scipy): hook every edge's larger root onto its smaller
    one, compress paths by pointer jumping, repeat until no edge joins two roots
    (a few rounds).  The image wraps around in azimuth.  Returns an (H, W) int64
    label (-1 where not valid); pixels of one region share the smallest pixel id.
    """
    if kernels.enabled():
        return kernels.connected_regions(valid, rng, rel, min_jump)
    h, w = valid.shape
    ids = np.arange(h * w, dtype=np.int64).reshape(h, w)
    right_r = np.roll(rng, -1, axis=1)
    link_right = valid & np.roll(valid, -1, axis=1)
    link_right &= np.abs(rng - right_r) < np.maximum(min_jump, rel * np.minimum(rng, right_r))
    link_down = valid[:-1] & valid[1:]
    link_down &= np.abs(rng[:-1] - rng[1:]) < np.maximum(min_jump, rel * np.minimum(rng[:-1], rng[1:]))
    a = np.concatenate([ids[link_right], ids[:-1][link_down]])
    b = np.concatenate([np.roll(ids, -1, axis=1)[link_right], ids[1:][link_down]])
    return np.where(valid, _union_find(h * w, a, b).reshape(h, w), -1)


def _union_find(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Component label (its smallest member) of each of ``n`` nodes joined by the edges ``a[i]``-``b[i]``."""
    parent = np.arange(n, dtype=np.int64)
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
    return parent


def grow_regions(seeds: np.ndarray, regions: np.ndarray, seed_fraction: float) -> np.ndarray:
    """Pixels of every region (label >= 0, a pixel id) of which at least ``seed_fraction`` (and > 0 pixels) are
    seeds."""
    if kernels.enabled():
        return kernels.grow_regions(seeds, regions, seed_fraction)
    seeds = seeds & (regions >= 0)
    if not seeds.any():
        return np.zeros(seeds.shape, bool)
    lab = regions[regions >= 0]
    size = np.bincount(lab, minlength=regions.size)
    hits = np.bincount(regions[seeds], minlength=regions.size)
    moving_region = (hits >= seed_fraction * np.maximum(size, 1)) & (hits > 0)
    out = np.zeros(seeds.shape, bool)
    out[regions >= 0] = moving_region[lab]
    return out


def fill_segments(prob_image: np.ndarray, range_image: np.ndarray, z_image: np.ndarray, threshold: float,
                  fill_fraction: float, rel_jump: float = 0.05, margin_columns: int = 32) -> np.ndarray:
    """The probability image with every non-ground segment that is at least ``fill_fraction`` moving raised
    to the threshold (so that all of it is labelled moving); other pixels are unchanged.

    Only the columns within ``margin_columns`` of a moving pixel are segmented (the rest cannot change).
    """
    moving = (prob_image >= threshold) & (range_image > 0)
    if not moving.any():
        return prob_image
    near = np.zeros(range_image.shape[1], bool)
    cols = np.flatnonzero(moving.any(axis=0))
    offsets = np.arange(-margin_columns, margin_columns + 1)
    near[(cols[:, None] + offsets[None, :]).ravel() % range_image.shape[1]] = True
    valid = (range_image > 0) & ~ground_mask(range_image, z_image) & near[None, :]
    raise_to = grow_regions(moving, connected_regions(valid, range_image, rel_jump), fill_fraction)
    out = prob_image.copy()
    out[raise_to] = np.maximum(out[raise_to], threshold)
    return out


def drop_small_regions(prob_image: np.ndarray, range_image: np.ndarray, threshold: float, min_pixels: int,
                       rel_jump: float = 0.1, min_jump: float = 0.5) -> np.ndarray:
    """The probability image with every connected moving region of fewer than ``min_pixels`` pixels set to 0.

    Regions are 4-connected moving pixels (probability >= threshold; the image wraps in azimuth) whose
    neighbouring ranges differ by less than ``max(min_jump, rel_jump * range)``: speckle on foliage and at depth
    edges, not an object.  Only the moving pixels are labelled (a few thousand, not the whole image).
    """
    moving = (prob_image >= threshold) & (range_image > 0)
    if min_pixels <= 1 or not moving.any():
        return prob_image
    h, w = moving.shape
    flat = np.flatnonzero(moving)
    compact = np.full(h * w, -1, np.int64)
    compact[flat] = np.arange(len(flat))
    rng = range_image.reshape(-1)
    row, col = np.divmod(flat, w)
    right = row * w + (col + 1) % w
    down = np.where(row < h - 1, flat + w, flat)
    a, b = [], []
    for other in (right, down):
        j = compact[other]
        near = (j >= 0) & (other != flat)
        i, j, r0, r1 = np.flatnonzero(near), j[near], rng[flat[near]], rng[other[near]]
        close = np.abs(r0 - r1) < np.maximum(min_jump, rel_jump * np.minimum(r0, r1))
        a.append(i[close])
        b.append(j[close])
    labels = _union_find(len(flat), np.concatenate(a), np.concatenate(b))
    small = np.bincount(labels, minlength=len(flat))[labels] < min_pixels
    if not small.any():
        return prob_image
    out = prob_image.copy()
    out.reshape(-1)[flat[small]] = 0.0
    return out
