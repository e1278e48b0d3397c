"""A memory of movers: an object seen moving stays moving while it stands where it stopped, for a while.

The network sees motion only: a car that stops at a light has no residual and turns static in its output, while
SemanticKITTI's labels (:mod:`ros2_mos.io.conventions`) keep it moving in every scan in which it is seen. This stage
remembers, in the world frame (the pipeline's pose), the voxels where non-ground pixels were labelled moving, with
the time each was last labelled so. In a later scan a connected non-ground range-image segment
(:func:`~ros2_mos.core.segments.connected_regions`) of which at least ``share`` of the pixels lie in voxels
remembered (labelled moving in at least ``min_scans`` scans, the last within ``max_age`` seconds; or moving now),
and at least one in a remembered voxel, is labelled moving whole: a one-scan false positive is not remembered.
Segments, not voxels, so that the ground and the static things a mover passed (a wall, a parked car: a small share
of their segment lies in its trail) keep their label.

Only the network's own moving pixels refresh the memory, never the ones this stage labelled: the memory of a stop
ends ``max_age`` after the object was last seen moving, so a false positive of the network is remembered for at
most ``max_age`` seconds too. Voxels older than that are forgotten, and at most :data:`MAX_VOXELS` are kept (the
newest). Everything is numpy over the image's non-ground pixels: sorted int64 voxel keys, no per-point loop.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.config import MoverMemoryConfig
from ros2_mos.core.projection import RangeImage
from ros2_mos.core.segments import connected_regions, ground_mask, grow_regions

#: At most this many voxels are remembered (the most recently moving ones are kept): bounded memory.
MAX_VOXELS = 200_000
#: Segments as :func:`~ros2_mos.core.segments.fill_segments` cuts them: neighbours closer than this share of the
#: range (or ``MIN_JUMP`` m) are one surface.
REL_JUMP = 0.05
MIN_JUMP = 0.3
#: A point takes its pixel's memory label when its range is within this share of the pixel's (or ``MIN_JUMP`` m):
#: not the background behind an object's edge, which shares the pixel.
POINT_TOLERANCE = 0.05
_BITS = 21  # bits per axis of a voxel key: +-2^20 voxels around the origin
_OFFSET = 1 << (_BITS - 1)


def voxel_keys(xyz: np.ndarray, voxel_size: float) -> np.ndarray:
    """One int64 key per (N, 3) point: its voxel's integer coordinates packed 21 bits each (clamped)."""
    cells = np.floor(np.asarray(xyz, np.float64) / voxel_size).astype(np.int64)
    np.clip(cells + _OFFSET, 0, (1 << _BITS) - 1, out=cells)
    return (cells[:, 0] << (2 * _BITS)) | (cells[:, 1] << _BITS) | cells[:, 2]


class MoverMemory:
    """The stage: :meth:`apply` raises the labels of remembered movers in one scan and remembers its movers."""

    def __init__(self, config: MoverMemoryConfig, max_voxels: int = MAX_VOXELS) -> None:
        self.config = config
        self.max_voxels = int(max_voxels)
        self._keys = np.zeros(0, np.int64)  # sorted, unique
        self._times = np.zeros(0, np.float64)  # when each voxel was last labelled moving by the network
        self._counts = np.zeros(0, np.int32)  # in how many scans it was, since it was last forgotten

    @property
    def size(self) -> int:
        """How many voxels are remembered."""
        return len(self._keys)

    def reset(self) -> None:
        """Forget every mover (the pipeline's reset: another place, or the poses can no longer be trusted)."""
        self._keys = np.zeros(0, np.int64)
        self._times = np.zeros(0, np.float64)
        self._counts = np.zeros(0, np.int32)

    def remembered(self, keys: np.ndarray, timestamp: float) -> np.ndarray:
        """Which voxel ``keys`` were labelled moving in at least ``min_scans`` scans, the last within ``max_age``
        seconds before ``timestamp``."""
        if not len(self._keys) or not len(keys):
            return np.zeros(len(keys), bool)
        at = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
        return ((self._keys[at] == keys) & (self._times[at] >= timestamp - self.config.max_age)
                & (self._counts[at] >= self.config.min_scans))

    def apply(self, prob_image: np.ndarray, point_prob: np.ndarray, image: RangeImage, pose: np.ndarray,
              timestamp: float, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """The (H, W) probability image and the per-point probabilities with the remembered movers raised to the
        threshold (new arrays where anything changed); the network's moving pixels of this scan are remembered."""
        if not self.config.enabled:
            return prob_image, point_prob
        self._forget(timestamp)
        moving = (prob_image >= threshold) & image.mask
        objects = image.mask & ~ground_mask(image.range, image.xyz[..., 2])
        pixel_ids = np.flatnonzero(objects)
        xyz = image.xyz.reshape(-1, 3)[pixel_ids].astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
        keys = voxel_keys(xyz, self.config.voxel_size)
        now_moving = moving.reshape(-1)[pixel_ids]
        static = ~now_moving
        hit = np.zeros(image.range.size, bool)
        hit[pixel_ids[static]] = self.remembered(keys[static], timestamp)
        self._insert(keys[now_moving], timestamp)
        if not hit.any():
            return prob_image, point_prob
        hit = hit.reshape(image.range.shape)
        regions = connected_regions(objects, image.range, REL_JUMP, MIN_JUMP)
        # At least `share` remembered or moving now, and something remembered (not a segment the network labels
        # partly moving: that is postprocess.segment_fill's business).
        raise_px = grow_regions(hit | moving, regions, self.config.share) & grow_regions(hit, regions, 0.0) & ~moving
        if not raise_px.any():
            return prob_image, point_prob
        pixels = image.pixels
        near = np.abs(pixels.range - image.range[pixels.v, pixels.u]) <= np.maximum(MIN_JUMP,
                                                                                    POINT_TOLERANCE * pixels.range)
        raise_points = raise_px[pixels.v, pixels.u] & pixels.in_image & near
        thr = np.float32(threshold)
        prob_image = np.where(raise_px, np.maximum(prob_image, thr), prob_image)
        point_prob = np.where(raise_points, np.maximum(point_prob, thr), point_prob).astype(point_prob.dtype)
        return prob_image, point_prob

    def _forget(self, timestamp: float) -> None:
        keep = self._times >= timestamp - self.config.max_age
        if not keep.all():
            self._keys, self._times, self._counts = self._keys[keep], self._times[keep], self._counts[keep]

    def _insert(self, keys: np.ndarray, timestamp: float) -> None:
        """Mark ``keys`` moving at ``timestamp`` (the newest time: it replaces any older one)."""
        if not len(keys):
            return
        keys = np.unique(keys)
        counts = np.ones(len(keys), np.int32)
        if len(self._keys):  # the memory holds no expired voxel here (_forget ran): add to the counts
            at = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
            found = self._keys[at] == keys
            counts[found] += np.minimum(self._counts[at[found]], 1 << 20)
        old = ~np.isin(self._keys, keys, assume_unique=True)
        all_keys = np.concatenate([self._keys[old], keys])
        all_times = np.concatenate([self._times[old], np.full(len(keys), float(timestamp))])
        all_counts = np.concatenate([self._counts[old], counts])
        if len(all_keys) > self.max_voxels:  # keep the most recently moving ones
            newest = np.argpartition(-all_times, self.max_voxels - 1)[:self.max_voxels]
            all_keys, all_times, all_counts = all_keys[newest], all_times[newest], all_counts[newest]
        order = np.argsort(all_keys, kind="stable")
        self._keys, self._times, self._counts = all_keys[order], all_times[order], all_counts[order]
