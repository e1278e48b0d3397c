"""PointCloud2 <-> numpy: hand-built rclpy/rosbags messages and a fuzz test of the decoder."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import PointCloud2, PointField

from ros2_mos.core.errors import ScanError
from ros2_mos.io.pointcloud2 import (
    DATATYPES,
    FLOAT32,
    FLOAT64,
    INT16,
    MAX_POINTS,
    UINT8,
    CloudFieldError,
    CloudLayoutError,
    decode_xyz_intensity,
    fill_from_records,
    fill_subset,
    fill_with_extra_fields,
    fill_xyzi,
    view_cloud,
)


def make_cloud(dtype: np.dtype, records: np.ndarray, *, height: int = 1, row_pad: int = 0,
               is_bigendian: bool = False) -> PointCloud2:
    """An rclpy PointCloud2 from a structured array, built by hand (not through the encoder)."""
    n = records.size
    width = n // height
    row = records.tobytes()
    step = dtype.itemsize
    rows = [row[r * width * step:(r + 1) * width * step] + b"\xee" * row_pad for r in range(height)]
    msg = PointCloud2()
    msg.height, msg.width = height, width
    msg.point_step = step
    msg.row_step = width * step + row_pad
    msg.is_bigendian = is_bigendian
    msg.fields = []
    to_dt = {np.dtype(v).str[1:]: k for k, v in DATATYPES.items()}
    for name in dtype.names:
        member, offset = dtype.fields[name][:2]
        base, shape = member.subdtype if member.subdtype else (member, ())
        msg.fields.append(PointField(name=name, offset=offset, datatype=to_dt[base.str[1:]],
                                     count=int(np.prod(shape)) if shape else 1))
    msg.data = b"".join(rows)
    return msg


def fields_of(msg: Any) -> list[tuple[str, int, int, int]]:
    return [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]


def test_xyzi_round_trip_rclpy() -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(100, 3)).astype(np.float32)
    inten = rng.random(100).astype(np.float32)
    msg = fill_xyzi(PointCloud2(), pts, inten, field_factory=PointField)
    assert msg.point_step == 16 and msg.row_step == 1600 and msg.width == 100 and msg.height == 1
    assert fields_of(msg) == [("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1),
                              ("intensity", 12, FLOAT32, 1)]
    got_pts, got_int, valid = decode_xyz_intensity(msg)
    assert got_pts.dtype == np.float32 and got_pts.flags.c_contiguous and got_pts.shape == (100, 3)
    np.testing.assert_array_equal(got_pts, pts)
    np.testing.assert_array_equal(got_int, inten)
    np.testing.assert_array_equal(valid, np.arange(100))


def test_big_endian_float64_padding_uint16_reflectivity() -> None:
    """An Ouster-like layout: float64 xyz big-endian, padding, reflectivity uint16, ring uint8."""
    dt = np.dtype({"names": ["x", "y", "z", "reflectivity", "ring"],
                   "formats": [">f8", ">f8", ">f8", ">u2", "u1"],
                   "offsets": [0, 8, 16, 28, 31], "itemsize": 40})
    rec = np.zeros(7, dtype=dt)
    rec["x"] = np.arange(7) * 1.5
    rec["y"] = -np.arange(7)
    rec["z"] = 0.25
    rec["reflectivity"] = np.arange(7) * 1000
    rec["ring"] = 3
    msg = make_cloud(dt, rec, is_bigendian=True)
    pts, inten, valid = decode_xyz_intensity(msg)
    np.testing.assert_array_equal(pts[:, 0], (np.arange(7) * 1.5).astype(np.float32))
    np.testing.assert_array_equal(pts[:, 1], -np.arange(7, dtype=np.float32))
    np.testing.assert_array_equal(inten, (np.arange(7) * 1000).astype(np.float32))
    assert valid.tolist() == list(range(7))


def test_organised_cloud_with_row_padding_and_nans() -> None:
    dt = np.dtype({"names": ["x", "y", "z", "intensity"], "formats": ["<f4", "<f4", "<f4", "<u1"],
                   "offsets": [0, 4, 8, 16], "itemsize": 20})
    height, width = 4, 5
    rec = np.zeros(height * width, dtype=dt)
    rec["x"] = np.arange(20)
    rec["y"] = 1.0
    rec["z"] = 2.0
    rec["intensity"] = np.arange(20) + 100
    rec["x"][[3, 7]] = np.nan
    rec["z"][11] = np.inf
    msg = make_cloud(dt, rec, height=height, row_pad=12)
    assert msg.row_step == width * 20 + 12
    pts, inten, valid = decode_xyz_intensity(msg)
    keep = [i for i in range(20) if i not in (3, 7, 11)]
    assert valid.tolist() == keep
    np.testing.assert_array_equal(pts[:, 0], np.array(keep, dtype=np.float32))
    np.testing.assert_array_equal(inten, np.array(keep, dtype=np.float32) + 100)


@pytest.mark.parametrize("name", ["intensity", "reflectivity", "remission"])
def test_intensity_names(name: str) -> None:
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), (name, "<f8")])
    rec = np.zeros(3, dtype=dt)
    rec[name] = [1.0, np.nan, 3.0]
    _, inten, _ = decode_xyz_intensity(make_cloud(dt, rec))
    assert inten.tolist() == [1.0, 0.0, 3.0]


def test_no_intensity_gives_zeros_and_count_gt1_takes_first() -> None:
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    _, inten, _ = decode_xyz_intensity(make_cloud(dt, np.ones(4, dtype=dt)))
    assert inten.dtype == np.float32 and inten.tolist() == [0.0] * 4
    dt2 = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<u2", (2,))])
    rec = np.zeros(2, dtype=dt2)
    rec["intensity"] = [[5, 6], [7, 8]]
    _, inten2, _ = decode_xyz_intensity(make_cloud(dt2, rec))
    assert inten2.tolist() == [5.0, 7.0]


def test_empty_only_nan_and_single_point() -> None:
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    pts, inten, valid = decode_xyz_intensity(make_cloud(dt, np.zeros(0, dtype=dt)))
    assert pts.shape == (0, 3) and inten.shape == (0,) and valid.shape == (0,)
    rec = np.zeros(5, dtype=dt)
    rec["x"] = np.nan
    pts, _, valid = decode_xyz_intensity(make_cloud(dt, rec))
    assert pts.shape == (0, 3) and valid.size == 0
    one = np.ones(1, dtype=dt)
    pts, _, valid = decode_xyz_intensity(make_cloud(dt, one))
    assert pts.tolist() == [[1.0, 1.0, 1.0]] and valid.tolist() == [0]


def test_float64_overflow_to_float32_is_skipped() -> None:
    dt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    rec = np.ones(2, dtype=dt)
    rec["x"][0] = 1e300
    _, _, valid = decode_xyz_intensity(make_cloud(dt, rec))
    assert valid.tolist() == [1]


def _xyz_msg(n: int = 4) -> PointCloud2:
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    return make_cloud(dt, np.ones(n, dtype=dt))


@pytest.mark.parametrize(
    ("mutate", "error", "match"),
    [
        (lambda m: setattr(m, "fields", [f for f in m.fields if f.name != "y"]), CloudFieldError, "no 'y'"),
        (lambda m: setattr(m, "point_step", 8), CloudFieldError, "beyond point_step"),
        (lambda m: setattr(m, "data", bytes(m.data)[:-1]), CloudLayoutError, "fewer than"),
        (lambda m: setattr(m, "row_step", 10), CloudLayoutError, "row_step"),
        (lambda m: setattr(m, "width", 2**31), CloudLayoutError, "limit"),
        (lambda m: (setattr(m, "height", 2**20), setattr(m, "width", 2**20)), CloudLayoutError, "limit"),
        (lambda m: setattr(m, "height", 3), CloudLayoutError, "fewer than"),
        (lambda m: m.fields.append(PointField(name="x", offset=0, datatype=FLOAT32, count=1)),
         CloudFieldError, "more than once"),
        (lambda m: setattr(m.fields[2], "datatype", 9), CloudFieldError, "unsupported datatype"),
        (lambda m: setattr(m.fields[2], "datatype", 0), CloudFieldError, "unsupported datatype"),
        (lambda m: setattr(m.fields[0], "datatype", INT16), CloudFieldError, "float32 or float64"),
        (lambda m: setattr(m.fields[0], "count", 0), CloudFieldError, "count 0"),
        (lambda m: setattr(m.fields[0], "count", 2), CloudFieldError, "beyond point_step|count 1"),
        (lambda m: setattr(m, "point_step", 0), CloudFieldError, "beyond point_step"),
        (lambda m: setattr(m.fields[1], "name", ""), CloudFieldError, "empty"),
    ],
)
def test_invalid_clouds_raise_scan_error(mutate: Any, error: type, match: str) -> None:
    msg = _xyz_msg()
    mutate(msg)
    with pytest.raises(error, match=match) as info:
        decode_xyz_intensity(msg)
    assert isinstance(info.value, ScanError)


def test_not_a_cloud() -> None:
    with pytest.raises(ScanError, match="not a PointCloud2"):
        decode_xyz_intensity(object())


def _ouster_like() -> tuple[np.dtype, np.ndarray]:
    dt = np.dtype({"names": ["x", "y", "z", "intensity", "t", "ring"],
                   "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2"],
                   "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})
    rec = np.zeros(6, dtype=dt)
    rec["x"] = np.arange(6)
    rec["y"] = 2
    rec["z"] = 3
    rec["intensity"] = np.arange(6) * 10
    rec["t"] = np.arange(6) * 1000
    rec["ring"] = np.arange(6) % 2
    return dt, rec


def test_subset_keeps_every_field_and_byte() -> None:
    dt, rec = _ouster_like()
    src = make_cloud(dt, rec, height=2, row_pad=4)
    out = fill_subset(PointCloud2(), src, np.array([5, 0, 2]), field_factory=PointField)
    assert fields_of(out) == fields_of(src)
    assert out.point_step == 32 and out.width == 3 and out.height == 1 and out.row_step == 96
    got = np.frombuffer(bytes(out.data), dtype=dt)
    np.testing.assert_array_equal(got, rec[[5, 0, 2]])
    mask = np.array([True, False, False, True, False, False])
    got_mask = np.frombuffer(bytes(fill_subset(PointCloud2(), src, mask, field_factory=PointField).data), dt)
    np.testing.assert_array_equal(got_mask, rec[[0, 3]])
    empty = fill_subset(PointCloud2(), src, np.zeros(0, dtype=int), field_factory=PointField)
    assert empty.width == 0 and len(empty.data) == 0
    with pytest.raises(ScanError, match="out of range"):
        fill_subset(PointCloud2(), src, np.array([6]), field_factory=PointField)


@pytest.mark.parametrize("big", [False, True])
def test_extra_fields_for_labels(big: bool) -> None:
    dt, rec = _ouster_like()
    if big:
        dt = dt.newbyteorder(">")
        rec = rec.astype(dt)
    src = make_cloud(dt, rec, is_bigendian=big)
    idx = np.array([1, 3, 4])
    labels = np.array([1, 0, 1], dtype=np.uint8)
    prob = np.array([0.9, 0.1, 0.75], dtype=np.float32)
    out = fill_with_extra_fields(PointCloud2(), src, idx, [("moving", labels), ("moving_probability", prob)],
                                 field_factory=PointField)
    assert out.is_bigendian == big
    assert fields_of(out)[-2:] == [("moving", 32, UINT8, 1), ("moving_probability", 36, FLOAT32, 1)]
    assert out.point_step == 40 and out.row_step == 120
    view = view_cloud(out)
    np.testing.assert_array_equal(view.records["moving"], labels)
    np.testing.assert_array_equal(view.records["moving_probability"], prob)
    for name in dt.names:
        np.testing.assert_array_equal(view.records[name], rec[name][idx])
    pts, _, _ = decode_xyz_intensity(out)
    np.testing.assert_array_equal(pts[:, 0], [1, 3, 4])
    with pytest.raises(CloudFieldError, match="already has"):
        fill_with_extra_fields(PointCloud2(), src, idx, [("ring", labels)], field_factory=PointField)
    with pytest.raises(ScanError, match="values for"):
        fill_with_extra_fields(PointCloud2(), src, idx, [("m", labels[:2])], field_factory=PointField)


def test_rosbags_messages_work_the_same() -> None:
    from ros2_mos.io.bags import empty_cloud, point_field

    dt, rec = _ouster_like()
    src = fill_from_records(empty_cloud(5, "f"), rec, field_factory=point_field)
    assert isinstance(src.data, np.ndarray)
    pts, inten, _ = decode_xyz_intensity(src)
    np.testing.assert_array_equal(inten, rec["intensity"])
    out = fill_with_extra_fields(empty_cloud(5, "f"), src, np.arange(6),
                                 [("moving", np.ones(6, np.uint8))], field_factory=point_field)
    assert isinstance(out.data, np.ndarray) and out.data.dtype == np.uint8
    assert view_cloud(out).records["moving"].tolist() == [1] * 6
    # The same layout as an rclpy message decodes identically.
    np.testing.assert_array_equal(decode_xyz_intensity(make_cloud(dt, rec))[0], pts)


# ----------------------------------------------------------------------------- fuzz

_FMT = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 8: "d"}


@dataclass
class FakeField:
    name: Any
    offset: Any
    datatype: Any
    count: Any


@dataclass
class FakeCloud:
    """A duck-typed message, as any object with PointCloud2's attributes is accepted."""

    height: Any
    width: Any
    fields: list
    is_bigendian: bool
    point_step: Any
    row_step: Any
    data: bytes
    is_dense: bool = False
    header: Any = None


def reference_decode(msg: FakeCloud) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Slow, independent oracle (struct per point); None where the message must be rejected."""
    names = [f.name for f in msg.fields]
    if len(set(names)) != len(names) or any(not n for n in names):
        return None
    if msg.height * msg.width > MAX_POINTS:
        return None
    if max(msg.height, msg.width, msg.point_step, msg.row_step) > 2**32 - 1:
        return None  # PointCloud2's uint32 fields cannot hold it (e.g. height 2**32 with width 0)
    for f in msg.fields:
        if f.datatype not in _FMT or f.count < 1:
            return None
        if f.offset + struct.calcsize(_FMT[f.datatype]) * f.count > msg.point_step:
            return None
    by_name = {f.name: f for f in msg.fields}
    if any(a not in by_name or by_name[a].datatype not in (FLOAT32, FLOAT64) or by_name[a].count != 1
           for a in "xyz"):
        return None
    n = msg.height * msg.width
    if n:
        if msg.point_step == 0 or msg.row_step < msg.width * msg.point_step:
            return None
        if len(msg.data) < (msg.height - 1) * msg.row_step + msg.width * msg.point_step:
            return None
    e = ">" if msg.is_bigendian else "<"
    inten_field = next((by_name[k] for k in ("intensity", "reflectivity", "remission") if k in by_name), None)
    pts, inten, valid = [], [], []
    for i in range(n):
        base = (i // msg.width) * msg.row_step + (i % msg.width) * msg.point_step
        xyz = [struct.unpack_from(e + _FMT[by_name[a].datatype], msg.data, base + by_name[a].offset)[0]
               for a in "xyz"]
        with np.errstate(over="ignore", invalid="ignore"):
            xyz32 = np.array(xyz, dtype=np.float64).astype(np.float32)
        if not np.isfinite(xyz32).all():
            continue
        value = 0.0
        if inten_field is not None:
            value = struct.unpack_from(e + _FMT[inten_field.datatype], msg.data, base + inten_field.offset)[0]
        with np.errstate(over="ignore", invalid="ignore"):
            v32 = np.float32(value)
        pts.append(xyz32)
        inten.append(v32 if np.isfinite(v32) else np.float32(0))
        valid.append(i)
    return (np.array(pts, dtype=np.float32).reshape(-1, 3), np.array(inten, dtype=np.float32),
            np.array(valid, dtype=np.intp))


_EXTRA_NAMES = st.sampled_from(["intensity", "reflectivity", "remission", "ring", "t", "x", ""])


@st.composite
def clouds(draw: Any) -> FakeCloud:
    """A random valid layout (any datatypes, padding, organised or not, either byte order, random
    payload bytes so NaN/inf/garbage values appear), then with probability 1/2 one or more hostile
    mutations: duplicate/empty names, bad datatypes or counts, offsets beyond point_step, short
    data, row_step mismatches, huge width/height claims, a missing coordinate."""
    fields: list[FakeField] = []
    offset = 0
    for name in ["x", "y", "z"] + draw(st.lists(_EXTRA_NAMES.filter(lambda n: n not in "xyz"),
                                                max_size=3, unique=True)):
        xyz = name in ("x", "y", "z")
        datatype = draw(st.sampled_from([FLOAT32, FLOAT64] if xyz else list(_FMT)))
        count = 1 if xyz else draw(st.integers(1, 2))
        offset += draw(st.integers(0, 3))
        fields.append(FakeField(name, offset, datatype, count))
        offset += struct.calcsize(_FMT[datatype]) * count
    fields = draw(st.permutations(fields))
    point_step = offset + draw(st.integers(0, 8))
    height, width = draw(st.integers(0, 4)), draw(st.integers(0, 12))
    row_step = width * point_step + draw(st.sampled_from([0, 0, 0, 3, 8]))
    length = max(0, (height - 1) * row_step + width * point_step) + draw(st.sampled_from([0, 0, 1, 16]))
    data = draw(st.binary(min_size=length, max_size=length))
    msg = FakeCloud(height, width, list(fields), draw(st.booleans()), point_step, row_step, data)
    for mutation in draw(st.lists(st.integers(0, 9), max_size=2)) if draw(st.booleans()) else []:
        k = draw(st.integers(0, len(msg.fields) - 1))
        f = msg.fields[k]
        if mutation == 0:
            msg.fields.append(FakeField(draw(st.sampled_from(["x", "y", "z", "intensity"])), 0, FLOAT32, 1))
        elif mutation == 1:
            msg.fields[k] = FakeField(f.name, f.offset, draw(st.sampled_from([0, 9, 10, 255])), f.count)
        elif mutation == 2:
            msg.fields[k] = FakeField(f.name, f.offset, f.datatype, draw(st.integers(0, 5)))
        elif mutation == 3:
            msg.fields[k] = FakeField(f.name, draw(st.integers(0, msg.point_step + 16)), f.datatype, f.count)
        elif mutation == 4:
            msg.data = msg.data[: draw(st.integers(0, len(msg.data)))]
        elif mutation == 5:
            msg.row_step = draw(st.integers(0, msg.row_step + 4))
        elif mutation == 6:
            msg.width = draw(st.sampled_from([2**24, 2**31, 2**40, 2**63]))
        elif mutation == 7:
            msg.height = draw(st.sampled_from([2**20, 2**32]))
        elif mutation == 8:
            del msg.fields[k]
        else:
            msg.point_step = draw(st.integers(0, msg.point_step))
    return msg


def test_fuzz_decoder_decodes_correctly_or_raises_scan_error() -> None:
    stats = {"cases": 0, "decoded": 0, "rejected": 0, "points": 0}

    @settings(max_examples=1000, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(clouds())
    def check(msg: FakeCloud) -> None:
        stats["cases"] += 1
        expected = reference_decode(msg)
        if expected is None:
            with pytest.raises(ScanError):
                decode_xyz_intensity(msg)
            stats["rejected"] += 1
            return
        pts, inten, valid = decode_xyz_intensity(msg)
        np.testing.assert_array_equal(valid, expected[2])
        np.testing.assert_array_equal(pts, expected[0])
        np.testing.assert_array_equal(inten, expected[1])
        assert pts.flags.c_contiguous and pts.dtype == np.float32
        stats["decoded"] += 1
        stats["points"] += len(valid)

    check()
    print(f"fuzz: {stats}")
    # Both branches must have been exercised for the test to mean anything.
    assert stats["decoded"] > 50 and stats["rejected"] > 50, stats
