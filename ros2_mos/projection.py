"""Spherical range projection Π of a scan (paper eq. 1), and the indices to go back.

For each point p = (x, y, z) with range r = |p|::

    u = ½ (1 − atan2(y, x) / π) · w
    v = (1 − (asin(z / r) + |f_down|) / f) · h

floored to integer pixels.  When several points fall on one pixel the closest one
wins, as in LiDAR-MOS/RangeNet++.  Every point keeps its (u, v) so that labels of
the image can be carried back to all points, including those that lost their pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.config import SensorConfig
from ros2_mos.errors import ScanError

@dataclass
class PixelIndex:
    """Where each point lands: its pixel (clamped into the image) and whether it lies inside."""

    u: np.ndarray  # (N,) int32 column
    v: np.ndarray  # (N,) int32 row
    range: np.ndarray  # (N,) float32
    in_image: np.ndarray  # (N,) bool: inside the vertical fov and the sensor's range limits


@dataclass
class RangeImage:
    """A projected scan: the per-pixel channels of the network input and the per-point index."""

    range: np.ndarray  # (H, W) float32, 0 where no point
    xyz: np.ndarray  # (H, W, 3) float32
    remission: np.ndarray  # (H, W) float32
    point_index: np.ndarray  # (H, W) int32 index of the pixel's point in the input, -1 where empty
    pixels: PixelIndex

    @property
    def mask(self) -> np.ndarray:
        """Pixels that hold a point."""
        return self.point_index >= 0


def check_points(points: np.ndarray, what: str = "points") -> np.ndarray:
    """Return ``points`` as an (N, 3) float array or raise ScanError naming the problem."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ScanError(f"{what} must be an (N, 3) array of x, y, z, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ScanError(f"{what} must be floating point, got dtype {arr.dtype}")
    return arr


def pixel_index(points: np.ndarray, sensor: SensorConfig) -> PixelIndex:
    """Compute each point's pixel; points must be finite with positive range (see ``finite_mask``)."""
    pts = check_points(points)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        r = np.sqrt(x * x + y * y + z * z)
        pitch = np.arcsin(np.clip(z / r, -1.0, 1.0, dtype=r.dtype))
    yaw = np.arctan2(y, x)
    u_f = 0.5 * (1.0 - yaw / np.pi) * sensor.width
    v_f = (1.0 - (pitch - sensor.fov_down) / sensor.fov) * sensor.height
    in_image = (v_f >= 0.0) & (v_f < sensor.height) & (r > sensor.min_range) & (r < sensor.max_range)
    u = np.clip(np.floor(u_f), 0, sensor.width - 1).astype(np.int32)
    v = np.clip(np.floor(v_f), 0, sensor.height - 1).astype(np.int32)
    return PixelIndex(u=u, v=v, range=r.astype(np.float32), in_image=in_image)


def closest_per_pixel(pixels: PixelIndex, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The closest range per pixel, and for every occupied pixel its id and the index of its closest point.

    ``np.minimum.at`` gives the per-pixel minimum in one unbuffered pass (no sort, and
    no reliance on numpy's unspecified order for repeated fancy-index assignment);
    the point whose range equals its pixel's minimum is the winner.
    """
    candidates = np.flatnonzero(pixels.in_image)
    pix = pixels.v[candidates] * width + pixels.u[candidates]
    r = pixels.range[candidates]
    best = np.full(height * width, np.inf, dtype=np.float32)
    np.minimum.at(best, pix, r)
    winner = r == best[pix]
    # Exact ties (two points at the same range on one pixel) keep the last one written.
    point_of_pixel = np.full(height * width, -1, dtype=np.int32)
    point_of_pixel[pix[winner]] = candidates[winner]
    occupied = np.flatnonzero(point_of_pixel >= 0)
    best[~np.isfinite(best)] = 0.0
    return best, occupied, point_of_pixel[occupied]


def project(points: np.ndarray, remission: np.ndarray, sensor: SensorConfig) -> RangeImage:
    """Project a scan of finite points with positive range to a full range image."""
    pts = check_points(points)
    rem = np.asarray(remission, dtype=np.float32).reshape(-1)
    if len(rem) != len(pts):
        raise ScanError(f"remission has {len(rem)} values for {len(pts)} points")
    pixels = pixel_index(pts, sensor)
    h, w = sensor.height, sensor.width
    rng, pix, idx = closest_per_pixel(pixels, w, h)
    point_index = np.full(h * w, -1, dtype=np.int32)
    point_index[pix] = idx
    xyz = np.zeros((h * w, 3), dtype=np.float32)
    xyz[pix] = pts[idx]
    rem_img = np.zeros(h * w, dtype=np.float32)
    rem_img[pix] = rem[idx]
    return RangeImage(
        range=rng.reshape(h, w),
        xyz=xyz.reshape(h, w, 3),
        remission=rem_img.reshape(h, w),
        point_index=point_index.reshape(h, w),
        pixels=pixels,
    )


def project_range(points: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """Only the (H, W) range image (0 where empty): what a past scan needs for its residual."""
    pixels = pixel_index(points, sensor)
    rng, _, _ = closest_per_pixel(pixels, sensor.width, sensor.height)
    return rng.reshape(sensor.height, sensor.width)


def finite_mask(points: np.ndarray) -> np.ndarray:
    """Points that can be projected: all coordinates finite and range > 0.

    Such points crash the reference implementation; here they are dropped before
    projection and reported by the pipeline instead.
    """
    pts = check_points(points)
    # One pass over the squared range: it is NaN/inf when any coordinate is, and 0 only at
    # the origin. (It also overflows for coordinates beyond ~1e19 m, which are garbage too.)
    with np.errstate(over="ignore", invalid="ignore"):
        r2 = np.einsum("ij,ij->i", pts, pts)
    return np.isfinite(r2) & (r2 > 0)
