"""Publishing a bag's PointCloud2 messages with rclpy: ``ros2-mos replay`` off a ROS install.

``ros2 bag play`` is not in the PyPI wheels; this reads the bag with rosbags and
publishes the same bytes as rclpy messages, at the recorded timing (scaled), as
fast as possible, or in lock-step with the node's output (``sync_topic``) so a
bag goes through the node exactly as fast as it can label it.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ros2_mos.io.bags import iter_messages
from ros2_mos.ros import messages as m


class Replayer:
    """A node publishing clouds on ``topic``; spins its own executor thread for the sync/diagnostics subscriptions."""

    def __init__(self, topic: str, *, reliable: bool = True, sync_topic: str | None = None, depth: int = 5) -> None:
        self.types = m.MessageTypes.rclpy()
        self.topic = topic
        self.node = Node("mos_replay")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, durability=DurabilityPolicy.VOLATILE,
                         reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)
        self.publisher = self.node.create_publisher(self.types.point_cloud2, topic, qos)
        self.synced = 0
        self.last_diagnostics = ""
        self.last_diagnostic_values: dict[str, str] = {}
        self.published_stamps: list[int] = []  # header stamps as published, in bag order
        self._cond = threading.Condition()
        if sync_topic:
            self.node.create_subscription(self.types.point_cloud2, sync_topic, self._on_sync,
                                          QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(self.types.diagnostic_array, "/diagnostics", self._on_diagnostics, 10)
        self._sync = bool(sync_topic)
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._executor.spin, name="replay_spin", daemon=True)
        self._thread.start()

    def _on_sync(self, _msg: Any) -> None:
        with self._cond:
            self.synced += 1
            self._cond.notify_all()

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            if status.name.startswith("mos_node"):
                values = {kv.key: kv.value for kv in status.values}
                self.last_diagnostic_values = values
                stages = ", ".join(f"{k[:-8]} {v}" for k, v in values.items() if k.endswith("_ms_mean"))
                self.last_diagnostics = (
                    f"{values.get('processed', '?')} of {values.get('received', '?')} received processed "
                    f"({values.get('rate_hz', '?')} per s of input time, node capacity {values.get('capacity_hz', '?')}"
                    f" Hz); lost: {values.get('dropped', '?')} in the node's queue, "
                    f"~{values.get('lost_in_transport', '?')} on the way in; {values.get('skipped', '?')} skipped;"
                    f" ms: {stages}")

    def wait_for_subscriber(self, timeout: float) -> bool:
        """True once at least one subscription (e.g. mos_node) has matched the publisher."""
        end = time.monotonic() + timeout
        while self.publisher.get_subscription_count() == 0:
            if time.monotonic() > end:
                return False
            time.sleep(0.05)
        return True

    def play(self, bag: str | Path, bag_topic: str, *, rate: float = 1.0, loop: bool = False,
             sync_timeout: float = 5.0, max_messages: int = 0, restamp: bool = False,
             sync: bool | None = None, start: int = 0) -> int:
        """Publish the clouds of ``bag_topic``; returns how many were published.

        ``start`` skips the bag's first clouds (on the first pass; a ``loop`` starts again from the first).

        ``restamp`` gives each cloud the wall-clock time of its publication, as a live driver
        would, so that subscribers can measure stamp-to-output latency.  ``sync`` overrides
        lock-step for this call (it needs the ``sync_topic`` given at construction).
        """
        lock_step = self._sync if sync is None else (sync and self._sync)
        if start < 0:
            raise ValueError(f"start must be >= 0, got {start}")
        sent = 0
        skip = start
        while True:
            start_wall: float | None = None
            start_bag = 0
            for _, bag_time, msg in iter_messages(bag, [bag_topic]):
                if skip:
                    skip -= 1
                    continue
                if start_wall is None:
                    start_wall, start_bag = time.monotonic(), bag_time
                elif rate > 0:
                    delay = start_wall + (bag_time - start_bag) * 1e-9 / rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                before = self.synced
                cloud = m.copy_cloud(self.types, msg)
                if restamp:
                    cloud.header.stamp = self.node.get_clock().now().to_msg()
                self.published_stamps.append(m.stamp_ns(cloud.header.stamp))
                self.publisher.publish(cloud)
                sent += 1
                if lock_step:
                    with self._cond:
                        self._cond.wait_for(lambda: self.synced > before, timeout=sync_timeout)
                if max_messages and sent >= max_messages:
                    return sent
            if not loop or sent == 0:
                return sent
            skip = 0

    def close(self) -> None:
        """Let reliable messages be acknowledged, then stop spinning and destroy the node."""
        try:
            self.publisher.wait_for_all_acked(Duration(seconds=2))
        except Exception:  # context already shut down (Ctrl-C): nothing left to flush
            pass
        self._executor.shutdown()
        self._thread.join(timeout=2.0)
        self.node.destroy_node()
