"""Issue 31.4: under overload the node stays current: it drops the oldest scans, its latency does not grow, and
/diagnostics says so. The node's own hand-off (LatestQueue), counters (NodeStats) and status (node_status), with a
worker that takes twice the input period per scan."""

from __future__ import annotations

import threading
import time

from ros2_mos.ros import messages as m
from ros2_mos.ros.diagnostics import node_status
from ros2_mos.ros.latest_queue import LatestQueue
from ros2_mos.ros.stats import NodeStats

PERIOD = 0.025  # input every 25 ms (40 Hz) ...
WORK = 0.05  # ... and 50 ms to label each scan: half the scans must go


def test_overload_drops_the_oldest_and_latency_stays_bounded():
    queue: LatestQueue[tuple[int, float]] = LatestQueue(1)
    stats = NodeStats(recent_s=5.0)
    done: list[tuple[int, float]] = []  # (index, latency s)

    def work() -> None:
        while not queue.closed:
            item = queue.get(timeout=0.2)
            if item is None:
                continue
            index, received = item
            time.sleep(WORK)
            done.append((index, time.monotonic() - received))
            stats.on_processed({"total": WORK * 1e3}, (time.monotonic() - received) * 1e3, False)

    worker = threading.Thread(target=work, daemon=True)
    worker.start()
    n = 80  # 2 s of input: an unbounded queue would be ~1 s behind at the end
    for i in range(n):
        stats.on_received(100.0 + i * PERIOD)
        if queue.put((i, time.monotonic())):
            stats.on_dropped()
        time.sleep(PERIOD)
    time.sleep(2 * WORK)
    queue.close()
    worker.join(2.0)

    snap = stats.snapshot()
    assert snap.dropped > n // 4, snap
    assert snap.received == n and snap.processed + snap.dropped in (n, n - 1)  # one may have waited at close
    indices = [i for i, _ in done]
    assert indices == sorted(indices)  # labelled in order, never an old scan after a newer one
    assert indices[-1] >= n - 3  # the newest scans were labelled: the dropped ones were the oldest
    latency = [lat for _, lat in done]
    # Bounded by one scan waiting plus one being labelled, however long the overload lasts (generous margins for a
    # loaded machine; a backlog would pass 1 s here).
    assert max(latency) < 4 * WORK + 0.2, latency
    third = len(latency) // 3
    assert sum(latency[-third:]) / third < sum(latency[:third]) / third + 0.1, latency

    level, message, values = node_status(snap, None)
    assert level == m.WARN and message.startswith("overloaded:"), message
    assert values["overloaded"] is True and values["dropped_recent"] == snap.dropped


def test_overload_report_clears_once_the_node_keeps_up():
    now = [0.0]
    stats = NodeStats(clock=lambda: now[0], recent_s=5.0)
    for i in range(20):
        now[0] = i * 0.1
        stats.on_received(1000.0 + i * 0.1)
        if i % 2:
            stats.on_dropped()
        else:
            stats.on_processed({"total": 150.0}, 160.0, False)
    level, message, values = node_status(stats.snapshot(), None)
    assert level == m.WARN and "10 of 20 scans of the last 5 s dropped" in message, message
    for i in range(20, 80):  # the input slows to what the node can do: 6 s without a drop
        now[0] = i * 0.1
        stats.on_received(1000.0 + i * 0.1)
        stats.on_processed({"total": 50.0}, 60.0, False)
    snap = stats.snapshot()
    level, message, values = node_status(snap, None)
    assert level == m.OK and message == "ok" and values["overloaded"] is False
    assert snap.dropped == 10 and snap.dropped_recent == 0
