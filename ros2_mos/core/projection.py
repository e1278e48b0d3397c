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

from ros2_mos.core import kernels
from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import ScanError


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

    @property
    def planes(self) -> np.ndarray:
        """(3, H*W) x, y and z planes: :func:`xyz_planes` of ``xyz``."""
        return xyz_planes(self.xyz)


def xyz_planes(xyz: np.ndarray) -> np.ndarray:
    """(3, H*W) x, y and z planes of an (H, W, 3) image: a view when the image is one of a (3, H, W) array, as
    :func:`project` makes it."""
    return np.moveaxis(xyz, -1, 0).reshape(3, -1)


def check_points(points: np.ndarray, what: str = "points") -> np.ndarray:
    """Return ``points`` as an (N, 3) float array or raise ScanError naming the problem."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ScanError(f"{what} must be an (N, 3) array of x, y, z, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ScanError(f"{what} must be floating point, got dtype {arr.dtype}")
    return arr


# atan(t) ~ t * P(t^2) on [0, 1]: odd least-squares fit of degree 17, max error 1e-7 rad in float32
# (np.arctan2 in float32 is off by up to 2.2e-7). numpy's arctan2 is scalar libm code, while the
# ~30 multiply-adds below are SIMD ufuncs (faster: benchmarks/experiments.md, Speed), and it runs
# once per scan and once per past scan.
_ATAN_COEFFS = np.array(
    [0.9999998863901668, -0.333325970473658, 0.19985906928451264, -0.14161229789124125,
     0.10498947063988592, -0.07234857807645328, 0.0397812161296372, -0.014401347962729183,
     0.0024567211130326477],
    dtype=np.float32,
)


def azimuth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``np.arctan2(y, x)`` for float32 arrays, within 4e-7 rad, computed with SIMD ufuncs only.

    Octant reduction to t = min(|x|, |y|) / max(|x|, |y|) in [0, 1], a polynomial for atan(t),
    then the octant is restored.  Same signs as arctan2 (±0 and ±pi by the sign of y); the
    origin maps to 0.  The error is 1/7000 of a pixel of a 2048-column image.
    """
    x = np.asarray(x, dtype=np.float32)
    y = np.asarray(y, dtype=np.float32)
    ax = np.abs(x)
    ay = np.abs(y)
    big = np.maximum(ax, ay)
    t = np.minimum(ax, ay)
    np.divide(t, big, out=t, where=big > 0)  # where big == 0, t is already 0
    t2 = t * t
    angle = np.full_like(t, _ATAN_COEFFS[-1])
    for c in _ATAN_COEFFS[-2::-1]:
        angle *= t2
        angle += c
    angle *= t
    np.subtract(np.float32(np.pi / 2), angle, out=angle, where=ay > ax)
    np.subtract(np.float32(np.pi), angle, out=angle, where=x < 0)
    return np.copysign(angle, y, out=angle)


def pixel_index(points: np.ndarray, sensor: SensorConfig) -> PixelIndex:
    """Compute each point's pixel; points must be finite with positive range (see ``finite_mask``)."""
    pts = check_points(points)
    if kernels.enabled():
        return PixelIndex(*kernels.project(pts, sensor)[0])
    # Contiguous float32 columns: every ufunc below then runs on SIMD-friendly unit strides.
    x, y, z = np.array(pts.T, dtype=np.float32, order="C")
    return pixel_index_columns(x, y, z, sensor)


def pixel_index_columns(x: np.ndarray, y: np.ndarray, z: np.ndarray, sensor: SensorConfig) -> PixelIndex:
    """:func:`pixel_index` of points given as three contiguous float32 coordinate arrays."""
    if kernels.enabled():
        return PixelIndex(*kernels.project((x, y, z), sensor)[0])
    rho = x * x
    rho += y * y
    r = z * z
    r += rho
    np.sqrt(rho, out=rho)
    np.sqrt(r, out=r)
    # asin(z / r) == atan2(z, rho): the polynomial again, and no clipping of z / r is needed.
    v_f = azimuth(rho, z)
    # u = ½ (1 − yaw/π) w and v = (1 − (pitch − f_down)/f) h, each as one multiply-add in place.
    u_f = azimuth(x, y)
    u_f *= np.float32(-0.5 * sensor.width / np.pi)
    u_f += np.float32(0.5 * sensor.width)
    v_f *= np.float32(-sensor.height / sensor.fov)
    v_f += np.float32(sensor.height * (1.0 + sensor.fov_down / sensor.fov))
    in_image = v_f >= 0.0
    in_image &= v_f < sensor.height
    in_image &= r > sensor.min_range
    in_image &= r < sensor.max_range
    # Clamping before the truncating cast equals flooring and then clamping, for finite values.
    u = np.clip(u_f, 0, sensor.width - 1, out=u_f).astype(np.int32)
    v = np.clip(v_f, 0, sensor.height - 1, out=v_f).astype(np.int32)
    return PixelIndex(u=u, v=v, range=r, in_image=in_image)


def _flat_pixels(pixels: PixelIndex, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the points inside the image and their flat pixel ids (row-major)."""
    candidates = np.flatnonzero(pixels.in_image)
    pix = pixels.v[candidates]
    pix *= width
    pix += pixels.u[candidates]
    return candidates, pix


def closest_per_pixel(pixels: PixelIndex, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The closest range per pixel, and for every occupied pixel its id and the index of its closest point.

    ``np.minimum.at`` gives the per-pixel minimum in one unbuffered pass (no sort, and
    no reliance on numpy's unspecified order for repeated fancy-index assignment);
    the point whose range equals its pixel's minimum is the winner.
    """
    candidates, pix = _flat_pixels(pixels, width)
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


def closest_point_image(points: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """(H, W) the index of each pixel's closest point, -1 where the pixel is empty; points finite with positive
    range (see ``finite_mask``)."""
    pts = check_points(points)
    if kernels.enabled():
        winner = kernels.project(pts, sensor, closest=True)[2]
    else:
        _, occupied, index = closest_per_pixel(pixel_index(pts, sensor), sensor.width, sensor.height)
        winner = np.full(sensor.height * sensor.width, -1, np.int32)
        winner[occupied] = index
    return winner.reshape(sensor.height, sensor.width)


def project(points: np.ndarray, remission: np.ndarray, sensor: SensorConfig) -> RangeImage:
    """Project a scan of finite points with positive range to a full range image."""
    pts = check_points(points)
    rem = np.asarray(remission, dtype=np.float32).reshape(-1)
    if len(rem) != len(pts):
        raise ScanError(f"remission has {len(rem)} values for {len(pts)} points")
    h, w = sensor.height, sensor.width
    if kernels.enabled():  # pixels and closest points in one pass, then the images in another
        columns, best, winner = kernels.project(pts, sensor, closest=True)
        rng, planes, rem_img, point_index = kernels.fill_images(winner, best, pts, rem)
        return RangeImage(range=rng.reshape(h, w), xyz=planes.reshape(3, h, w).transpose(1, 2, 0),
                          remission=rem_img.reshape(h, w), point_index=point_index.reshape(h, w),
                          pixels=PixelIndex(*columns))
    pixels = pixel_index(pts, sensor)
    rng, pix, idx = closest_per_pixel(pixels, w, h)
    point_index = np.full(h * w, -1, dtype=np.int32)
    point_index[pix] = idx
    # One flat scatter per coordinate: a scatter of (n, 3) rows is 10x slower than three of n values.
    xyz = np.zeros((3, h * w), dtype=np.float32)
    for i in range(3):
        xyz[i, pix] = pts[idx, i]
    rem_img = np.zeros(h * w, dtype=np.float32)
    rem_img[pix] = rem[idx]
    return RangeImage(
        range=rng.reshape(h, w),
        xyz=xyz.reshape(3, h, w).transpose(1, 2, 0),
        remission=rem_img.reshape(h, w),
        point_index=point_index.reshape(h, w),
        pixels=pixels,
    )


def project_range(points: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """Only the (H, W) range image (0 where empty): what a past scan needs for its residual."""
    if kernels.enabled():  # the (N, 3) rows as they are, no transposed copy
        return kernels.range_image(check_points(points), sensor)
    x, y, z = np.array(check_points(points).T, dtype=np.float32, order="C")
    return project_range_columns(x, y, z, sensor)


def project_range_columns(x: np.ndarray, y: np.ndarray, z: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """:func:`project_range` of points given as three contiguous float32 coordinate arrays."""
    if kernels.enabled():
        return kernels.range_image((x, y, z), sensor)
    pixels = pixel_index_columns(x, y, z, sensor)
    candidates, pix = _flat_pixels(pixels, sensor.width)
    best = np.full(sensor.height * sensor.width, np.inf, dtype=np.float32)
    np.minimum.at(best, pix, pixels.range[candidates])
    best[np.isinf(best)] = 0.0
    return best.reshape(sensor.height, sensor.width)


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
