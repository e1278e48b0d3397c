"""Running mos_node as a separate process and feeding it a bag: for the demo and the benchmark.

This is how users run it (a driver or ``ros2 bag play`` in one process, the node in
another, a consumer in a third), so the figures include DDS transport and the
node's own queueing, not only the pipeline.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


def isolate_ros_domain() -> str:
    """A random ROS_DOMAIN_ID, localhost only, for this process and the ones it starts.

    Also selects the shipped Fast DDS profile for large messages (unless the user set one),
    as we recommend for any deployment that moves full-size clouds between processes.
    """
    from ros2_mos.ros.dds import use_large_message_profile

    domain = str(random.randint(100, 200))
    os.environ["ROS_DOMAIN_ID"] = domain
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    use_large_message_profile()
    return domain


class NodeProcess:
    """``mos_node`` in a child process (same environment); stopped with SIGINT like Ctrl-C."""

    def __init__(self, params: dict[str, str] | None = None) -> None:
        cmd = [str(Path(sys.executable).parent / "mos_node"), "--ros-args"]
        for key, value in (params or {}).items():
            cmd += ["-p", f"{key}:={value}"]
        self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.log: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.log.append(line)

    @property
    def pid(self) -> int:
        return self.process.pid

    def stop(self, timeout: float = 10.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._reader.join(timeout=2.0)
        return self.process.returncode

    def final_statistics(self) -> str:
        lines = [line.strip() for line in self.log if "final statistics" in line]
        return lines[-1] if lines else ""

    def __enter__(self) -> "NodeProcess":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


@dataclass
class ReplayReport:
    sent: int
    elapsed_s: float
    labels: dict[int, np.ndarray]  # bag index -> per-point moving labels of /mos/labels
    latency_ms: list[float]  # stamp -> /mos/labels received, per scan (only with restamp)
    diagnostics: dict[str, str] = field(default_factory=dict)
    diagnostics_line: str = ""
    input_s: float = 0.0  # input time the replayed clouds span (their stamps, one period added)
    warmup: int = 0  # clouds sent before, in lock-step, not counted

    @property
    def processed_per_input_s(self) -> float:
        """Labelled scans per second of input time (10 at a 10 Hz sensor when nothing is lost)."""
        return len(self.labels) / self.input_s if self.input_s > 0 else 0.0


def replay_through_node(
    bag: Path, rate: float, restamp: bool = False, subscriber_timeout: float = 30.0, warmup: int = 0,
    reset_gap_s: float = 1.5,
) -> ReplayReport:
    """Replay ``bag`` to a running node (rate 0 = lock-step) and collect its /mos/labels.

    ``warmup`` > 0 first sends that many of the bag's clouds in lock-step (the node's first scans
    pay for lazy initialisation: memory, caches, the runtime's first runs), then pauses
    ``reset_gap_s`` so that the node starts the measured replay with a fresh buffer
    (its ``reset_after_gap``); those clouds are not counted.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from ros2_mos.io.bags import pointcloud_topic
    from ros2_mos.io.pointcloud2 import view_cloud
    from ros2_mos.ros.messages import MessageTypes, stamp_ns
    from ros2_mos.ros.replayer import Replayer

    received: dict[int, tuple[np.ndarray, float]] = {}
    rclpy.init()
    replayer = None
    listener = None
    executor = SingleThreadedExecutor()
    spin = threading.Thread(target=executor.spin, daemon=True)
    try:
        types = MessageTypes.rclpy()
        listener = rclpy.create_node("mos_harness_listener")
        clock = listener.get_clock()

        def on_labels(msg: Any) -> None:
            now = clock.now().nanoseconds
            received[stamp_ns(msg.header.stamp)] = (view_cloud(msg).records["moving"].astype(bool), now)

        listener.create_subscription(types.point_cloud2, "/mos/labels", on_labels,
                                     QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        executor.add_node(listener)
        spin.start()
        topic = pointcloud_topic(bag, None)
        replayer = Replayer(topic, reliable=True, sync_topic="/mos/labels" if rate == 0 or warmup else None)
        if not replayer.wait_for_subscriber(subscriber_timeout):
            raise RuntimeError(f"mos_node did not subscribe to {topic} within {subscriber_timeout:.0f} s")
        if warmup:
            replayer.play(bag, topic, rate=0, max_messages=warmup, restamp=True, sync=True)
            time.sleep(reset_gap_s)
            replayer.published_stamps.clear()
            received.clear()
        start = time.monotonic()
        sent = replayer.play(bag, topic, rate=rate, restamp=restamp, sync=rate == 0)
        deadline = time.monotonic() + 10.0
        while len(received) < sent and time.monotonic() < deadline:
            time.sleep(0.05)
        elapsed = time.monotonic() - start
        time.sleep(1.5)  # one more diagnostics period
        index = {stamp: i for i, stamp in enumerate(replayer.published_stamps)}
        labels = {index[s]: moving for s, (moving, _) in received.items() if s in index}
        latency = [(t - s) * 1e-6 for s, (_, t) in received.items() if s in index] if restamp else []
        stamps = replayer.published_stamps
        periods = sorted(b - a for a, b in zip(stamps, stamps[1:]))
        input_s = ((stamps[-1] - stamps[0]) + (periods[len(periods) // 2] if periods else 0)) * 1e-9 if stamps else 0.0
        return ReplayReport(sent, elapsed, labels, latency, dict(replayer.last_diagnostic_values),
                            replayer.last_diagnostics, input_s, warmup)
    finally:
        if replayer is not None:
            replayer.close()
        executor.shutdown()
        if listener is not None:
            listener.destroy_node()
        rclpy.try_shutdown()
        spin.join(timeout=2)
