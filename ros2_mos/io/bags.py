"""rosbag2 bags (mcap or sqlite3) read and written with ``rosbags``, without a ROS install.

``rosbag2``/``ros2 bag`` are not on PyPI, so the simulator, ``replay`` and the
offline ``process`` command use the pure-Python ``rosbags`` library with the
Jazzy typestore; the bags it writes open in ``ros2 bag`` and Foxglove. Messages
are rosbags dataclasses, which :mod:`ros2_mos.io.pointcloud2` handles like rclpy's.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ros2_mos.core.atomic import output_error
from ros2_mos.core.errors import DatasetError
from ros2_mos.io.pointcloud2 import fill_xyzi

#: Message type names used in this project's bags.
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
IMAGE = "sensor_msgs/msg/Image"

#: rosbag2 metadata version written; 8 is what Jazzy's rosbag2 writes and reads.
BAG_VERSION = 8

_STORAGES = ("mcap", "sqlite3")


def typestore() -> Any:
    """The ROS 2 Jazzy typestore (cached): message classes and (de)serialisers."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import Stores, get_typestore

        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    return _TYPESTORE


_TYPESTORE: Any = None


def msg_class(msgtype: str) -> Any:
    """The rosbags dataclass for a message type name such as ``sensor_msgs/msg/PointCloud2``."""
    try:
        return typestore().types[msgtype]
    except KeyError as exc:
        raise DatasetError(f"unknown message type {msgtype!r}") from exc


def header(stamp_ns: int, frame_id: str) -> Any:
    """A std_msgs/Header for a stamp in nanoseconds."""
    ts = typestore()
    time_cls = ts.types["builtin_interfaces/msg/Time"]
    header_cls = ts.types["std_msgs/msg/Header"]
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return header_cls(stamp=time_cls(sec=sec, nanosec=nanosec), frame_id=frame_id)


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (rosbags or rclpy) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def point_field(**kwargs: Any) -> Any:
    """PointField factory for :mod:`ros2_mos.io.pointcloud2`'s fill functions (rosbags type)."""
    return msg_class("sensor_msgs/msg/PointField")(**kwargs)


def empty_cloud(stamp_ns: int, frame_id: str) -> Any:
    """An empty rosbags PointCloud2 with a header, to be filled by a ``fill_*`` function."""
    return msg_class(POINTCLOUD2)(
        header=header(stamp_ns, frame_id), height=1, width=0, fields=[], is_bigendian=False,
        point_step=0, row_step=0, data=np.zeros(0, dtype=np.uint8), is_dense=True,
    )


def _storage_plugin(storage: str) -> Any:
    from rosbags.rosbag2 import StoragePlugin

    if storage not in _STORAGES:
        raise DatasetError(f"unknown bag storage {storage!r}; use one of {', '.join(_STORAGES)}")
    return StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3


def _crc_writer_class() -> Any:
    """rosbags' Writer whose MCAP chunks carry the CRC32 of their data (rosbags 0.11.9 writes 0: "no CRC").

    With the CRC, a reader (rosbags' included) notices a damaged chunk instead of decoding garbage.
    ``close_chunk`` follows rosbags 0.11.9's (pinned in requirements.txt) with the CRC filled in;
    ``test_bags`` checks that a flipped byte inside a chunk is caught.
    """
    from binascii import crc32
    from collections import defaultdict
    from io import BytesIO

    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.rosbag2.storage_mcap import (
        McapWriter,
        PendingChunk,
        write_record,
        write_string,
        write_uint16,
        write_uint32,
        write_uint64,
    )

    class CrcMcapWriter(McapWriter):
        def close_chunk(self) -> None:
            data = self.chunk.bio.getvalue()
            rec = BytesIO()
            write_uint64(rec, self.chunk.message_start_time)
            write_uint64(rec, self.chunk.message_end_time)
            write_uint64(rec, len(data))
            write_uint32(rec, crc32(data))
            compressed = self.compressor(data)
            write_string(rec, self.compression)
            write_uint64(rec, len(compressed))
            rec.write(compressed)
            chunk_start = self.bio.tell()
            write_record(self.bio, 0x06, rec)
            chunk_end = self.bio.tell()
            offsets: list[tuple[int, int]] = []
            for cid, msgs in self.chunk.msgs.items():
                offsets.append((cid, self.bio.tell()))
                rec = BytesIO()
                write_uint16(rec, cid)
                write_uint32(rec, len(msgs) * 16)
                for ts, offset in msgs:
                    write_uint64(rec, ts)
                    write_uint64(rec, offset)
                write_record(self.bio, 0x07, rec)
            rec = BytesIO()
            write_uint64(rec, self.chunk.message_start_time)
            write_uint64(rec, self.chunk.message_end_time)
            write_uint64(rec, chunk_start)
            write_uint64(rec, chunk_end - chunk_start)
            write_uint32(rec, len(offsets) * 10)
            for cid, offset in offsets:
                write_uint16(rec, cid)
                write_uint64(rec, offset)
            write_uint64(rec, self.bio.tell() - chunk_end)
            write_string(rec, self.compression)
            write_uint64(rec, len(compressed))
            write_uint64(rec, len(data))
            self.chunks.append(rec)
            self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

    class CrcWriter(Writer):
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: CrcMcapWriter}

    return CrcWriter


class BagWriter:
    """A rosbag2 writer for several topics of rosbags messages.

    Use as a context manager; topics are added on first write with the
    message's own type, so callers only say what to write::

        with BagWriter(path) as bag:
            bag.write("/mos/labels", stamp_ns, cloud_msg)
    """

    def __init__(self, bag_path: str | Path, storage: str = "mcap") -> None:
        self.path = Path(bag_path)
        if self.path.exists():
            raise DatasetError(f"bag output {self.path} already exists; remove it or choose another path")
        self._writer = _crc_writer_class()(self.path, version=BAG_VERSION, storage_plugin=_storage_plugin(storage))
        self._connections: dict[str, Any] = {}
        self.count = 0

    def __enter__(self) -> BagWriter:
        try:
            self._writer.open()
        except OSError as exc:
            raise output_error(self.path, exc) from None
        return self

    def __exit__(self, exc_type: object, *_: object) -> None:
        """Close the bag; after an error the close may fail too (a full disk): that second error is not raised
        over the first one (the caller removes the partial bag)."""
        try:
            self._writer.close()
        except Exception as exc:
            if exc_type is not None:
                return
            if isinstance(exc, OSError):
                raise output_error(self.path, exc) from None
            raise

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialise ``msg`` (a rosbags dataclass) and append it at ``stamp_ns`` on ``topic``."""
        ts = typestore()
        msgtype = msg.__msgtype__
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=ts)
            self._connections[topic] = conn
        elif conn.msgtype != msgtype:
            raise DatasetError(f"topic {topic} already holds {conn.msgtype}, not {msgtype}")
        try:
            self._writer.write(conn, int(stamp_ns), ts.serialize_cdr(msg, msgtype))
        except OSError as exc:  # a full disk: one line, not the storage plugin's traceback
            raise output_error(self.path, exc) from None
        self.count += 1


def write_scans_bag(
    bag_path: str | Path,
    scans: Iterable[tuple[int, np.ndarray, np.ndarray]],
    topic: str = "/points",
    frame_id: str = "velodyne",
    storage: str = "mcap",
) -> int:
    """Write scans as PointCloud2 (float32 x, y, z, intensity; 16 bytes per point) to a new bag.

    ``scans`` yields (stamp_ns, points (N, 3) float32, intensity (N,) float32);
    each message is stamped with ``stamp_ns`` in its header and in the bag.
    Returns the number of messages written.
    """
    with BagWriter(bag_path, storage=storage) as bag:
        for stamp_ns, points, intensity in scans:
            msg = fill_xyzi(empty_cloud(stamp_ns, frame_id), points, intensity, field_factory=point_field)
            bag.write(topic, stamp_ns, msg)
        return bag.count


def bag_topics(bag_path: str | Path) -> dict[str, str]:
    """topic -> message type of a bag."""
    from rosbags.rosbag2 import Reader

    with _open_reader(Reader, bag_path) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


@contextmanager
def _open_reader(reader_cls: Any, bag_path: str | Path) -> Iterator[Any]:
    """An opened rosbags reader; a missing, truncated or unreadable bag is a DatasetError."""
    path = Path(bag_path)
    if not path.exists():
        raise DatasetError(f"bag {path} does not exist")
    try:
        reader = reader_cls(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError and others for bad bags
        raise DatasetError(f"cannot open bag {path}: {exc}") from exc
    try:
        yield reader
    finally:
        reader.close()


def iter_messages(bag_path: str | Path, topics: Iterable[str]) -> Iterator[tuple[str, int, Any]]:
    """Yield (topic, bag timestamp ns, deserialised rosbags message) in bag time order."""
    from rosbags.rosbag2 import Reader

    wanted = set(topics)
    ts = typestore()
    with _open_reader(Reader, bag_path) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        messages = reader.messages(connections=connections)
        count = 0
        while True:
            try:
                conn, timestamp, raw = next(messages)
                msg = ts.deserialize_cdr(raw, conn.msgtype)
            except StopIteration:
                return
            except Exception as exc:  # truncated, zeroed or CRC-failing storage; undecodable messages
                raise DatasetError(f"bag {bag_path} is damaged after {count} messages: "
                                   f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from exc
            count += 1
            yield conn.topic, int(timestamp), msg


def pointcloud_topic(bag_path: str | Path, topic: str | None = None) -> str:
    """The PointCloud2 topic to read: ``topic`` if given (checked), else the bag's only one."""
    topics = bag_topics(bag_path)
    clouds = sorted(t for t, m in topics.items() if m == POINTCLOUD2)
    if topic is not None:
        if topics.get(topic) != POINTCLOUD2:
            raise DatasetError(
                f"bag {bag_path} has no PointCloud2 topic {topic!r} (PointCloud2 topics: {clouds or 'none'})"
            )
        return topic
    if len(clouds) != 1:
        raise DatasetError(
            f"bag {bag_path} has {len(clouds)} PointCloud2 topics {clouds}; choose one with --topic"
        )
    return clouds[0]


def iter_pointclouds(bag_path: str | Path, topic: str | None = None) -> Iterator[tuple[int, Any]]:
    """Yield (header stamp ns, rosbags PointCloud2) of one topic (the only one if ``topic`` is None)."""
    name = pointcloud_topic(bag_path, topic)
    for _, _, msg in iter_messages(bag_path, [name]):
        yield stamp_to_ns(msg.header.stamp), msg
