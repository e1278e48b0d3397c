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

from ros2_mos.config import PostprocessConfig
from ros2_mos.projection import PixelIndex


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


def knn_backproject(
    prob_image: np.ndarray, range_image: np.ndarray, pixels: PixelIndex, config: PostprocessConfig
) -> np.ndarray:
    """Per-point moving probability by kNN over the range image (see module docstring)."""
    h, w = range_image.shape
    half = config.window // 2
    n = len(pixels.u)
    if n == 0:
        return np.empty(0, np.float32)
    dv, du = np.meshgrid(np.arange(-half, half + 1), np.arange(-half, half + 1), indexing="ij")
    dv, du = dv.ravel(), du.ravel()
    rows = pixels.v[:, None] + dv[None, :]
    cols = (pixels.u[:, None] + du[None, :]) % w  # the image wraps around in azimuth
    outside = (rows < 0) | (rows >= h)
    flat = np.clip(rows, 0, h - 1) * w + cols
    neighbour_range = range_image.reshape(-1)[flat]
    empty = outside | (neighbour_range <= 0)
    dist = np.abs(neighbour_range - pixels.range[:, None])
    dist[empty] = np.inf
    dist *= _inverse_gaussian(config.window, config.sigma)[None, :]
    # The point's own pixel, at the point's own range, is always among the k (ties with
    # neighbours at distance 0 would otherwise make the choice arbitrary).
    dist[:, (config.window * config.window) // 2] = -1.0
    k = config.k
    if k < dist.shape[1]:
        nearest = np.argpartition(dist, k - 1, axis=1)[:, :k]
    else:
        nearest = np.broadcast_to(np.arange(dist.shape[1]), (n, dist.shape[1]))
    near_dist = np.take_along_axis(dist, nearest, axis=1)
    keep = near_dist <= config.cutoff
    probs = prob_image.reshape(-1)[np.take_along_axis(flat, nearest, axis=1)]
    total = (probs * keep).sum(axis=1)
    count = keep.sum(axis=1)
    own = prob_image[pixels.v, pixels.u]
    return np.where(count > 0, total / np.maximum(count, 1), own).astype(np.float32)


def backproject(
    prob_image: np.ndarray, range_image: np.ndarray, pixels: PixelIndex, config: PostprocessConfig
) -> np.ndarray:
    """Per-point moving probability with the configured mode."""
    if config.mode == "nearest":
        return nearest_backproject(prob_image, pixels)
    return knn_backproject(prob_image, range_image, pixels, config)
