"""The compiled per-point geometry kernels (``_kernels.c``), loaded with ctypes.

``projection.py`` and ``residuals.py`` are written in numpy, ~80 whole-array operations per projection of
a scan. ``_kernels.c`` does the same float32 arithmetic, in the same order, in one pass per point: the
results are bit-identical (``test/test_kernels.py``) and several times faster (benchmarks/experiments.md, Speed). The
registration's normals, Gauss-Newton sums and loop (``registration.py``) are here too; they agree with their
numpy code to 1e-9 (double-precision sums in another order, ``test/test_registration.py``). The range image's
connected regions (``segments.py``: the same labels) and the kNN vote (``postprocess.py``: the same labels,
probabilities to 2e-7: float32 sums in another order, eight points at a time in vector lanes) are here as well, and
so are autolabel's local ground, voxel clusters, column rules and nearest-object attachment (``offline/objects.py``:
the same ground heights, cluster and object ids). The extension is built by ``pip install`` (setup.py; it needs a C
compiler). Where it is missing or stale, or with ``ROS2_MOS_KERNELS=0`` in the environment, :func:`enabled` is False
and the numpy code runs instead; :func:`status` says which in one line (the node logs it, ``ros2-mos bench`` prints
it).

ctypes releases the GIL for the call, so kernels on several threads (the residual pool) run in parallel.
"""

from __future__ import annotations

import ctypes
import importlib.machinery
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from ros2_mos.core.config import SensorConfig

#: Must equal MOS_KERNELS_ABI in _kernels.c: a library built from an older source is not used.
ABI = 13



class _Sensor(ctypes.Structure):
    """MosSensor of _kernels.c: the projection's float32 constants."""

    _fields_ = [
        ("width", ctypes.c_int32),
        ("height", ctypes.c_int32),
        ("u_scale", ctypes.c_float),
        ("u_shift", ctypes.c_float),
        ("v_scale", ctypes.c_float),
        ("v_shift", ctypes.c_float),
        ("min_range", ctypes.c_float),
        ("max_range", ctypes.c_float),
    ]


def _library_path() -> Path | None:
    here = Path(__file__).parent
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = here / f"_kernels{suffix}"
        if path.is_file():
            return path
    return None


def _load() -> tuple[ctypes.CDLL | None, str]:
    """The library and a one-line status."""
    if os.environ.get("ROS2_MOS_KERNELS", "1").strip() in ("0", "false", "no", "off"):
        return None, "numpy code (compiled kernels off: ROS2_MOS_KERNELS=0)"
    path = _library_path()
    if path is None:
        return None, "numpy code (compiled kernels not built: reinstall with a C compiler, `pip install -e .`)"
    try:
        lib = ctypes.CDLL(str(path))
        abi = lib.mos_kernels_abi()
    except (OSError, AttributeError) as err:
        return None, f"numpy code (compiled kernels unusable: {err})"
    if abi != ABI:
        return None, f"numpy code (compiled kernels are stale: ABI {abi}, want {ABI}; reinstall, `pip install -e .`)"
    vp = ctypes.c_void_p
    lib.mos_project.restype = None
    lib.mos_project.argtypes = [vp, vp, vp, ctypes.c_int64, ctypes.c_int64, vp, ctypes.POINTER(_Sensor),
                                vp, vp, vp, vp, vp, vp]
    lib.mos_free_space.restype = None
    lib.mos_free_space.argtypes = [vp, vp, vp, vp, ctypes.c_int64, vp, ctypes.POINTER(_Sensor), vp,
                                   ctypes.c_float, ctypes.c_float, vp]
    lib.mos_plane_icp_sums.restype = ctypes.c_int64
    lib.mos_plane_icp_sums.argtypes = [vp, vp, vp, vp, ctypes.c_int64, vp, ctypes.POINTER(_Sensor), vp, vp, vp, vp,
                                       vp, vp, ctypes.c_float, ctypes.c_float, ctypes.c_float, vp, vp, vp]
    lib.mos_refine.restype = ctypes.c_int32
    lib.mos_refine.argtypes = [vp, vp, vp, vp, ctypes.c_int64, vp, ctypes.POINTER(_Sensor), vp, vp, vp, vp, vp, vp,
                               ctypes.c_int32, ctypes.c_float, ctypes.c_float, ctypes.c_float, ctypes.c_double,
                               ctypes.c_int64, ctypes.c_double, ctypes.c_double]
    lib.mos_fill_images.restype = None
    lib.mos_fill_images.argtypes = [vp, vp, ctypes.c_int64, vp, vp, vp, vp, vp, vp, vp, vp]
    lib.mos_range_image.restype = None
    lib.mos_range_image.argtypes = [vp, vp, vp, ctypes.c_int64, ctypes.c_int64, vp, ctypes.POINTER(_Sensor), vp]
    lib.mos_normals.restype = None
    lib.mos_normals.argtypes = [vp, vp, vp, vp, ctypes.c_int32, ctypes.c_int32, vp, vp, vp]
    lib.mos_residual.restype = None
    lib.mos_residual.argtypes = [vp, vp, ctypes.c_int64, ctypes.c_float, ctypes.c_float, ctypes.c_int32, vp]
    lib.mos_connected_regions.restype = None
    lib.mos_connected_regions.argtypes = [vp, vp, ctypes.c_int32, ctypes.c_int32, ctypes.c_float, ctypes.c_float,
                                          vp]
    lib.mos_grow_regions.restype = None
    lib.mos_voxel_clusters.restype = None
    lib.mos_voxel_clusters.argtypes = [vp, ctypes.c_int64, vp, ctypes.c_int32, vp, vp, vp]
    lib.mos_attach_below.restype = None
    lib.mos_attach_below.argtypes = [vp, ctypes.c_int32, ctypes.c_int32, vp, vp, vp, ctypes.c_double, ctypes.c_double,
                                     ctypes.c_float, ctypes.c_int32, ctypes.c_float, vp, vp, vp]
    lib.mos_attach_over.restype = None
    lib.mos_attach_over.argtypes = [vp, ctypes.c_int32, ctypes.c_int32, vp, vp, vp, ctypes.c_double, ctypes.c_double,
                                    ctypes.c_int32, vp, vp]
    lib.mos_grow_regions.argtypes = [vp, vp, ctypes.c_int64, ctypes.c_double, vp, vp]
    lib.mos_local_ground.restype = None
    lib.mos_local_ground.argtypes = [vp, ctypes.c_int64, ctypes.c_int64, vp, ctypes.c_int32, ctypes.c_int32,
                                     ctypes.c_int32, ctypes.c_int32, ctypes.c_float, vp, vp, vp]
    lib.mos_attach_nearest.restype = None
    lib.mos_attach_nearest.argtypes = [vp, vp, ctypes.c_int64, vp, ctypes.c_int64, vp, ctypes.c_int64, ctypes.c_float,
                                       vp, vp, ctypes.c_int64, ctypes.c_float, vp, ctypes.c_int32, vp, vp]
    lib.mos_knn_vote.restype = None
    lib.mos_knn_vote.argtypes = [vp, vp, ctypes.c_int32, ctypes.c_int32, vp, vp, vp, ctypes.c_int64, ctypes.c_int32,
                                 ctypes.c_int32, vp, ctypes.c_float, ctypes.c_float, ctypes.c_int32, vp, vp]
    return lib, "compiled kernels"


_LIB, _STATUS = _load()
_forced_off = False


def enabled() -> bool:
    """Whether the compiled kernels are used (else the numpy code)."""
    return _LIB is not None and not _forced_off


def status() -> str:
    """One line: which geometry code runs, and why not the compiled kernels where they are off."""
    return "numpy code (compiled kernels off for this run)" if _forced_off and _LIB is not None else _STATUS


@contextmanager
def disabled() -> Iterator[None]:
    """Run the numpy code inside the block (tests compare both; benchmarks A/B them)."""
    global _forced_off
    before, _forced_off = _forced_off, True
    try:
        yield
    finally:
        _forced_off = before


def _f32(value: float) -> float:
    """``value`` rounded to float32 (as a Python float, which ctypes takes and converts back exactly)."""
    return float(np.float32(value))


def _sensor(sensor: SensorConfig) -> _Sensor:
    """The constants exactly as ``projection.pixel_index_columns`` computes them (float32)."""
    return _Sensor(
        sensor.width,
        sensor.height,
        _f32(-0.5 * sensor.width / np.pi),
        _f32(0.5 * sensor.width),
        _f32(-sensor.height / sensor.fov),
        _f32(sensor.height * (1.0 + sensor.fov_down / sensor.fov)),
        _f32(sensor.min_range),
        _f32(sensor.max_range),
    )


def _ptr(array: np.ndarray | None) -> int | None:
    return None if array is None else array.ctypes.data


def _transform(transform: np.ndarray | None) -> np.ndarray | None:
    """A 4x4 rigid transform as the kernels take it: row-major 3x4 float32 (``transform_columns`` casts so)."""
    if transform is None:
        return None
    return np.ascontiguousarray(np.asarray(transform, dtype=np.float64)[:3, :4], dtype=np.float32)


#: Column, row, range and inside-the-image flag per point (``projection.PixelIndex``'s fields).
Pixels = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _coordinates(points: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[list[np.ndarray], int, int]:
    """The kernels' view of points: three pointers' arrays, their common stride in floats, and N.

    (N, 3) rows are passed as they are (stride 3; copied only when not contiguous float32), three
    coordinate columns as they are (stride 1).
    """
    if isinstance(points, tuple):
        columns = [np.ascontiguousarray(c, dtype=np.float32) for c in points]
        if not len(columns[0]) == len(columns[1]) == len(columns[2]):
            raise ValueError("x, y and z have different lengths")
        return columns, 1, len(columns[0])
    rows = np.ascontiguousarray(points, dtype=np.float32)
    if rows.ndim != 2 or rows.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {rows.shape}")
    return [rows, rows[:, 1], rows[:, 2]], 3, len(rows)


def project(points: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray], sensor: SensorConfig,
            closest: bool = False) -> tuple[Pixels, np.ndarray | None, np.ndarray | None]:
    """Project (N, 3) points, or three coordinate columns, in one pass.

    Returns ``(u, v, range, in_image)``, and when ``closest`` the (H*W,) closest range per pixel (+inf where
    empty) and the index of that point (-1 where empty); else None, None.
    """
    coords, stride, n = _coordinates(points)
    u = np.empty(n, np.int32)
    v = np.empty(n, np.int32)
    rng = np.empty(n, np.float32)
    inside = np.empty(n, np.bool_)
    best = winner = None
    if closest:
        best = np.full(sensor.height * sensor.width, np.inf, np.float32)
        winner = np.full(sensor.height * sensor.width, -1, np.int32)
    assert _LIB is not None
    _LIB.mos_project(coords[0].ctypes.data, coords[1].ctypes.data, coords[2].ctypes.data, stride, n, None,
                     ctypes.byref(_sensor(sensor)), u.ctypes.data, v.ctypes.data, rng.ctypes.data,
                     inside.ctypes.data, _ptr(best), _ptr(winner))
    return (u, v, rng, inside), best, winner


def range_image(points: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray], sensor: SensorConfig,
                transform: np.ndarray | None = None) -> np.ndarray:
    """(H, W) closest range per pixel of the points (moved by ``transform`` first, when given), 0 where empty."""
    coords, stride, n = _coordinates(points)
    t = _transform(transform)
    out = np.empty((sensor.height, sensor.width), np.float32)
    assert _LIB is not None
    _LIB.mos_range_image(coords[0].ctypes.data, coords[1].ctypes.data, coords[2].ctypes.data, stride, n, _ptr(t),
                         ctypes.byref(_sensor(sensor)), out.ctypes.data)
    return out


def fill_images(winner: np.ndarray, best: np.ndarray, points: np.ndarray, remission: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From :func:`project`'s closest point per pixel: range (0 where empty), (3, H*W) x, y, z planes, remission
    and point index (-1 where empty), each per pixel."""
    winner = np.ascontiguousarray(winner, dtype=np.int32)
    best = np.ascontiguousarray(best, dtype=np.float32)
    rows = np.ascontiguousarray(points, dtype=np.float32)
    rem = np.ascontiguousarray(remission, dtype=np.float32)
    npix = winner.size
    if best.size != npix or rows.ndim != 2 or rows.shape[1] != 3 or len(rem) != len(rows):
        raise ValueError(f"fill images: {npix} winners, {best.size} ranges, points {rows.shape}, {len(rem)} remissions")
    rng = np.empty(npix, np.float32)
    planes = np.empty((3, npix), np.float32)
    rem_out = np.empty(npix, np.float32)
    index = np.empty(npix, np.int32)
    assert _LIB is not None
    _LIB.mos_fill_images(winner.ctypes.data, best.ctypes.data, npix, rows.ctypes.data, rem.ctypes.data,
                         rng.ctypes.data, planes[0].ctypes.data, planes[1].ctypes.data, planes[2].ctypes.data,
                         rem_out.ctypes.data, index.ctypes.data)
    return rng, planes, rem_out, index


def free_space(planes: np.ndarray, occupied: np.ndarray, transform: np.ndarray, sensor: SensorConfig,
               past_range: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(H*W,) ``residuals.free_space_image``: ``planes`` (3, H*W) float32 holds the current points, ``occupied``
    the flat ids of the pixels that hold one, ``past_range`` the past scan's own (H, W) range image."""
    planes = np.ascontiguousarray(planes, dtype=np.float32)
    occupied = np.ascontiguousarray(occupied, dtype=np.int64)
    past = np.ascontiguousarray(past_range, dtype=np.float32)
    npix = planes.shape[1]
    if past.size != npix or npix != sensor.height * sensor.width:
        raise ValueError(f"free space: {npix} pixels of points, {past.size} of past range, sensor "
                         f"{sensor.height} x {sensor.width}")
    out = np.zeros(npix, np.float32)
    t = _transform(transform)
    assert _LIB is not None
    _LIB.mos_free_space(planes[0].ctypes.data, planes[1].ctypes.data, planes[2].ctypes.data, occupied.ctypes.data,
                        len(occupied), t.ctypes.data, ctypes.byref(_sensor(sensor)), past.ctypes.data,
                        _f32(lo), _f32(hi), out.ctypes.data)
    return out


def residual(current_range: np.ndarray, past_range: np.ndarray, lo: float, hi: float, signed: bool) -> np.ndarray:
    """``residuals.residual_image`` of two range images of one shape."""
    current = np.ascontiguousarray(current_range, dtype=np.float32)
    past = np.ascontiguousarray(past_range, dtype=np.float32)
    if current.shape != past.shape:
        raise ValueError(f"residual of range images of shapes {current.shape} and {past.shape}")
    out = np.empty_like(current)
    assert _LIB is not None
    _LIB.mos_residual(current.ctypes.data, past.ctypes.data, current.size, _f32(lo), _f32(hi),
                      int(signed), out.ctypes.data)
    return out


def normals(planes: np.ndarray, range_image: np.ndarray) -> np.ndarray:
    """``registration.normal_planes``: (3, H*W) float32 unit normals of a scan's own points, 0 where none."""
    planes = np.ascontiguousarray(planes, dtype=np.float32)
    rng = np.ascontiguousarray(range_image, dtype=np.float32)
    if rng.ndim != 2 or planes.shape != (3, rng.size):
        raise ValueError(f"normals of planes {planes.shape} and a range image {rng.shape}")
    out = np.empty_like(planes)
    assert _LIB is not None
    _LIB.mos_normals(planes[0].ctypes.data, planes[1].ctypes.data, planes[2].ctypes.data, rng.ctypes.data,
                     rng.shape[1], rng.shape[0], out[0].ctypes.data, out[1].ctypes.data, out[2].ctypes.data)
    return out


def _icp_arrays(planes: np.ndarray, points: np.ndarray, sensor: SensorConfig, past_planes: np.ndarray,
                past_normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The registration kernels' arrays, contiguous and of their types, their shapes checked."""
    planes = np.ascontiguousarray(planes, dtype=np.float32)
    past_planes = np.ascontiguousarray(past_planes, dtype=np.float32)
    past_normals = np.ascontiguousarray(past_normals, dtype=np.float32)
    npix = sensor.height * sensor.width
    if planes.shape != (3, npix) or past_planes.shape != (3, npix) or past_normals.shape != (3, npix):
        raise ValueError(f"plane ICP: planes {planes.shape}, {past_planes.shape} and normals {past_normals.shape}, "
                         f"sensor {sensor.height} x {sensor.width}")
    return planes, np.ascontiguousarray(points, dtype=np.int64), past_planes, past_normals


def plane_icp_sums(planes: np.ndarray, points: np.ndarray, transform: np.ndarray, sensor: SensorConfig,
                   past_planes: np.ndarray, past_normals: np.ndarray, plane_limit: float, point_limit: float,
                   huber: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """``registration.plane_icp_sums`` (hessian, gradient, cost, pairs) in one pass: ``planes``, ``past_planes`` and
    ``past_normals`` (3, H*W) float32 hold the current and the past scan's own points and the past normals,
    ``points`` the flat current pixels to use."""
    planes, points, past_planes, past_normals = _icp_arrays(planes, points, sensor, past_planes, past_normals)
    hessian = np.zeros((6, 6), np.float64)
    gradient = np.zeros(6, np.float64)
    cost = np.zeros(1, np.float64)
    t = _transform(transform)
    assert _LIB is not None
    pairs = _LIB.mos_plane_icp_sums(planes[0].ctypes.data, planes[1].ctypes.data, planes[2].ctypes.data,
                                    points.ctypes.data, len(points), t.ctypes.data, ctypes.byref(_sensor(sensor)),
                                    past_planes[0].ctypes.data, past_planes[1].ctypes.data, past_planes[2].ctypes.data,
                                    past_normals[0].ctypes.data, past_normals[1].ctypes.data,
                                    past_normals[2].ctypes.data, _f32(plane_limit), _f32(point_limit), _f32(huber),
                                    hessian.ctypes.data, gradient.ctypes.data, cost.ctypes.data)
    return hessian, gradient, float(cost[0]), int(pairs)


def refine(planes: np.ndarray, points: np.ndarray, transform: np.ndarray, sensor: SensorConfig,
           past_planes: np.ndarray, past_normals: np.ndarray, iterations: int, plane_limit: float, point_limit: float,
           huber: float, damping: float, min_pairs: int, converged: tuple[float, float]) -> np.ndarray | None:
    """``registration.refine_to_past``'s Gauss-Newton loop in one call: the refined 4x4 transform, or None where a
    step had too few pairs or singular equations."""
    planes, points, past_planes, past_normals = _icp_arrays(planes, points, sensor, past_planes, past_normals)
    pose = np.array(transform, dtype=np.float64, order="C")
    if pose.shape != (4, 4):
        raise ValueError(f"a 4x4 transform, got {pose.shape}")
    assert _LIB is not None
    steps = _LIB.mos_refine(planes[0].ctypes.data, planes[1].ctypes.data, planes[2].ctypes.data, points.ctypes.data,
                            len(points), pose.ctypes.data, ctypes.byref(_sensor(sensor)), past_planes[0].ctypes.data,
                            past_planes[1].ctypes.data, past_planes[2].ctypes.data, past_normals[0].ctypes.data,
                            past_normals[1].ctypes.data, past_normals[2].ctypes.data, int(iterations),
                            _f32(plane_limit), _f32(point_limit), _f32(huber), float(damping), int(min_pairs),
                            float(converged[0]), float(converged[1]))
    return None if steps < 0 else pose


def connected_regions(valid: np.ndarray, range_image: np.ndarray, rel: float, min_jump: float) -> np.ndarray:
    """``segments.connected_regions``: (H, W) int64 region labels (the smallest pixel id of each), -1 where not
    valid."""
    mask = np.ascontiguousarray(valid, dtype=np.bool_)
    rng = np.ascontiguousarray(range_image, dtype=np.float32)
    if rng.ndim != 2 or mask.shape != rng.shape:
        raise ValueError(f"connected regions of a mask {mask.shape} and a range image {rng.shape}")
    labels = np.empty(rng.shape, np.int64)
    assert _LIB is not None
    _LIB.mos_connected_regions(mask.ctypes.data, rng.ctypes.data, rng.shape[0], rng.shape[1], _f32(rel),
                               _f32(min_jump), labels.ctypes.data)
    return labels


def voxel_clusters(cells: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``objects.voxel_clusters`` after its cells: per cell of ``cells`` (voxel keys, sorted and unique) the index of
    its cluster, cells joined where one's key plus one of ``steps`` (positive key offsets) is the other's; clusters
    numbered by their smallest cell."""
    keys = np.ascontiguousarray(cells, dtype=np.int64)
    offsets = np.ascontiguousarray(steps, dtype=np.int64)
    if keys.ndim != 1 or offsets.ndim != 1 or (offsets <= 0).any():
        raise ValueError(f"voxel clusters of cells {keys.shape} with positive steps, got steps {offsets.tolist()}")
    if len(keys) > 1 and (np.diff(keys) <= 0).any():
        raise ValueError("voxel clusters: the cells must be sorted and unique")
    parent = np.empty(len(keys), np.int64)
    cursor = np.empty(len(offsets), np.int64)
    cluster = np.empty(len(keys), np.int64)
    assert _LIB is not None
    _LIB.mos_voxel_clusters(keys.ctypes.data, len(keys), offsets.ctypes.data, len(offsets), parent.ctypes.data,
                            cursor.ctypes.data, cluster.ctypes.data)
    return cluster


def _attach(function: str, image: np.ndarray, which: np.ndarray, horizontal: np.ndarray, z: np.ndarray,
            point_object: np.ndarray, *numbers: float | int) -> np.ndarray:
    """Checks the inputs of :func:`attach_below` / :func:`attach_over` and calls the kernel ``function`` with
    ``numbers`` (its scalar arguments, already of their C types) between the points' arrays and the outputs."""
    n = len(point_object)
    if (image.dtype != np.int32 or image.ndim != 2 or not image.flags.c_contiguous or point_object.dtype != np.int32
            or not point_object.flags.c_contiguous or horizontal.dtype != np.float32 or z.dtype != np.float32
            or len(horizontal) != n or len(z) != n):
        raise ValueError(f"column attachment of an int32 image {image.dtype} {image.shape}, int32 object ids "
                         f"{point_object.dtype} and float32 coordinates {horizontal.dtype} {z.dtype} of {n} points")
    chosen = np.zeros(n, np.uint8)
    chosen[which] = 1
    horizontal, z = np.ascontiguousarray(horizontal), np.ascontiguousarray(z)
    attached = np.zeros(n, np.uint8)
    assert _LIB is not None
    getattr(_LIB, function)(image.ctypes.data, image.shape[0], image.shape[1], chosen.ctypes.data,
                            horizontal.ctypes.data, z.ctypes.data, *numbers, point_object.ctypes.data,
                            attached.ctypes.data)
    return attached.view(bool)


def attach_below(image: np.ndarray, which: np.ndarray, horizontal: np.ndarray, z: np.ndarray,
                 point_object: np.ndarray, steep: float, gentle: float, ground_step: float, search: int,
                 under: float = 0.0, under_ok: np.ndarray | None = None) -> np.ndarray:
    """``objects.attach_below`` over the closest points' ``image`` (int32), in place on ``point_object`` (int32);
    ``horizontal`` and ``z`` float32 per point, ``steep`` and ``gentle`` the slopes, ``under`` the depth under a
    face (0: none), ``under_ok`` per point whether it may join so (None: all); returns which were attached."""
    ok = None
    if under_ok is not None:
        ok = np.ascontiguousarray(under_ok, dtype=np.uint8)
        if ok.shape != point_object.shape:
            raise ValueError(f"column attachment: {len(ok)} under_ok flags for {len(point_object)} points")
    return _attach("mos_attach_below", image, which, horizontal, z, point_object, float(steep), float(gentle),
                   _f32(ground_step), int(search), _f32(under), _ptr(ok))


def attach_over(image: np.ndarray, which: np.ndarray, horizontal: np.ndarray, z: np.ndarray,
                point_object: np.ndarray, steep: float, row_slope: float, search: int) -> np.ndarray:
    """``objects.attach_over`` as :func:`attach_below`; ``row_slope`` the rise's bound per metre of range."""
    return _attach("mos_attach_over", image, which, horizontal, z, point_object, float(steep), float(row_slope),
                   int(search))


def local_ground(points: np.ndarray, cell_of: np.ndarray, shape: tuple[int, int], radius: int,
                 outlier_drop: float) -> np.ndarray:
    """``objects.local_ground`` after its grid: per point of ``points`` ((N, 3) float32) the ground height, the
    points' flat cells ``cell_of`` (int64) on a grid of ``shape``; ``outlier_drop`` +inf for none."""
    if points.dtype != np.float32 or points.ndim != 2 or points.shape[1] != 3 or len(cell_of) != len(points):
        raise ValueError(f"local ground of float32 (N, 3) points and a cell each, got {points.dtype} {points.shape} "
                         f"and {len(cell_of)} cells")
    rows, cols = int(shape[0]), int(shape[1])
    cells = np.ascontiguousarray(cell_of, dtype=np.int64)
    if len(cells) and (cells.min() < 0 or cells.max() >= rows * cols):
        raise ValueError(f"local ground: cells outside the {rows} x {cols} grid")
    if not (radius >= 0 and rows > 0 and cols > 0) or np.isnan(outlier_drop):
        raise ValueError(f"local ground: radius {radius}, grid {rows} x {cols}, outlier drop {outlier_drop}")
    coords = np.ascontiguousarray(points)
    grid = np.empty(3 * rows * cols, np.float32)
    window = np.empty((2 * radius + 1) ** 2, np.float32)
    out = np.empty(len(points), np.float32)
    use_drop = bool(np.isfinite(outlier_drop))
    assert _LIB is not None
    _LIB.mos_local_ground(coords[:, 2:].ctypes.data, 3, len(points), cells.ctypes.data, rows, cols, int(radius),
                          int(use_drop), _f32(outlier_drop) if use_drop else 0.0, grid.ctypes.data,
                          window.ctypes.data, out.ctypes.data)
    return out


def attach_nearest(points: np.ndarray, loose: np.ndarray, near: np.ndarray, reach: float, cells: np.ndarray,
                   owner: np.ndarray, grid: float, steps: np.ndarray, point_object: np.ndarray) -> np.ndarray:
    """``objects.attach_to_nearest`` after its object cells, in place on ``point_object`` (int32): ``points`` (N, 3)
    float32, ``loose`` indices, ``near`` the objects' sorted ``reach``-sized cell keys, ``cells`` their sorted
    ``grid``-sized cell keys and ``owner`` each, ``steps`` (S, 2) nearest first; returns which were attached."""
    n = len(point_object)
    if (points.dtype != np.float32 or points.ndim != 2 or points.shape[1] != 3 or len(points) != n
            or point_object.dtype != np.int32 or not point_object.flags.c_contiguous or len(cells) != len(owner)):
        raise ValueError(f"nearest-object attachment of float32 (N, 3) points, int32 object ids and an owner per "
                         f"cell, got {points.dtype} {points.shape}, {point_object.dtype}, {len(cells)} / {len(owner)}")
    which = np.ascontiguousarray(loose, dtype=np.int64)
    if len(which) and (which.min() < 0 or which.max() >= n):
        raise ValueError("nearest-object attachment: loose points outside the cloud")
    rows = np.ascontiguousarray(points)
    near_keys = np.ascontiguousarray(near, dtype=np.int64)
    keys = np.ascontiguousarray(cells, dtype=np.int64)
    owners = np.ascontiguousarray(owner, dtype=np.int32)
    offsets = np.ascontiguousarray(steps, dtype=np.int64)
    attached = np.zeros(n, np.uint8)
    assert _LIB is not None
    _LIB.mos_attach_nearest(rows.ctypes.data, rows[:, 1:].ctypes.data, 3, which.ctypes.data, len(which),
                            near_keys.ctypes.data, len(near_keys), _f32(reach), keys.ctypes.data, owners.ctypes.data,
                            len(keys), _f32(grid), offsets.ctypes.data, len(offsets), point_object.ctypes.data,
                            attached.ctypes.data)
    return attached.view(bool)


def grow_regions(seeds: np.ndarray, regions: np.ndarray, seed_fraction: float) -> np.ndarray:
    """``segments.grow_regions`` over :func:`connected_regions`' labels: the pixels of every region at least
    ``seed_fraction`` of which (and one pixel at least) are seeds."""
    labels = np.ascontiguousarray(regions, dtype=np.int64)
    mask = np.ascontiguousarray(seeds, dtype=np.bool_)
    if mask.shape != labels.shape:
        raise ValueError(f"grow regions: seeds {mask.shape}, regions {labels.shape}")
    if labels.size and (labels.max() >= labels.size or labels.min() < -1):
        raise ValueError("grow regions: labels must be pixel ids or -1")
    out = np.empty(labels.shape, np.bool_)
    scratch = np.empty(2 * labels.size, np.int32)
    assert _LIB is not None
    _LIB.mos_grow_regions(labels.ctypes.data, mask.ctypes.data, labels.size, float(seed_fraction),
                          scratch.ctypes.data, out.ctypes.data)
    return out


def knn_vote(prob_image: np.ndarray, range_image: np.ndarray, u: np.ndarray, v: np.ndarray, point_range: np.ndarray,
             window: int, k: int, weights: np.ndarray, cutoff: float, threshold: float | None) -> np.ndarray:
    """``postprocess.knn_backproject``: (N,) float32 moving probability of the points at pixels (``u``, ``v``)."""
    prob = np.ascontiguousarray(prob_image, dtype=np.float32)
    rng = np.ascontiguousarray(range_image, dtype=np.float32)
    cols = np.ascontiguousarray(u, dtype=np.int32)
    rows = np.ascontiguousarray(v, dtype=np.int32)
    ranges = np.ascontiguousarray(point_range, dtype=np.float32)
    gauss = np.ascontiguousarray(weights, dtype=np.float32)
    if rng.ndim != 2 or prob.shape != rng.shape or not len(cols) == len(rows) == len(ranges):
        raise ValueError(f"kNN vote: probabilities {prob.shape}, ranges {rng.shape}, {len(cols)} / {len(rows)} / "
                         f"{len(ranges)} pixels")
    if window % 2 != 1 or not 1 <= window <= 15 or gauss.size != window * window or not 1 <= k <= window * window:
        raise ValueError(f"kNN vote: window {window}, k {k}, {gauss.size} weights")
    h, w = rng.shape
    if len(cols) and (cols.min() < 0 or cols.max() >= w or rows.min() < 0 or rows.max() >= h):
        raise ValueError("kNN vote: pixels outside the image")
    out = np.empty(len(cols), np.float32)
    scratch = np.empty(3 * h * w if threshold is not None else 1, np.uint8)
    assert _LIB is not None
    _LIB.mos_knn_vote(prob.ctypes.data, rng.ctypes.data, h, w, cols.ctypes.data, rows.ctypes.data, ranges.ctypes.data,
                      len(cols), window, k, gauss.ctypes.data, _f32(cutoff), _f32(threshold or 0.0),
                      int(threshold is not None), scratch.ctypes.data, out.ctypes.data)
    return out
