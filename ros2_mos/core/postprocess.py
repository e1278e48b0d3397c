"""Back-projection of per-pixel predictions to every point of the scan.

A range image keeps one point per pixel; the others (and points that share a
pixel with an object's edge) would inherit a wrong label from a plain lookup.
RangeNet++'s kNN post-processing fixes that: for each point, look at the
``window`` x ``window`` pixels around its own, weight their range difference to
the point by an inverse Gaussian of the pixel offset, take the ``k`` closest, drop
those farther than ``cutoff`` metres, and vote.  We vote with probabilities (the
mean moving probability of the kept neighbours), so label and probability agree;
the point's own pixel is always one of the k.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core import kernels
from ros2_mos.core.config import PostprocessConfig
from ros2_mos.core.projection import PixelIndex

# Range given to empty pixels: far beyond any cut-off, so they never vote.
_EMPTY_RANGE = 1e9


def _inverse_gaussian(window: int, sigma: float) -> np.ndarray:
    """1 − normalised Gaussian over the window offsets (RangeNet++'s ``inv_gauss_k``)."""
    half = window // 2
    offs = np.arange(-half, half + 1, dtype=np.float64)
    g = np.exp(-(offs[:, None] ** 2 + offs[None, :] ** 2) / (2.0 * sigma * sigma))
    g /= g.sum()
    return (1.0 - g).astype(np.float32).ravel()


def nearest_backproject(prob_image: np.ndarray, pixels: PixelIndex) -> np.ndarray:
    """Each point takes its own pixel's probability."""
    return prob_image[pixels.v, pixels.u].astype(np.float32)


def _wrap_pad(image: np.ndarray, half: int, fill: float) -> np.ndarray:
    """Pad rows with ``fill`` and columns by wrapping around (the image spans 360 deg in azimuth)."""
    w = image.shape[1]
    padded = np.pad(image.astype(np.float32), ((half, half), (0, 0)), constant_values=fill)
    return np.concatenate([padded[:, w - half :], padded, padded[:, :half]], axis=1) if half else padded


def _window_mixed(prob_image: np.ndarray, window: int, threshold: float) -> np.ndarray:
    """Pixels whose window holds probabilities on both sides of ``threshold`` (empty pixels included).

    Thresholding first turns the window's min/max into a window "any" of two boolean
    images, and "any" over a square is separable: one pass along the (wrapped) columns,
    one along the (padded) rows -- 2 x window array operations instead of window².
    """
    half = window // 2
    h, w = prob_image.shape
    flags = np.empty((2, h, w), dtype=bool)
    np.less(prob_image, threshold, out=flags[0])
    np.logical_not(flags[0], out=flags[1])
    cols = np.concatenate([flags[:, :, w - half :], flags, flags[:, :, :half]], axis=2) if half else flags
    across = cols[:, :, :w].copy()
    for dc in range(1, window):
        across |= cols[:, :, dc : dc + w]
    rows = np.zeros((2, h + 2 * half, w), dtype=bool)
    rows[:, half : half + h] = across
    both = rows[:, :h].copy()
    for dr in range(1, window):
        both |= rows[:, dr : dr + h]
    return both[0] & both[1]


def knn_backproject(
    prob_image: np.ndarray,
    range_image: np.ndarray,
    pixels: PixelIndex,
    config: PostprocessConfig,
    threshold: float | None = None,
) -> np.ndarray:
    """Per-point moving probability by kNN over the range image (see module docstring).

    With a ``threshold``, the vote is computed only for points whose window holds
    probabilities on both sides of it: elsewhere every possible vote gives the same
    label, so those points keep their own pixel's probability.  Labels are identical
    to the full computation; on a typical scan this skips over 90% of the work.
    """
    if len(pixels.u) == 0:
        return np.empty(0, np.float32)
    if kernels.enabled():  # the same vote compiled, eight points at a time (benchmarks/experiments.md, Speed)
        return kernels.knn_vote(prob_image, range_image, pixels.u, pixels.v, pixels.range, config.window, config.k,
                                _inverse_gaussian(config.window, config.sigma), config.cutoff, threshold)
    if threshold is None:
        return _knn_vote(prob_image, range_image, pixels, config)
    flat = pixels.v.astype(np.intp) * prob_image.shape[1] + pixels.u
    out = np.take(prob_image.ravel(), flat).astype(np.float32, copy=False)
    mixed = np.flatnonzero(np.take(_window_mixed(prob_image, config.window, threshold).ravel(), flat))
    if len(mixed):
        subset = PixelIndex(pixels.u[mixed], pixels.v[mixed], pixels.range[mixed], pixels.in_image[mixed])
        out[mixed] = _knn_vote(prob_image, range_image, subset, config)
    return out


def _knn_vote(
    prob_image: np.ndarray, range_image: np.ndarray, pixels: PixelIndex, config: PostprocessConfig
) -> np.ndarray:
    h, w = range_image.shape
    half = config.window // 2
    # Pad rows with "no return" and wrap columns (the image is 360 deg in azimuth), so every
    # window is a fixed set of flat offsets: no bounds checks, no masks per neighbour.
    rng = _wrap_pad(np.where(range_image > 0, range_image, _EMPTY_RANGE), half, _EMPTY_RANGE)
    prob = _wrap_pad(prob_image, half, 0.0)
    pw = w + 2 * half
    offsets = np.arange(-half, half + 1, dtype=np.int64)
    window_offsets = (np.repeat(offsets, config.window) * pw + np.tile(offsets, config.window))[None, :]
    flat = ((pixels.v.astype(np.int64) + half) * pw + pixels.u + half)[:, None] + window_offsets
    dist = np.take(rng.reshape(-1), flat)
    dist -= pixels.range[:, None]
    np.abs(dist, out=dist)
    dist *= _inverse_gaussian(config.window, config.sigma)[None, :]
    # The point's own pixel, at the point's own range, is always among the k (ties with
    # neighbours at distance 0 would otherwise make the choice arbitrary).
    dist[:, (config.window * config.window) // 2] = -1.0
    if config.k < dist.shape[1]:
        # The k-th smallest distance bounds the k nearest; a partition is ~3x cheaper than an argpartition.
        kth = np.partition(dist, config.k - 1, axis=1)[:, config.k - 1 : config.k]
        keep = (dist <= kth) & (dist <= config.cutoff)
    else:
        keep = dist <= config.cutoff
    probs = np.take(prob.reshape(-1), flat)
    total = np.einsum("ij,ij->i", probs, keep.astype(np.float32))
    # The own pixel is always kept, so every point has at least one vote.
    return (total / keep.sum(axis=1)).astype(np.float32)


def backproject(
    prob_image: np.ndarray,
    range_image: np.ndarray,
    pixels: PixelIndex,
    config: PostprocessConfig,
    threshold: float | None = None,
) -> np.ndarray:
    """Per-point moving probability with the configured mode (see :func:`knn_backproject` for ``threshold``)."""
    if config.mode == "nearest":
        return nearest_backproject(prob_image, pixels)
    return knn_backproject(prob_image, range_image, pixels, config, threshold)
