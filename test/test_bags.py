"""rosbag2 round trips through rosbags: what the simulator writes, replay and process read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.bags import (
    BagWriter,
    bag_topics,
    empty_cloud,
    iter_messages,
    iter_pointclouds,
    msg_class,
    point_field,
    write_scans_bag,
)
from ros2_mos.io.pointcloud2 import decode_xyz_intensity, fill_subset


def _scans(count: int = 3, n: int = 500, seed: int = 0) -> list[tuple[int, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [
        (1_700_000_000_000_000_000 + i * 100_000_000 + 7,
         rng.normal(scale=20.0, size=(n + i, 3)).astype(np.float32),
         rng.random(n + i).astype(np.float32))
        for i in range(count)
    ]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_write_scans_round_trip(tmp_path: Path, storage: str) -> None:
    scans = _scans()
    bag = tmp_path / "bag"
    assert write_scans_bag(bag, iter(scans), storage=storage) == len(scans)
    assert bag_topics(bag) == {"/points": "sensor_msgs/msg/PointCloud2"}
    read = list(iter_pointclouds(bag))
    assert len(read) == len(scans)
    for (stamp, points, intensity), (stamp_read, msg) in zip(scans, read):
        assert stamp_read == stamp
        assert msg.header.frame_id == "velodyne"
        got_points, got_intensity, valid = decode_xyz_intensity(msg)
        np.testing.assert_array_equal(got_points, points)
        np.testing.assert_array_equal(got_intensity, intensity)
        np.testing.assert_array_equal(valid, np.arange(len(points)))


def test_custom_topic_and_frame(tmp_path: Path) -> None:
    write_scans_bag(tmp_path / "b", iter(_scans(1)), topic="/lidar", frame_id="os_sensor")
    ((_, msg),) = list(iter_pointclouds(tmp_path / "b", topic="/lidar"))
    assert msg.header.frame_id == "os_sensor"
    with pytest.raises(DatasetError, match="no PointCloud2 topic"):
        list(iter_pointclouds(tmp_path / "b", topic="/points"))


def test_existing_output_and_missing_input_are_errors(tmp_path: Path) -> None:
    write_scans_bag(tmp_path / "b", iter(_scans(1)))
    with pytest.raises(DatasetError, match="already exists"):
        write_scans_bag(tmp_path / "b", iter(_scans(1)))
    with pytest.raises(DatasetError, match="does not exist"):
        list(iter_pointclouds(tmp_path / "nope"))
    with pytest.raises(DatasetError, match="storage"):
        write_scans_bag(tmp_path / "c", iter(_scans(1)), storage="rosbag1")


def test_generic_writer_several_topics(tmp_path: Path) -> None:
    """The offline `process` output: clouds and odometry on several topics in one bag."""
    (stamp, points, intensity), = _scans(1)
    bag = tmp_path / "out"
    src = empty_cloud(stamp, "velodyne")
    from ros2_mos.io.pointcloud2 import fill_xyzi

    fill_xyzi(src, points, intensity, field_factory=point_field)
    moving = fill_subset(empty_cloud(stamp, "velodyne"), src, np.arange(0, len(points), 2),
                         field_factory=point_field)
    odom_cls = msg_class("nav_msgs/msg/Odometry")
    from ros2_mos.io.bags import header

    ts_types = {n: msg_class(n) for n in ("geometry_msgs/msg/PoseWithCovariance",
                                          "geometry_msgs/msg/TwistWithCovariance",
                                          "geometry_msgs/msg/Pose", "geometry_msgs/msg/Twist",
                                          "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion",
                                          "geometry_msgs/msg/Vector3")}
    pose = ts_types["geometry_msgs/msg/Pose"](
        position=ts_types["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0),
        orientation=ts_types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    zero = ts_types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    odom = odom_cls(
        header=header(stamp, "odom"), child_frame_id="velodyne",
        pose=ts_types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=ts_types["geometry_msgs/msg/TwistWithCovariance"](
            twist=ts_types["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)),
    )
    with BagWriter(bag) as writer:
        writer.write("/mos/moving_points", stamp, moving)
        writer.write("/mos/odometry", stamp, odom)
        with pytest.raises(DatasetError, match="already holds"):
            writer.write("/mos/odometry", stamp, moving)
    assert bag_topics(bag) == {"/mos/moving_points": "sensor_msgs/msg/PointCloud2",
                               "/mos/odometry": "nav_msgs/msg/Odometry"}
    got = {topic: msg for topic, _, msg in iter_messages(bag, ["/mos/moving_points", "/mos/odometry"])}
    np.testing.assert_array_equal(decode_xyz_intensity(got["/mos/moving_points"])[0], points[::2])
    assert got["/mos/odometry"].pose.pose.position.y == 2.0
    assert got["/mos/odometry"].child_frame_id == "velodyne"


def test_mcap_chunks_carry_crcs_so_damage_inside_them_is_an_error(tmp_path: Path) -> None:
    import struct
    from binascii import crc32

    bag = tmp_path / "bag"
    write_scans_bag(bag, iter(_scans(count=4, n=20_000)))
    (mcap,) = bag.glob("*.mcap")
    raw = bytearray(mcap.read_bytes())
    # Walk the records after the 8-byte magic (opcode, uint64 length, content) to the first chunk (0x06):
    # start, end, uncompressed size, uncompressed CRC32, compression, compressed size, data.
    at, crcs = 8, []
    while at < len(raw) - 8 and raw[at] != 0x0F:  # 0x0F: data end
        opcode, length = raw[at], struct.unpack_from("<Q", raw, at + 1)[0]
        if opcode == 0x06:
            size, crc = struct.unpack_from("<QI", raw, at + 9 + 16)
            name_len = struct.unpack_from("<I", raw, at + 9 + 28)[0]
            data_at = at + 9 + 32 + name_len + 8
            crcs.append(crc)
            assert crc == crc32(raw[data_at:data_at + size])  # uncompressed chunks: the data as stored
        at += 9 + length
    assert crcs and all(crcs)
    assert len(list(iter_pointclouds(bag))) == 4  # the intact bag reads
    # Random bytes in the middle of the file (inside a chunk of point data): an error, not garbage.
    middle = len(raw) // 2
    raw[middle:middle + 5000] = np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    mcap.write_bytes(bytes(raw))
    with pytest.raises(DatasetError):
        list(iter_pointclouds(bag))


def test_replayer_start_skips_the_first_clouds_of_the_first_pass_only(tmp_path):
    """Replayer.play(start=k): the bag's first k clouds are skipped once; a loop then begins at the first cloud."""
    import rclpy

    from ros2_mos.ros.replayer import Replayer
    from ros2_mos.tools.harness import isolate_ros_domain

    scans = _scans(4, n=50)
    write_scans_bag(tmp_path / "b", iter(scans))
    isolate_ros_domain()
    rclpy.init()
    try:
        replayer = Replayer("/points", reliable=False)
        try:
            assert replayer.play(tmp_path / "b", "/points", rate=0, start=2) == 2
            assert replayer.play(tmp_path / "b", "/points", rate=0, start=3, loop=True, max_messages=3) == 3
            with pytest.raises(ValueError, match="start"):
                replayer.play(tmp_path / "b", "/points", rate=0, start=-1)
        finally:
            replayer.close()
    finally:
        rclpy.try_shutdown()
    stamps = [s for s, _, _ in scans]
    assert replayer.published_stamps == [stamps[2], stamps[3], stamps[3], stamps[0], stamps[1]]
