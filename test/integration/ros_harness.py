"""Helpers for the node tests: an in-process mos_node, a peer that feeds and listens, cloud builders."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, ShutdownException
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from scenes import street_sequence  # noqa: E402  (test/ is on sys.path: see test/conftest.py)

from ros2_mos.io.pointcloud2 import fill_xyzi
from ros2_mos.ros import messages as m

TYPES = m.MessageTypes.rclpy()
OUTPUTS = {"static_points": TYPES.point_cloud2, "moving_points": TYPES.point_cloud2, "labels": TYPES.point_cloud2,
           "range_image": TYPES.image, "mask": TYPES.image, "odometry": TYPES.odometry}
BASE_STAMP = 1_700_000_000_000_000_000


def isolate_ros(domain_id: int) -> None:
    """Per-run domain and localhost-only discovery, so parallel runs and other hosts never interfere."""
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


def cloud(stamp: int, points: np.ndarray, intensity: np.ndarray | None = None, frame: str = "velodyne") -> Any:
    return fill_xyzi(m.empty_cloud(TYPES, m.make_header(TYPES, stamp, frame)), points, intensity,
                     field_factory=TYPES.point_field)


class Harness:
    """mos_node and a peer node (publisher of /points, subscriber of every output) on one executor."""

    def __init__(self, context: Context, overrides: dict[str, Any]) -> None:
        from ros2_mos.ros.node import MosNode

        self.context = context
        self.node = MosNode(context=context,
                            parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        self.peer = rclpy.create_node("mos_test_peer", context=context)
        self.received: dict[str, list[Any]] = defaultdict(list)
        self._cond = threading.Condition()
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.subscriptions = {key: self.subscribe(key) for key in OUTPUTS}
        self.peer.create_subscription(TYPES.diagnostic_array, "/diagnostics", lambda msg: self._on("diag", msg), 10)
        self.pub = self.peer.create_publisher(TYPES.point_cloud2, "/points", qos)
        self.executor = MultiThreadedExecutor(num_threads=2, context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        # Spin in short steps that a test can pause: destroying a subscription while the executor
        # builds its wait set kills the spinning thread (rclpy InvalidHandle on the QoS event handler).
        self._spinning = threading.Lock()
        self._closing = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        self._wait(lambda: self.pub.get_subscription_count() > 0, 5.0)
        # The node builds clouds and images only for matched subscribers: wait until all are matched.
        self.wait_matched(OUTPUTS)

    def subscribe(self, key: str) -> Any:
        """The peer's subscription to the output ``key`` (its messages go to ``received[key]``)."""
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        return self.peer.create_subscription(OUTPUTS[key], f"/mos/{key}", lambda msg: self._on(key, msg), qos)

    def unsubscribe(self, key: str) -> None:
        """Destroy the peer's subscription to the output ``key`` between two steps of the executor."""
        with self._spinning:
            self.peer.destroy_subscription(self.subscriptions.pop(key))

    def _spin(self) -> None:
        while not self._closing.is_set():
            with self._spinning:
                try:
                    self.executor.spin_once(timeout_sec=0.05)
                except (ShutdownException, ExternalShutdownException):
                    return

    def wait_matched(self, keys: Any, matched: bool = True, timeout: float = 5.0) -> bool:
        """Wait until the node's publishers of ``keys`` have (or no longer have) a subscriber."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all((self.node._pubs[k].get_subscription_count() > 0) == matched for k in keys):
                return True
            time.sleep(0.01)
        return False

    def _on(self, key: str, msg: Any) -> None:
        with self._cond:
            self.received[key].append(msg)
            self._cond.notify_all()

    def _wait(self, predicate: Any, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(predicate, timeout=timeout)

    def handled(self) -> int:
        s = self.node.stats.snapshot()
        return s.processed + s.skipped_total + s.errors

    def feed(self, msg: Any, timeout: float = 20.0) -> dict[str, Any] | None:
        """Publish one cloud and wait until the node handled it; its outputs by topic, or None if skipped."""
        stamp = m.stamp_ns(msg.header.stamp)
        before = self.handled()
        processed_before = self.node.stats.snapshot().processed
        self.pub.publish(msg)
        deadline = time.monotonic() + timeout
        while self.handled() == before:
            assert time.monotonic() < deadline, "node did not handle the cloud in time"
            time.sleep(0.005)
        if self.node.stats.snapshot().processed == processed_before:
            return None

        def complete() -> bool:
            return all(any(m.stamp_ns(x.header.stamp) == stamp for x in self.received[k]) for k in OUTPUTS)

        assert self._wait(complete, 5.0), f"not every output arrived for stamp {stamp}"
        with self._cond:
            return {k: next(x for x in self.received[k] if m.stamp_ns(x.header.stamp) == stamp) for k in OUTPUTS}

    def close(self) -> None:
        self._closing.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()


@contextmanager
def running_harness(domain_id: int, overrides: dict[str, Any]) -> Iterator[Harness]:
    """A Harness in its own rclpy context on an isolated domain, torn down whatever happens."""
    isolate_ros(domain_id)
    context = rclpy.Context()
    rclpy.init(context=context)
    h = Harness(context, overrides)
    try:
        yield h
    finally:
        h.close()
        rclpy.try_shutdown(context=context)


def harness_fixture(domain_id: int, **overrides: Any) -> Any:
    """A module-scoped ``harness`` fixture: the in-process node with the tiny model, diagnostics every 0.2 s."""

    @pytest.fixture(scope="module")
    def harness(tiny_model_path: Path) -> Iterator[Harness]:
        with running_harness(domain_id, {"model": str(tiny_model_path), "diagnostics_period": 0.2, **overrides}) as h:
            yield h

    return harness


def sequence_fixture(scans: int) -> Any:
    """A module-scoped ``sequence`` fixture: a simulated street of ``scans`` scans (points, remission, ...)."""

    @pytest.fixture(scope="module")
    def sequence() -> list:
        return street_sequence(scans)

    return sequence


def child_env(domain_id: int, large_messages: bool = False) -> dict[str, str]:
    """The environment for a node process: the parent's (both bootstrap variables or neither, as it has them),
    an isolated domain, unbuffered output, and with ``large_messages`` the shipped large-message Fast DDS profile."""
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    if large_messages:
        from ros2_mos.ros.dds import use_large_message_profile

        use_large_message_profile(env)
    return env


def executable(name: str) -> str:
    """A console script of this environment (mos_node, ros2-mos)."""
    return str(Path(sys.executable).parent / name)


def run_node_until_ready(ros_args: list[str], env: dict[str, str], ready_timeout: float = 30.0) -> tuple[int, str]:
    """Start ``mos_node --ros-args ROS_ARGS``, stop it with SIGINT once it says it is ready (or at the timeout, or let
    it exit by itself); returns its exit code and everything it printed."""
    import signal
    import subprocess

    node = subprocess.Popen([executable("mos_node"), "--ros-args", *ros_args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(node.stdout), daemon=True)
    reader.start()
    deadline = time.monotonic() + ready_timeout
    while node.poll() is None and not any("ready in" in line for line in lines) and time.monotonic() < deadline:
        time.sleep(0.05)
    if node.poll() is None:
        node.send_signal(signal.SIGINT)
    code = node.wait(timeout=15)
    reader.join(5)
    return code, "".join(lines)
