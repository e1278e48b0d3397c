"""The input policy of ScanProcessor (the node's and `process`'s): another sensor on the topic, stamps that step
back a little or a lot, gaps, and the pipeline's pose-jump checks (issue 32, items 1, 4, 8)."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import street_sequence, yaw_pose

from ros2_mos.core.config import MosConfig, OdometryConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.io.pointcloud2 import fill_xyzi
from ros2_mos.ros import messages as m
from ros2_mos.ros.params import node_settings
from ros2_mos.ros.processor import ScanProcessor, SkippedScan

TYPES = m.MessageTypes.rosbags()
T0, PERIOD = 10**18, 10**8  # ns; 10 Hz
#: The second sensor: 1.5 m behind the first, turned 180 degrees.
REAR = yaw_pose(-1.5, 0.0, np.pi)


@pytest.fixture(scope="module")
def sequence():
    return street_sequence(12)


def make_processor(model, **params) -> ScanProcessor:
    return ScanProcessor(MosPipeline(MosConfig(model=str(model))), node_settings(params), TYPES)


def msg(stamp: int, points: np.ndarray, remission: np.ndarray, frame: str = "front"):
    return fill_xyzi(m.empty_cloud(TYPES, m.make_header(TYPES, stamp, frame)), points, remission,
                     field_factory=TYPES.point_field)


def rear(points: np.ndarray) -> np.ndarray:
    """The first sensor's points as the second sensor sees them."""
    inv = np.linalg.inv(REAR)
    return (points @ inv[:3, :3].T + inv[:3, 3]).astype(np.float32)


def moving_share(out) -> float:
    return out.n_moving / len(out.valid_index)


def test_another_frame_id_resets_with_a_note(tiny_model_path, sequence):
    """Issue 32.1: a second sensor's scans on the topic from scan 5 on were labelled against the first sensor's
    history (a quarter of every scan moving, no warning); now the first of them starts the stream over."""
    proc = make_processor(tiny_model_path)
    for i in range(5):
        proc.process(msg(T0 + i * PERIOD, *sequence[i][:2]))
    shares = []
    for i in range(5, 12):
        out = proc.process(msg(T0 + i * PERIOD, rear(sequence[i][0]), sequence[i][1], "rear"))
        if i == 5:
            assert out.reset and any("frame_id changed from 'front' to 'rear'" in n for n in out.notes), out.notes
            assert not out.result.residuals_complete and out.result.degraded
        else:
            assert not out.reset, out.notes
        shares.append(moving_share(out))
    assert max(shares) < 0.1, shares
    assert proc.frame_id == "rear" and proc.stream_problem == ""


def test_another_frame_id_is_skipped_when_asked(tiny_model_path, sequence):
    proc = make_processor(tiny_model_path, frame_change="skip")
    for i in range(4):
        proc.process(msg(T0 + i * PERIOD, *sequence[i][:2]))
    with pytest.raises(SkippedScan, match="frame_id 'rear', not the stream's 'front'") as info:
        proc.process(msg(T0 + 4 * PERIOD, rear(sequence[4][0]), sequence[4][1], "rear"))
    assert info.value.reason == "other_frame"
    out = proc.process(msg(T0 + 5 * PERIOD, *sequence[5][:2]))
    assert not out.reset and out.result.residuals_complete


@pytest.mark.parametrize("policy", ["reset", "skip"])
def test_interleaved_sensors_are_reported(tiny_model_path, sequence, policy):
    """Issue 32.1: two sensors 50 ms apart on one topic (25-36 % moving, nothing said); now reported, and with
    frame_change: skip the first sensor is labelled alone, with its full history."""
    proc = make_processor(tiny_model_path, frame_change=policy)
    outs = []
    for i in range(8):
        outs.append(proc.process(msg(T0 + i * PERIOD, *sequence[i][:2])))
        try:
            outs.append(proc.process(msg(T0 + i * PERIOD + PERIOD // 2, rear(sequence[i][0]), sequence[i][1],
                                         "rear")))
        except SkippedScan as exc:
            assert policy == "skip" and exc.reason == "other_frame"
        if i >= 1:
            assert "2 sensors interleaved on one topic" in proc.stream_problem, (i, proc.stream_problem)
            assert "'front', 'rear'" in proc.stream_problem
    assert max(moving_share(o) for o in outs) < 0.1
    if policy == "skip":
        assert len(outs) == 8 and outs[-1].result.residuals_complete and "only 'front'" in proc.stream_problem
    else:  # every switch resets; once the interleaving is reported, without a note (a log line) per scan
        assert all(o.reset for o in outs[1:]) and not any(o.notes for o in outs[4:]), [o.notes for o in outs]
    # The second sensor goes away: the report clears once the window has passed.
    for i in range(8, 12):
        proc.process(msg(T0 + i * PERIOD + 3 * 10**9, *sequence[i][:2]))
    assert proc.stream_problem == ""


def test_interleaved_sensors_make_the_diagnostics_an_error():
    from ros2_mos.ros.diagnostics import node_status
    from ros2_mos.ros.stats import NodeStats

    stats = NodeStats()
    stats.on_received(1.0)
    level, message, _ = node_status(stats.snapshot(), None, "clouds of 2 sensors interleaved on one topic")
    assert level == m.ERROR and "interleaved" in message
    assert node_status(stats.snapshot(), None)[0] == m.OK


def test_a_slightly_late_stamp_is_skipped_and_the_history_kept(tiny_model_path, sequence):
    """Issue 32.4: a stamp 1 ms back threw away the odometry map and the whole history."""
    proc = make_processor(tiny_model_path)
    for i in range(3):
        out = proc.process(msg(T0 + i * PERIOD, *sequence[i][:2]))
    kiss = proc.pipeline.odometry._kiss
    with pytest.raises(SkippedScan, match=r"1\.0 ms older than the last scan") as info:
        proc.process(msg(T0 + 2 * PERIOD - 10**6, *sequence[3][:2]))
    assert info.value.reason == "late_stamp"
    out = proc.process(msg(T0 + 3 * PERIOD, *sequence[3][:2]))
    assert not out.reset and out.result.residuals_complete and proc.pipeline.odometry._kiss is kiss
    # Further back than stamp_tolerance is time travel (a replay restarted): everything starts over.
    out = proc.process(msg(T0 - 10 * PERIOD, *sequence[0][:2]))
    assert out.reset and any("backwards" in n for n in out.notes)
    assert proc.pipeline.odometry._kiss is not kiss
    strict = make_processor(tiny_model_path, stamp_tolerance=0.0)
    for stamp in (T0, T0 + PERIOD, T0 + PERIOD - 10**6):
        out = strict.process(msg(stamp, *sequence[0][:2]))
    assert out.reset


def test_a_gap_clears_the_buffer_but_keeps_the_odometry(tiny_model_path, sequence):
    """Issue 32.4: a silent driver makes the past scans too old to use, not the odometry's map wrong."""
    proc = make_processor(tiny_model_path, reset_after_gap=0.5)
    for i in range(3):
        before = proc.process(msg(T0 + i * PERIOD, *sequence[i][:2]))
    kiss = proc.pipeline.odometry._kiss
    out = proc.process(msg(T0 + 2 * PERIOD + 2 * 10**9, *sequence[3][:2]))
    assert out.reset and "odometry kept" in out.notes[0] and not out.result.residuals_complete
    assert proc.pipeline.odometry._kiss is kiss
    # The pose continues the trajectory (one scan on: the ego drives 1 m per scan), not a restart at the origin.
    step = np.linalg.norm(out.result.pose[:3, 3] - before.result.pose[:3, 3])
    assert 0.8 < step < 1.2 and np.linalg.norm(out.result.pose[:3, 3]) > 2.5


def test_a_cloud_in_the_odom_frame_is_skipped_and_a_self_transform_refused(tiny_model_path, sequence):
    """Issue 32.8: odom_frame equal to sensor_frame started silently."""
    with pytest.raises(ConfigError, match="'sensor_frame' and 'odom_frame' are both 'odom'"):
        node_settings({"sensor_frame": "odom"})
    with pytest.raises(ConfigError, match="both 'base'"):
        node_settings({"sensor_frame": "base", "odom_frame": "base"})
    proc = make_processor(tiny_model_path)
    with pytest.raises(SkippedScan, match="frame_id 'odom', the odom_frame") as info:
        proc.process(msg(T0, *sequence[0][:2], frame="odom"))
    assert info.value.reason == "odom_frame_cloud"


def test_a_turn_no_vehicle_makes_resets_the_buffer(tiny_model_path, sequence):
    """Issue 32.1: beside max_translation_jump, a check on rotation (here with given poses)."""
    pipe = MosPipeline(MosConfig(model=str(tiny_model_path), odometry=OdometryConfig(max_rotation_jump=20.0)))
    for i in range(3):
        res = pipe.process(*sequence[i][:2], i * 0.1, pose=sequence[i][3])
        assert not res.reset
    turned = sequence[3][3] @ yaw_pose(0.0, 0.0, np.radians(25.0))
    res = pipe.process(*sequence[3][:2], 0.3, pose=turned)
    assert res.reset and any("turned 25 deg" in w for w in res.warnings), res.warnings
    # The same turn over 2 s (dropped scans) is no jump.
    res = pipe.process(*sequence[4][:2], 2.3, pose=turned @ yaw_pose(0.0, 0.0, np.radians(25.0)))
    assert not res.reset
    with pytest.raises(ConfigError, match="max_rotation_jump"):
        OdometryConfig(max_rotation_jump=0.0)


def test_the_diagnostics_say_why_the_labels_are_degraded(tiny_model_path, sequence):
    """Issue 32.1: after a frame_id change /diagnostics says so (WARN), not only "0 of 2 past scans"."""
    from ros2_mos.ros.diagnostics import node_status
    from ros2_mos.ros.stats import NodeStats

    proc = make_processor(tiny_model_path)
    proc.process(msg(T0, *sequence[0][:2]))
    out = proc.process(msg(T0 + PERIOD, rear(sequence[1][0]), sequence[1][1], "rear"))
    stats = NodeStats()
    stats.on_received(1.0)
    level, message, values = node_status(stats.snapshot(), out)
    assert level == m.WARN and "frame_id changed from 'front' to 'rear'" in message and values["frame_id"] == "rear"


def test_skip_reports_when_only_another_sensor_arrives(tiny_model_path, sequence):
    """With frame_change: skip, the first sensor gone and another one there: nothing is labelled, and it is said."""
    proc = make_processor(tiny_model_path, frame_change="skip")
    proc.process(msg(T0, *sequence[0][:2]))
    for i in range(1, 30):
        with pytest.raises(SkippedScan):
            proc.process(msg(T0 + i * PERIOD, rear(sequence[i % 12][0]), sequence[i % 12][1], "rear"))
    assert "none of the stream's 'front'" in proc.stream_problem and "nothing is labelled" in proc.stream_problem
