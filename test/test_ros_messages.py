"""Output message builders (both backends), the drop-oldest queue, statistics and the scan processor."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from scenes import street_sequence

from ros2_mos.core.config import MosConfig
from ros2_mos.core.errors import ScanError
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.io.pointcloud2 import decode_xyz_intensity, fill_xyzi, view_cloud
from ros2_mos.ros import messages as m
from ros2_mos.ros.latest_queue import LatestQueue
from ros2_mos.ros.params import node_settings
from ros2_mos.ros.processor import ScanProcessor, SkippedScan
from ros2_mos.ros.stats import NodeStats, summary_line

BACKENDS = ["rclpy", "rosbags"]


def _types(name: str) -> m.MessageTypes:
    if name == "rclpy":
        pytest.importorskip("sensor_msgs")
    return getattr(m.MessageTypes, name)()


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def _quat_to_matrix(x, y, z, w):
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize("angles", [(0, 0, 0), (np.pi, 0, 0), (0, np.pi, 0), (0, 0, np.pi), (0.3, -1.2, 2.9),
                                    (np.pi / 2, np.pi / 2, 0), (-3.0, 0.1, -0.2)])
def test_quaternion_round_trip(angles):
    r = _rotation(*angles)
    q = m.rotation_to_quaternion(r)
    assert abs(np.linalg.norm(q) - 1) < 1e-12 and q[3] >= 0
    np.testing.assert_allclose(_quat_to_matrix(*q), r, atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_images_odometry_tf_diagnostics(backend):
    types = _types(backend)
    header = m.make_header(types, 1_500_000_000_123_456_789, "lidar")
    assert m.stamp_ns(header.stamp) == 1_500_000_000_123_456_789
    rng = np.arange(12, dtype=np.float32).reshape(3, 4)
    img = m.image_msg(types, header, rng)
    assert (img.height, img.width, img.step, img.encoding) == (3, 4, 16, "32FC1")
    np.testing.assert_array_equal(np.frombuffer(bytes(img.data), "<f4").reshape(3, 4), rng)
    mask = m.image_msg(types, header, np.eye(3, 4, dtype=np.uint8) * 255)
    assert mask.encoding == "mono8" and mask.step == 4
    pose = np.eye(4)
    pose[:3, :3] = _rotation(0.5, 0, 0)
    pose[:3, 3] = [1, 2, 3]
    odom = m.odometry_msg(types, m.make_header(types, 5, "odom"), "lidar", pose)
    assert odom.child_frame_id == "lidar" and odom.pose.pose.position.z == 3.0
    assert abs(odom.pose.pose.orientation.z - np.sin(0.25)) < 1e-12
    tf = m.tf_msg(types, m.make_header(types, 5, "odom"), "lidar", pose)
    if types.tf_message is None:
        assert tf is None
    else:
        assert tf.transforms[0].transform.translation.y == 2.0
    diag = m.diagnostics_msg(types, header, "mos", "hw", m.WARN, "degraded", {"rate_hz": 9.87654, "n": 3})
    status = diag.status[0]
    assert [(kv.key, kv.value) for kv in status.values] == [("rate_hz", "9.877"), ("n", "3")]
    assert status.level in (m.WARN, bytes([m.WARN]))


def test_copy_cloud_between_backends():
    pytest.importorskip("sensor_msgs")
    rosbags, rclpy_types = m.MessageTypes.rosbags(), m.MessageTypes.rclpy()
    pts = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    src = fill_xyzi(m.empty_cloud(rosbags, m.make_header(rosbags, 7, "a")), pts, None,
                    field_factory=rosbags.point_field)
    dst = m.copy_cloud(rclpy_types, src)
    assert type(dst).__module__.startswith("sensor_msgs")
    np.testing.assert_array_equal(decode_xyz_intensity(dst)[0], pts)
    back = m.copy_cloud(rosbags, dst)
    assert isinstance(back.data, np.ndarray) and m.stamp_ns(back.header.stamp) == 7


def test_latest_queue_drops_the_oldest_and_closes():
    q: LatestQueue[int] = LatestQueue(1)
    assert q.put(1) is False
    assert q.put(2) is True and q.put(3) is True
    assert q.dropped == 2 and len(q) == 1 and q.get(0) == 3
    assert q.get(timeout=0.01) is None
    got = []
    t = threading.Thread(target=lambda: got.append(q.get(timeout=5)))
    t.start()
    q.close()
    t.join(2)
    assert got == [None] and q.closed and q.put(4) is False
    with pytest.raises(ValueError):
        LatestQueue(0)


def test_stats_snapshot_and_summary():
    now = [0.0]
    s = NodeStats(window=10, clock=lambda: now[0])
    for i in range(5):
        now[0] = 7.0 + i * 0.3  # the node's clock: slower than the input (a replay at a third of the speed)
        s.on_received(1000.0 + i * 0.1)  # the clouds' stamps: 10 Hz
        s.on_processed({"total": 50.0 + i, "decode": 1.0}, latency_ms=60.0, degraded=i == 0)
    s.on_dropped()
    s.on_skipped("too_few_points", "only 3 points")
    snap = s.snapshot()
    assert snap.processed == 5 and snap.dropped == 1 and snap.degraded == 1 and snap.skipped_total == 1
    # 5 processed over 0.5 s of input time (4 periods + one for the last scan): 10 per second of input time.
    assert abs(snap.rate_hz - 10.0) < 1e-6 and abs(snap.input_hz - 10.0) < 1e-6
    assert abs(snap.capacity_hz - 1000.0 / 52.0) < 1e-6  # mean total 52 ms
    assert snap.stage_ms["total"] == (52.0, 54.0)
    assert snap.stage_median_ms == {"total": 52.0, "decode": 1.0}
    line = summary_line(snap)
    assert "5/5 scans processed (10.0 per s of input time, input 10.0 Hz, node capacity 19.2 Hz)" in line
    assert "lost: 1 in the node's queue, ~0 on the way in" in line
    now[0] = 100.0
    assert s.snapshot().rate_hz == snap.rate_hz  # after the input stops the rate stays what it was


def test_stats_count_clouds_lost_on_the_way_and_restart_input_time():
    s = NodeStats(window=10)
    for i in [0, 1, 2, 3, 6, 7, 8, 12]:  # 4, 5 and 9, 10, 11 never arrived
        s.on_received(50.0 + i * 0.1)
    snap = s.snapshot()
    assert snap.lost_in_transport == 5 and snap.received == 8
    assert abs(snap.input_hz - 8 / 1.3) < 1e-6  # 1.2 s from first to last stamp + one period
    every_other = NodeStats(window=10, max_gap_s=5.0)
    for i in range(0, 20, 2):  # half the clouds lost, regularly: still counted
        every_other.on_received(10.0 + i * 0.1)
    every_other.on_received(12.0)
    every_other.on_received(12.1)
    assert every_other.snapshot().lost_in_transport == 9
    paused = NodeStats(window=10, max_gap_s=1.0)
    for t in (0.0, 0.1, 0.2, 0.3, 2.3, 2.4):  # a 2 s pause (the node resets after 1 s): not lost clouds
        paused.on_received(t)
    assert paused.snapshot().lost_in_transport == 0
    # Clouds sent in lock-step (every 55 ms) before a pause, then the sensor's 10 Hz: the period is estimated
    # afresh after the pause, so no 100 ms step is taken for a lost cloud (bench's warm-up once counted 45 of 45).
    restarted = NodeStats(window=50, max_gap_s=1.0)
    stamps = [i * 0.055 for i in range(5)] + [2.0 + i * 0.1 for i in range(45)]
    for t in stamps:
        restarted.on_received(t)
    assert restarted.snapshot().lost_in_transport == 0
    restarted.on_received(2.0 + 46 * 0.1)  # one cloud (45) lost after the pause: counted
    assert restarted.snapshot().lost_in_transport == 1
    never_resets = NodeStats(window=10, max_gap_s=0.0)  # reset_after_gap 0: a long step is lost clouds
    for t in (0.0, 0.1, 0.2, 0.3, 2.3, 2.4):
        never_resets.on_received(t)
    assert never_resets.snapshot().lost_in_transport == 19
    s.on_received(10.0)  # time went back: a replay restarted; its input time adds up
    s.on_received(10.1)
    assert abs(s.snapshot().input_hz - 10 / 1.5) < 1e-6
    assert s.snapshot().lost_in_transport == 5


def test_processor_outputs_and_skips(tiny_model_path):
    types = m.MessageTypes.rosbags()
    proc = ScanProcessor(MosPipeline(MosConfig(model=str(tiny_model_path))),
                         node_settings({"reset_after_gap": 0.5}), types)
    seq = street_sequence(4)
    for i, (pts, rem, _, _) in enumerate(seq[:3]):
        msg = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + i * 10**8, "v")), pts, rem,
                        field_factory=types.point_field)
        out = proc.process(msg)
    assert set(out.messages) == {"static_points", "moving_points", "labels", "range_image", "mask", "odometry", "tf"}
    assert out.messages["static_points"].width + out.messages["moving_points"].width == len(seq[2][0])
    assert view_cloud(out.messages["labels"]).records["moving"].sum() == out.n_moving > 0
    assert {"decode", "odometry", "inference", "encode", "total"} <= set(out.timings)
    with pytest.raises(SkippedScan, match="repeats"):
        proc.process(msg)
    # A gap longer than reset_after_gap resets the buffer.
    late = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + 10 * 10**8, "v")), *seq[3][:2],
                     field_factory=types.point_field)
    out = proc.process(late)
    assert out.reset and not out.result.residuals_complete and "reset_after_gap" in out.notes[0]
    tiny = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + 11 * 10**8, "v")),
                     np.ones((3, 3), np.float32), None, field_factory=types.point_field)
    with pytest.raises(SkippedScan, match="min_points") as info:
        proc.process(tiny)
    assert info.value.reason == "too_few_points"
    # Far more points than the sensor has pixels (TEST_SENSOR: 32 x 512 = 16k; 4 per pixel allowed): refused
    # before decoding, so one huge cloud cannot grow the node's memory.
    huge = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + 11 * 10**8 + 1, "v")),
                     np.ones((4 * 32 * 512 + 1, 3), np.float32), None, field_factory=types.point_field)
    with pytest.raises(SkippedScan, match="65537 points, more than 4 per pixel") as info:
        proc.process(huge)
    assert info.value.reason == "too_many_points"
    # Points scattered through a volume are no LiDAR scan: skipped, with the reason, before the odometry.
    scattered = np.random.default_rng(0).uniform(-30, 30, (60_000, 3)).astype(np.float32)
    cube = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + 11 * 10**8 + 2, "v")), scattered, None,
                     field_factory=types.point_field)
    with pytest.raises(SkippedScan, match=r"^cloud at 1000000001\.100 s is not a plausible LiDAR scan: only ") as info:
        proc.process(cube)
    assert info.value.reason == "implausible_scan" and str(info.value).endswith(": skipped")
    broken = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18 + 12 * 10**8, "v")), *seq[0][:2],
                       field_factory=types.point_field)
    broken.row_step = 3
    with pytest.raises(ScanError, match="row_step"):
        proc.process(broken)


def test_processor_withholds_incomplete_labels_when_asked(tiny_model_path):
    types = m.MessageTypes.rosbags()
    proc = ScanProcessor(MosPipeline(MosConfig(model=str(tiny_model_path))),
                         node_settings({"publish_incomplete": False}), types)
    pts, rem = street_sequence(1)[0][:2]
    msg = fill_xyzi(m.empty_cloud(types, m.make_header(types, 10**18, "v")), pts, rem,
                    field_factory=types.point_field)
    out = proc.process(msg)
    assert out.labels_withheld
    assert not {"static_points", "moving_points", "labels", "mask"} & set(out.messages)
    assert {"odometry", "range_image"} <= set(out.messages)


def test_outputs_are_one_table_that_the_parameters_and_builders_follow():
    """Issue 17.3: an output is one entry of ros.outputs.OUTPUTS; its parameter and message come from it."""
    from types import SimpleNamespace

    from ros2_mos.ros.outputs import OUTPUTS, ScanContext, build_messages
    from ros2_mos.ros.params import SPECS

    types = m.MessageTypes.rosbags()
    pts = np.array([[5.0, 0.0, 0.0], [0.0, 6.0, 0.5], [-7.0, 0.0, 1.0]], np.float32)
    view = view_cloud(fill_xyzi(m.empty_cloud(types, m.make_header(types, 7, "a")), pts, None,
                                field_factory=types.point_field))
    result = SimpleNamespace(probability=np.array([0.1, 0.9, 0.2], np.float32), valid=np.ones(3, bool),
                             range_image=np.zeros((2, 4), np.float32), mask_image=np.zeros((2, 4), np.uint8),
                             pose=np.eye(4))
    context = ScanContext(types, m.make_header(types, 7, "a"), m.make_header(types, 7, "odom"), "a", view,
                          np.arange(3), np.array([False, True, False]), result)
    messages = build_messages(context, None, withhold_labels=False, publish_tf=False)
    assert list(messages) == [o.key for o in OUTPUTS]
    for o in OUTPUTS:
        assert SPECS[f"topics.{o.key}"].default == f"/mos/{o.key}"
        assert isinstance(messages[o.key], getattr(types, o.message_type))
    assert messages["static_points"].width == 2 and messages["moving_points"].width == 1
    withheld = build_messages(context, None, withhold_labels=True, publish_tf=False)
    assert set(withheld) == {o.key for o in OUTPUTS if not o.labels} == {"range_image", "odometry"}
    assert set(build_messages(context, frozenset({"odometry"}), False, False)) == {"odometry"}
