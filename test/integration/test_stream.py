"""Another sensor on mos_node's input topic over real rclpy: a frame_id change resets with a warning, interleaved
sensors are an ERROR on /diagnostics (issue 32.1)."""

from __future__ import annotations

import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from ros_harness import BASE_STAMP, cloud, harness_fixture, sequence_fixture  # noqa: E402
from scenes import yaw_pose  # noqa: E402

from ros2_mos.ros import messages as m  # noqa: E402

DOMAIN = 80 + os.getpid() % 150
PERIOD = 100_000_000
REAR = np.linalg.inv(yaw_pose(-1.5, 0.0, np.pi))  # first sensor's frame -> second sensor's

sequence = sequence_fixture(6)
harness = harness_fixture(DOMAIN)


def _rear(points: np.ndarray) -> np.ndarray:
    return (points @ REAR[:3, :3].T + REAR[:3, 3]).astype(np.float32)


def _status(msg):
    s = msg.status[0]
    level = s.level if isinstance(s.level, int) else int.from_bytes(s.level, "little")
    return level, s.message, {kv.key: kv.value for kv in s.values}


def test_interleaved_sensors_are_an_error_on_diagnostics(harness, sequence):
    stamp = BASE_STAMP + 50 * 10**12
    resets = harness.node.stats.snapshot().resets
    assert harness.feed(cloud(stamp, *sequence[0][:2], frame="front")) is not None
    out = harness.feed(cloud(stamp + PERIOD // 2, _rear(sequence[0][0]), sequence[0][1], frame="rear"))
    assert out is not None and harness.node._last_output.reset
    assert any("frame_id changed from 'front' to 'rear'" in n for n in harness.node._last_output.notes)
    for i in range(1, 4):
        assert harness.feed(cloud(stamp + i * PERIOD, *sequence[i][:2], frame="front")) is not None
        assert harness.feed(cloud(stamp + i * PERIOD + PERIOD // 2, _rear(sequence[i][0]), sequence[i][1],
                                  frame="rear")) is not None
    assert harness.node.stats.snapshot().resets >= resets + 7
    start = len(harness.received["diag"])

    def interleaved() -> bool:
        return any("interleaved" in _status(msg)[1] for msg in harness.received["diag"][start:])

    assert harness._wait(interleaved, 5.0), [_status(msg)[1] for msg in harness.received["diag"][start:]]
    level, message, values = next(_status(msg) for msg in harness.received["diag"][start:]
                                  if "interleaved" in _status(msg)[1])
    assert level == m.ERROR and "'front', 'rear'" in message and values["frame_id"] == "rear"
