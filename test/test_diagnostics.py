"""The node's /diagnostics status (ros2_mos.ros.diagnostics.node_status), from hand-driven counters."""

from __future__ import annotations

from ros2_mos.ros import messages as m
from ros2_mos.ros.diagnostics import ERROR_STREAK, STALE_AFTER_S, node_status
from ros2_mos.ros.stats import NodeStats


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_no_input_then_ok_then_stale_then_a_streak_of_errors():
    clock = Clock()
    stats = NodeStats(clock=clock)
    level, message, values = node_status(stats.snapshot(), None)
    assert (level, message) == (m.WARN, "no input")
    stats.on_received(0.0)
    stats.on_processed({"inference": 20.0}, 50.0, degraded=False)
    level, message, values = node_status(stats.snapshot(), None)
    assert (level, message) == (m.OK, "ok")
    assert values["received"] == 1 and values["processed"] == 1 and values["inference_ms_mean"] == 20.0
    assert values["inference_ms_median"] == 20.0
    clock.now += STALE_AFTER_S + 0.5
    level, message, _ = node_status(stats.snapshot(), None)
    assert (level, message) == (m.WARN, f"no input for {STALE_AFTER_S + 0.5:.1f} s")
    for _ in range(ERROR_STREAK):
        stats.on_error("RuntimeError: boom")
    level, message, values = node_status(stats.snapshot(), None)
    assert level == m.ERROR and message == f"{ERROR_STREAK} scans failed in a row: RuntimeError: boom"
    assert values["errors"] == ERROR_STREAK
