"""Residual images (paper Sec. III-B): how much a past scan disagrees with the current one.

A past scan j is moved into the current frame with the relative pose
``inv(T_0) @ T_j``, re-projected, and compared pixel by pixel::

    d_j = |r_0 − r_j→0| / r_0      where both ranges lie in (min_range, max_range), else 0

or, signed, ``(r_j→0 − r_0) / r_0``: positive where the past ray passed farther than the
current point (that space was free: something moved in), negative where a past return
came from closer (something moved away, or the current point was hidden behind it).
The (2, 50) m window and the normalisation by the current range are those of the
LiDAR-MOS reference code.

The re-projection only approximates the past scan's rays: near the ego, a static surface that the
past scan saw from another side (a parked car being passed) re-projects with gaps through which
farther past points show, and reads as "moved in". :func:`free_space_image` asks the past scan's
own rays instead: each current point is moved into the past scan's frame and compared with the
range that the past scan measured in that direction, ``(r_j(q) − |q|) / |q|``: positive where
the past ray passed beyond the point (its place was free then: it moved in), negative where the
past scan saw something closer (the point was hidden then: no evidence).
"""

from __future__ import annotations

from typing import Callable, Iterable, Iterator, Sequence, TypeVar

import numpy as np

from ros2_mos.core import kernels
from ros2_mos.core.config import ResidualConfig, SensorConfig
from ros2_mos.core.projection import check_points, pixel_index_columns, project_range_columns, xyz_planes

T = TypeVar("T")


def transform_points(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points (float32 out)."""
    return np.ascontiguousarray(transform_columns(check_points(points), transform).T)


def transform_columns(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """The transformed (N, 3) points as a contiguous (3, N) float32 array: x, y, z rows.

    Element-wise rather than a matmul: a (N, 3) @ (3, 3) product goes to the BLAS, whose
    threads then spin and steal the cores KISS-ICP and ONNX Runtime need next.  The
    columns are made contiguous first so that the twelve multiply-adds are SIMD loops.
    """
    t = np.asarray(transform, dtype=np.float64)
    x, y, z = np.array(points.T, dtype=np.float32, order="C")
    out = np.empty((3, len(x)), dtype=np.float32)
    for i in range(3):
        np.multiply(x, np.float32(t[i, 0]), out=out[i])
        out[i] += y * np.float32(t[i, 1])
        out[i] += z * np.float32(t[i, 2])
        out[i] += np.float32(t[i, 3])
    return out


def relative_pose(current_pose: np.ndarray, past_pose: np.ndarray) -> np.ndarray:
    """The transform taking points of the past scan's frame into the current scan's frame."""
    return np.linalg.inv(current_pose) @ past_pose


def scans_at_offsets(past_scans: Sequence[T], offsets: Sequence[int]) -> list[T]:
    """The buffered scans ``offsets`` back (newest first, 1 = the previous scan) that the buffer holds yet."""
    return [past_scans[o - 1] for o in offsets if o <= len(past_scans)]


def residual_image(
    current_range: np.ndarray, past_range: np.ndarray, config: ResidualConfig, signed: bool = False
) -> np.ndarray:
    """|r_0 − r_j| / r_0 (or signed, (r_j − r_0) / r_0) where both ranges lie inside the window, 0 elsewhere."""
    lo, hi = config.min_range, config.upper
    if kernels.enabled():
        return kernels.residual(current_range, past_range, lo, hi, signed)
    valid = (current_range > lo) & (current_range < hi) & (past_range > lo) & (past_range < hi)
    out = np.zeros_like(current_range, dtype=np.float32)
    r0 = current_range[valid]
    diff = (past_range[valid] - r0) / r0
    out[valid] = diff if signed else np.abs(diff)
    return out


def past_range_image(
    past_points: np.ndarray, past_pose: np.ndarray, current_pose: np.ndarray, sensor: SensorConfig
) -> np.ndarray:
    """The range image of a past scan as seen from the current scan's pose."""
    if kernels.enabled():  # moved and projected in one pass
        return kernels.range_image(check_points(past_points, "past points"), sensor,
                                   relative_pose(current_pose, past_pose))
    x, y, z = transform_columns(check_points(past_points, "past points"), relative_pose(current_pose, past_pose))
    return project_range_columns(x, y, z, sensor)


def residual_images(
    current_range: np.ndarray,
    current_pose: np.ndarray,
    past_scans: list[tuple[np.ndarray, np.ndarray]],
    n: int,
    sensor: SensorConfig,
    config: ResidualConfig,
    map_fn: Callable[..., Iterable] = map,
    offsets: Sequence[int] | None = None,
    signed: bool = False,
) -> np.ndarray:
    """(n, H, W) residuals against the past scans, newest first; missing ones stay 0.

    ``offsets`` (default 1..n) says how many scans back each residual's past scan is:
    residual k compares with ``past_scans[offsets[k] - 1]``.

    ``map_fn`` may be a thread pool's ``map``: numpy releases the GIL in the heavy
    ufuncs, so the re-projections of several past scans overlap on several cores.

    ``past_scans`` holds (points in their own sensor frame, world pose), newest first.
    Fewer than ``n`` entries happen at a sequence start or after a buffer reset: the
    missing channels are zero, which is what the network saw in training for that case.
    """
    out = np.zeros((n, sensor.height, sensor.width), dtype=np.float32)
    offsets = tuple(offsets) if offsets is not None else tuple(range(1, n + 1))
    if len(offsets) != n:
        raise ValueError(f"{len(offsets)} offsets for {n} residual images")
    chosen = scans_at_offsets(past_scans, offsets)

    def one(scan: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        return residual_image(current_range, past_range_image(scan[0], scan[1], current_pose, sensor), config, signed)

    results: Iterator[np.ndarray] = iter(map_fn(one, chosen))
    for j, image in enumerate(results):
        out[j] = image
    return out


def free_space_image(
    current_xyz: np.ndarray,
    current_mask: np.ndarray,
    past_range: np.ndarray,
    to_past: np.ndarray,
    sensor: SensorConfig,
    config: ResidualConfig,
) -> np.ndarray:
    """(H, W) ``(r_j(q) − |q|) / |q|`` per current pixel, along the past scan's own rays; 0 elsewhere.

    ``current_xyz`` (H, W, 3) holds each current pixel's point, ``current_mask`` (H, W) which pixels
    hold one; ``past_range`` (H, W) is the past scan's own range image (in its own frame) and
    ``to_past`` the 4x4 transform from the current scan's frame into the past scan's. A pixel is 0
    where its point leaves the past image or either range lies outside the residual window.
    """
    return _free_space_against(current_xyz, current_mask, sensor, config)(past_range, to_past)


def _free_space_against(current_xyz: np.ndarray, current_mask: np.ndarray, sensor: SensorConfig,
                        config: ResidualConfig) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``(past_range, to_past) -> free_space_image(...)`` for this scan, with the per-scan work done once: its
    occupied pixels, and their points (numpy) or its contiguous planes (compiled kernels)."""
    occupied = np.flatnonzero(current_mask)
    shape = current_mask.shape
    if kernels.enabled():
        planes = np.ascontiguousarray(xyz_planes(current_xyz), dtype=np.float32)
        return lambda past_range, to_past: kernels.free_space(
            planes, occupied, to_past, sensor, past_range, config.min_range, config.upper).reshape(shape)
    points = current_xyz.reshape(-1, 3)[occupied]
    return lambda past_range, to_past: _free_space(points, occupied, shape, past_range, to_past, sensor, config)


def _free_space(points: np.ndarray, occupied: np.ndarray, shape: tuple[int, ...], past_range: np.ndarray,
                to_past: np.ndarray, sensor: SensorConfig, config: ResidualConfig) -> np.ndarray:
    """:func:`free_space_image` of the (M, 3) points at the flat pixels ``occupied`` of an image of ``shape``."""
    out = np.zeros(int(np.prod(shape)), dtype=np.float32)
    if len(points):
        x, y, z = transform_columns(points, to_past)
        pixels = pixel_index_columns(x, y, z, sensor)
        flat = pixels.v * np.int32(sensor.width)
        flat += pixels.u
        seen = past_range.reshape(-1)[flat]
        here = pixels.range
        lo, hi = np.float32(config.min_range), np.float32(config.upper)
        valid = pixels.in_image & (here > lo) & (here < hi) & (seen > lo) & (seen < hi)
        seen -= here
        seen /= here
        out[occupied[valid]] = seen[valid]
    return out.reshape(shape)


def free_space_images(
    current_xyz: np.ndarray,
    current_mask: np.ndarray,
    current_pose: np.ndarray,
    past_scans: list[tuple[np.ndarray, np.ndarray]],
    offsets: Sequence[int],
    sensor: SensorConfig,
    config: ResidualConfig,
    map_fn: Callable[..., Iterable] = map,
) -> np.ndarray:
    """(len(offsets), H, W) :func:`free_space_image` against the scans ``offsets`` back; missing ones stay 0.

    ``past_scans`` holds (the past scan's own range image, its world pose), newest first.
    """
    out = np.zeros((len(offsets),) + current_mask.shape, dtype=np.float32)
    chosen = scans_at_offsets(past_scans, offsets)
    if not chosen:
        return out
    against = _free_space_against(current_xyz, current_mask, sensor, config)

    def one(scan: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        return against(scan[0], relative_pose(scan[1], current_pose))

    for j, image in enumerate(map_fn(one, chosen)):
        out[j] = image
    return out
