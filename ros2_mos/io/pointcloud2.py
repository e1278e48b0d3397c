"""Vectorised sensor_msgs/PointCloud2 <-> numpy conversion, without rclpy.

``sensor_msgs_py`` is not on PyPI, and the offline tools (bags, ``process``) must
work off a ROS install, so this module reimplements the part of it we need. It is
duck-typed: any object with the PointCloud2 attributes works, which covers
rclpy's ``sensor_msgs.msg.PointCloud2`` and the dataclasses ``rosbags``
deserialises. Every conversion is one ``np.frombuffer`` view with a structured
dtype built from the message's fields (honouring ``is_bigendian``,
``point_step`` and ``row_step``), never a Python loop over points.

Messages come off the wire from other programs, so nothing here trusts them:
every inconsistency raises a :class:`~ros2_mos.core.errors.ScanError` subclass with a
message that says what was wrong, and nothing allocates based on a size the
message merely claims.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ros2_mos.core.errors import ScanError

# sensor_msgs/msg/PointField datatype constants (Jazzy defines 1..8).
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

#: PointField datatype -> numpy dtype (byte order applied separately).
DATATYPES: dict[int, np.dtype] = {
    INT8: np.dtype(np.int8),
    UINT8: np.dtype(np.uint8),
    INT16: np.dtype(np.int16),
    UINT16: np.dtype(np.uint16),
    INT32: np.dtype(np.int32),
    UINT32: np.dtype(np.uint32),
    FLOAT32: np.dtype(np.float32),
    FLOAT64: np.dtype(np.float64),
}
_NUMPY_TO_DATATYPE: dict[np.dtype, int] = {v: k for k, v in DATATYPES.items()}

#: Names under which drivers publish a per-point return strength, in order of preference.
INTENSITY_NAMES: tuple[str, ...] = ("intensity", "reflectivity", "remission")
#: Per-point measurement times, as drivers name them (Ouster ``t`` in ns, Velodyne ``time`` in s, Hesai ``timestamp``).
TIME_NAMES: tuple[str, ...] = ("t", "time", "timestamp", "time_stamp", "offset_time")

#: Upper bound on points per cloud; far above any rotating LiDAR (a 128-beam sensor
#: gives ~260k) yet small enough that a corrupt header cannot make us allocate GBs.
MAX_POINTS: int = 16_000_000
#: Upper bound on the bytes per point; real drivers use 16..64.
MAX_POINT_STEP: int = 65_536
_UINT32_MAX = 2**32 - 1
#: Upper bound on fields per point.
MAX_FIELDS: int = 256


class CloudLayoutError(ScanError):
    """The fields, point_step, row_step, width/height or data length are inconsistent."""


class CloudFieldError(ScanError):
    """A field is missing, duplicated, of an unsupported datatype, or outside the point."""


@dataclass(frozen=True)
class Field:
    """One PointField, detached from any message type so layouts can be built and compared."""

    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclass(frozen=True)
class CloudView:
    """A validated, zero-copy view of a PointCloud2's points.

    ``records`` is a flat structured array (one entry per point, row-major for
    organised clouds) whose itemsize is the message's ``point_step``, so the raw
    bytes of every point, padding included, can be copied out unchanged.
    """

    fields: tuple[Field, ...]
    records: np.ndarray
    point_step: int
    is_bigendian: bool
    height: int
    width: int

    @property
    def size(self) -> int:
        """Number of points (width * height), finite or not."""
        return int(self.records.shape[0])

    @property
    def names(self) -> tuple[str, ...]:
        """Field names in message order."""
        return tuple(f.name for f in self.fields)


def _byteorder(is_bigendian: bool) -> str:
    return ">" if is_bigendian else "<"


def _as_int(value: Any, what: str) -> int:
    """Read an integer header value; rejects bools-as-garbage, floats and negatives."""
    try:
        number = int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CloudLayoutError(f"PointCloud2 {what} is not an integer: {value!r}") from exc
    if number != value or number < 0:
        raise CloudLayoutError(f"PointCloud2 {what} must be a non-negative integer, got {value!r}")
    if number > _UINT32_MAX:  # a real message cannot hold it (and 0 x 2**64 points would pass as empty)
        raise CloudLayoutError(f"PointCloud2 {what} {value!r} does not fit the message's uint32")
    return number


def read_fields(fields: Iterable[Any], point_step: int) -> tuple[Field, ...]:
    """Validate a message's PointField list against ``point_step``.

    Raises CloudFieldError on duplicate or empty names, unknown datatypes, a
    count of 0, or a field reaching past the end of the point.
    """
    out: list[Field] = []
    seen: set[str] = set()
    for raw in fields:
        if len(out) >= MAX_FIELDS:
            raise CloudFieldError(f"PointCloud2 has more than {MAX_FIELDS} fields")
        name = getattr(raw, "name", None)
        if not isinstance(name, str) or not name:
            raise CloudFieldError(f"PointCloud2 field has an empty or non-string name: {name!r}")
        if name in seen:
            raise CloudFieldError(f"PointCloud2 field {name!r} appears more than once")
        seen.add(name)
        datatype = _as_int(getattr(raw, "datatype", None), f"field {name!r} datatype")
        if datatype not in DATATYPES:
            raise CloudFieldError(
                f"PointCloud2 field {name!r} has unsupported datatype {datatype} "
                f"(supported: {sorted(DATATYPES)})"
            )
        offset = _as_int(getattr(raw, "offset", None), f"field {name!r} offset")
        count = _as_int(getattr(raw, "count", None), f"field {name!r} count")
        if count == 0:
            raise CloudFieldError(f"PointCloud2 field {name!r} has count 0")
        end = offset + DATATYPES[datatype].itemsize * count
        if end > point_step:
            raise CloudFieldError(
                f"PointCloud2 field {name!r} spans bytes {offset}..{end} "
                f"beyond point_step {point_step}"
            )
        out.append(Field(name, offset, datatype, count))
    return tuple(out)


def structured_dtype(fields: Sequence[Field], point_step: int, is_bigendian: bool) -> np.dtype:
    """The numpy dtype of one point: one entry per field, itemsize = point_step."""
    order = _byteorder(is_bigendian)
    formats: list[Any] = []
    for f in fields:
        base = DATATYPES[f.datatype].newbyteorder(order)
        formats.append(base if f.count == 1 else (base, (f.count,)))
    try:
        return np.dtype(
            {
                "names": [f.name for f in fields],
                "formats": formats,
                "offsets": [f.offset for f in fields],
                "itemsize": point_step,
            }
        )
    except (ValueError, TypeError) as exc:  # e.g. numpy refusing a layout
        raise CloudFieldError(f"PointCloud2 fields do not form a valid point layout: {exc}") from exc


def _buffer(data: Any) -> np.ndarray:
    """The message payload as a read-only uint8 array without copying (bytes, array.array, ndarray)."""
    try:
        buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    except (TypeError, ValueError) as exc:
        raise CloudLayoutError(f"PointCloud2 data is not a byte buffer: {type(data).__name__}") from exc
    if buf.dtype != np.uint8:
        buf = buf.view(np.uint8) if buf.flags.c_contiguous else np.ascontiguousarray(buf).view(np.uint8)
    return buf.reshape(-1)


def view_cloud(msg: Any) -> CloudView:
    """Validate a PointCloud2 and return a zero-copy structured view of its points.

    Handles organised (height > 1) and unorganised clouds, row padding
    (row_step > width * point_step), per-point padding and either byte order.
    """
    try:
        height = _as_int(msg.height, "height")
        width = _as_int(msg.width, "width")
        point_step = _as_int(msg.point_step, "point_step")
        row_step = _as_int(msg.row_step, "row_step")
        raw_fields = msg.fields
        data = msg.data
        is_bigendian = bool(msg.is_bigendian)
    except AttributeError as exc:
        raise CloudLayoutError(f"not a PointCloud2 message: {exc}") from exc

    if height * width > MAX_POINTS:
        raise CloudLayoutError(
            f"PointCloud2 claims {width} x {height} points, more than the limit of {MAX_POINTS}"
        )
    if point_step > MAX_POINT_STEP:
        raise CloudLayoutError(f"PointCloud2 point_step {point_step} exceeds {MAX_POINT_STEP}")
    fields = read_fields(raw_fields, point_step)
    dtype = structured_dtype(fields, point_step, is_bigendian)
    buf = _buffer(data)
    n = height * width
    if n == 0:
        return CloudView(fields, np.zeros(0, dtype=dtype), point_step, is_bigendian, height, width)
    if point_step == 0:
        raise CloudLayoutError("PointCloud2 point_step is 0 for a non-empty cloud")
    if row_step < width * point_step:
        raise CloudLayoutError(
            f"PointCloud2 row_step {row_step} is smaller than width * point_step "
            f"= {width} * {point_step}"
        )
    needed = (height - 1) * row_step + width * point_step
    if buf.size < needed:
        raise CloudLayoutError(
            f"PointCloud2 data has {buf.size} bytes, fewer than the {needed} its "
            f"height {height}, width {width}, point_step {point_step}, row_step {row_step} need"
        )
    if row_step == width * point_step:
        records = buf[: n * point_step].view(dtype)
    else:
        # Padded rows: a strided (height, width) view, flattened (one copy) row-major.
        grid = np.lib.stride_tricks.as_strided(
            buf, shape=(height, width * point_step), strides=(row_step, 1), writeable=False
        )
        records = np.ascontiguousarray(grid).reshape(-1).view(dtype)
    return CloudView(fields, records, point_step, is_bigendian, height, width)


def _scalar_column(view: CloudView, name: str) -> np.ndarray:
    """One field as a 1-D native array (the first element where count > 1)."""
    column = view.records[name]
    return column[:, 0] if column.ndim == 2 else column


def _field(view: CloudView, name: str) -> Field | None:
    return next((f for f in view.fields if f.name == name), None)


def decode_xyz_intensity(
    msg: Any, intensity_names: Sequence[str] = INTENSITY_NAMES
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.intp]]:
    """Decode the finite points of a PointCloud2 (or of a :class:`CloudView` already made of one).

    Returns ``points`` (M, 3) float32 C-contiguous, ``intensity`` (M,) float32
    (zeros where the cloud has none of ``intensity_names``; non-finite
    intensities become 0) and ``valid_index`` (M,) indices of those points in
    the original cloud (row-major), so results can be mapped back to the
    message's points for /mos/static_points and /mos/labels.

    Points with any non-finite coordinate are skipped. x, y, z must be float32
    or float64 with count 1; the intensity may be any numeric datatype.
    """
    view = msg if isinstance(msg, CloudView) else view_cloud(msg)
    for axis in ("x", "y", "z"):
        f = _field(view, axis)
        if f is None:
            raise CloudFieldError(
                f"PointCloud2 has no {axis!r} field (fields: {', '.join(view.names) or 'none'})"
            )
        if f.datatype not in (FLOAT32, FLOAT64) or f.count != 1:
            raise CloudFieldError(
                f"PointCloud2 field {axis!r} must be float32 or float64 with count 1, "
                f"got datatype {f.datatype} count {f.count}"
            )
    xyz = np.empty((view.size, 3), dtype=np.float32)
    for column, axis in enumerate(("x", "y", "z")):
        # Casting float64 -> float32 can overflow to inf: caught by the finite test below.
        with np.errstate(over="ignore", invalid="ignore"):
            xyz[:, column] = view.records[axis]
    # Per column: a reduction over the short axis 1 of an (N, 3) array is 25x slower.
    finite = np.isfinite(xyz[:, 0])
    finite &= np.isfinite(xyz[:, 1])
    finite &= np.isfinite(xyz[:, 2])
    valid_index = np.flatnonzero(finite)
    points = np.take(xyz, valid_index, axis=0) if valid_index.size != view.size else xyz

    name = next((n for n in intensity_names if _field(view, n) is not None), None)
    if name is None:
        intensity = np.zeros(valid_index.size, dtype=np.float32)
    else:
        column = _scalar_column(view, name)
        with np.errstate(over="ignore", invalid="ignore"):
            if valid_index.size != view.size:
                column = column[valid_index]
            intensity = column.astype(np.float32)  # always a copy: the message buffer stays untouched
        intensity[~np.isfinite(intensity)] = 0.0
    return points, intensity, valid_index


def sweep_phases(msg: Any, valid_index: np.ndarray, time_names: Sequence[str] = TIME_NAMES) -> np.ndarray | None:
    """Per point ``valid_index`` (indices into the cloud, as :func:`decode_xyz_intensity` returns them), its firing
    time within the sweep from the cloud's own per-point time field (the first of ``time_names`` present, any unit):
    -0.5 at the earliest, +0.5 at the latest, linearly between (float64). None where the cloud has no such field of
    count 1, or its times there are not all finite or do not differ."""
    view = msg if isinstance(msg, CloudView) else view_cloud(msg)
    field = next((f for f in (_field(view, n) for n in time_names) if f is not None), None)
    if field is None or field.count != 1 or len(valid_index) == 0:
        return None
    times = _scalar_column(view, field.name)[valid_index].astype(np.float64)
    if not np.all(np.isfinite(times)):
        return None
    first, last = float(times.min()), float(times.max())
    if not last > first:
        return None
    return (times - first) / (last - first) - 0.5


# ----------------------------------------------------------------------------- encoding

#: Builds a PointField message object: field_factory(name=..., offset=..., datatype=..., count=...).
FieldFactory = Callable[..., Any]


def fields_for_dtype(dtype: np.dtype) -> tuple[Field, ...]:
    """PointFields for a structured numpy dtype (scalar or 1-D subarray members)."""
    if dtype.names is None:
        raise CloudFieldError(f"not a structured dtype: {dtype}")
    out = []
    for name in dtype.names:
        member, offset = dtype.fields[name][:2]  # type: ignore[index]
        base, shape = (member.subdtype if member.subdtype else (member, ()))
        datatype = _NUMPY_TO_DATATYPE.get(base.newbyteorder("="))
        if datatype is None or len(shape) > 1:
            raise CloudFieldError(f"field {name!r} has a dtype PointCloud2 cannot carry: {member}")
        out.append(Field(name, int(offset), datatype, int(np.prod(shape)) if shape else 1))
    return tuple(out)


def _set_data(msg: Any, data: np.ndarray) -> None:
    """Assign the payload in the form the message type wants.

    rosbags' dataclasses hold an ndarray (its serialiser needs one); rclpy's
    messages hold an array.array and take bytes fastest.
    """
    if isinstance(getattr(msg, "data", None), np.ndarray):
        msg.data = np.ascontiguousarray(data, dtype=np.uint8).reshape(-1)
    else:
        msg.data = np.ascontiguousarray(data).tobytes()


def fill_cloud(
    msg: Any,
    fields: Sequence[Field],
    point_step: int,
    data: np.ndarray,
    *,
    width: int,
    height: int = 1,
    is_bigendian: bool = False,
    is_dense: bool = True,
    field_factory: FieldFactory,
) -> Any:
    """Fill fields, layout and data of a PointCloud2 message object in place (header untouched).

    ``data`` is the packed payload (any array whose bytes are height * width *
    point_step long); ``field_factory`` makes the PointField objects of the
    message's own type (``sensor_msgs.msg.PointField`` for rclpy, the
    typestore's class for rosbags). Returns ``msg`` for chaining.
    """
    payload = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    if payload.size != width * height * point_step:
        raise CloudLayoutError(
            f"payload has {payload.size} bytes, expected {width} * {height} * {point_step}"
        )
    msg.fields = [
        field_factory(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields
    ]
    msg.height = int(height)
    msg.width = int(width)
    msg.point_step = int(point_step)
    msg.row_step = int(width * point_step)
    msg.is_bigendian = bool(is_bigendian)
    msg.is_dense = bool(is_dense)
    _set_data(msg, payload)
    return msg


def _is_big_endian(dtype: np.dtype) -> bool:
    """Byte order of a structured dtype's members; PointCloud2 carries one order per cloud."""
    orders = set()
    for name in dtype.names or ():
        base = dtype.fields[name][0].base  # type: ignore[index]
        if base.itemsize > 1:
            orders.add(base.byteorder if base.byteorder != "=" else ("<" if np.little_endian else ">"))
    if len(orders) > 1:
        raise CloudFieldError("structured dtype mixes byte orders")
    return orders == {">"}


def fill_from_records(msg: Any, records: np.ndarray, *, field_factory: FieldFactory,
                      height: int = 1, is_dense: bool = True) -> Any:
    """Fill an unorganised (or ``height``-row) cloud from a 1-D structured array."""
    fields = fields_for_dtype(records.dtype)
    n = int(records.size)
    if height < 1 or n % height:
        raise CloudLayoutError(f"{n} points do not form {height} rows")
    return fill_cloud(msg, fields, records.dtype.itemsize, records, width=n // height, height=height,
                      is_bigendian=_is_big_endian(records.dtype), is_dense=is_dense,
                      field_factory=field_factory)


XYZI_DTYPE = np.dtype(
    {"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 12],
     "itemsize": 16}
)


def xyzi_records(points: np.ndarray, intensity: np.ndarray | None = None) -> np.ndarray:
    """Pack (N,3) points and optional (N,) intensity into the common 16-byte x,y,z,intensity layout."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ScanError(f"points must have shape (N, 3), got {pts.shape}")
    records = np.zeros(pts.shape[0], dtype=XYZI_DTYPE)
    records["x"], records["y"], records["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if intensity is not None:
        inten = np.asarray(intensity).reshape(-1)
        if inten.shape[0] != pts.shape[0]:
            raise ScanError(f"intensity has {inten.shape[0]} values for {pts.shape[0]} points")
        records["intensity"] = inten
    return records


def fill_xyzi(msg: Any, points: np.ndarray, intensity: np.ndarray | None = None, *,
              field_factory: FieldFactory) -> Any:
    """Fill ``msg`` as an unorganised float32 x, y, z, intensity cloud (the layout most drivers use)."""
    return fill_from_records(msg, xyzi_records(points, intensity), field_factory=field_factory)


# ----------------------------------------------------------------------------- subsets

def _normalise_index(index: np.ndarray, size: int) -> np.ndarray:
    idx = np.asarray(index)
    if idx.dtype == np.bool_:
        if idx.shape != (size,):
            raise ScanError(f"boolean mask has shape {idx.shape}, cloud has {size} points")
        return np.flatnonzero(idx)
    idx = idx.astype(np.intp, copy=False).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= size):
        raise ScanError(f"point index out of range for a cloud of {size} points")
    return idx


def raw_points(view: CloudView, index: np.ndarray) -> np.ndarray:
    """The raw bytes of the selected points: (M, point_step) uint8, every field and padding kept."""
    rows = view.records.view(np.uint8).reshape(view.size, view.point_step)
    # One opaque item per point: taking M items copies each as a block, 25x faster than a 2-D fancy index.
    items = rows.view(np.dtype((np.void, view.point_step))).reshape(view.size)
    return np.take(items, _normalise_index(index, view.size)).view(np.uint8).reshape(-1, view.point_step)


def fill_subset(msg_out: Any, source: Any | CloudView, index: np.ndarray, *,
                field_factory: FieldFactory) -> Any:
    """Fill ``msg_out`` with the selected points of ``source`` keeping all their fields.

    The result is unorganised (height 1) with the source's fields, byte order
    and point_step; used for /mos/static_points and /mos/moving_points so that
    downstream consumers get exactly the driver's layout back.
    """
    view = source if isinstance(source, CloudView) else view_cloud(source)
    raw = raw_points(view, index)
    return fill_cloud(msg_out, view.fields, view.point_step, raw, width=raw.shape[0],
                      is_bigendian=view.is_bigendian, is_dense=True, field_factory=field_factory)


def _align(value: int, alignment: int) -> int:
    return -(-value // alignment) * alignment


def fill_with_extra_fields(
    msg_out: Any,
    source: Any | CloudView,
    index: np.ndarray,
    extra: Sequence[tuple[str, np.ndarray]],
    *,
    field_factory: FieldFactory,
) -> Any:
    """Fill ``msg_out`` with the selected points of ``source`` plus new per-point fields.

    ``extra`` is a list of (name, values) with one value per *selected* point;
    each new field is appended after the source's point_step at its natural
    alignment, in the source's byte order (e.g. ``moving`` uint8 and
    ``moving_probability`` float32 for /mos/labels). Raises CloudFieldError if a
    name already exists in the source.
    """
    view = source if isinstance(source, CloudView) else view_cloud(source)
    raw = raw_points(view, index)
    m = raw.shape[0]
    order = _byteorder(view.is_bigendian)
    added: list[tuple[Field, np.dtype, np.ndarray]] = []
    taken = set(view.names)
    offset = view.point_step
    for name, value in extra:
        if name in taken:
            raise CloudFieldError(f"cannot add field {name!r}: the cloud already has one")
        taken.add(name)
        arr = np.asarray(value).reshape(-1)
        if arr.shape[0] != m:
            raise ScanError(f"field {name!r} has {arr.shape[0]} values for {m} points")
        base = arr.dtype.newbyteorder("=")
        if base not in _NUMPY_TO_DATATYPE:
            raise CloudFieldError(f"field {name!r} has a dtype PointCloud2 cannot carry: {arr.dtype}")
        offset = _align(offset, base.itemsize)
        added.append((Field(name, offset, _NUMPY_TO_DATATYPE[base], 1), base.newbyteorder(order), arr))
        offset += base.itemsize
    point_step = _align(offset, 4)
    # One structured record per output point: the source bytes as an opaque block, then the new
    # fields; whole-column assignments to it are contiguous loops, not strided byte copies.
    layout = np.dtype({
        "names": ["source"] + [f"extra{i}" for i in range(len(added))],
        "formats": [np.dtype((np.void, view.point_step))] + [dtype for _, dtype, _ in added],
        "offsets": [0] + [field.offset for field, _, _ in added],
        "itemsize": point_step,
    })
    out = np.zeros(m, dtype=layout)
    out["source"] = raw.view(np.dtype((np.void, view.point_step))).reshape(m)
    for i, (_, _, arr) in enumerate(added):
        out[f"extra{i}"] = arr
    return fill_cloud(msg_out, view.fields + tuple(f for f, _, _ in added), point_step, out, width=m,
                      is_bigendian=view.is_bigendian, is_dense=True, field_factory=field_factory)
