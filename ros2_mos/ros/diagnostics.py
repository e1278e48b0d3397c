"""What ``mos_node`` reports on ``/diagnostics``: one status from the counters and the last labelled scan.

Pure (no rclpy): the node calls :func:`node_status` on its timer and publishes the result.
"""

from __future__ import annotations

from typing import Any

from ros2_mos.ros import messages as m
from ros2_mos.ros.processor import ScanOutput
from ros2_mos.ros.stats import Snapshot

DIAGNOSTIC_NAME = "mos_node: moving object segmentation"
#: Consecutive unexpected failures after which diagnostics report ERROR.
ERROR_STREAK = 3
#: Seconds without input after which diagnostics report the input as stale.
STALE_AFTER_S = 2.0


def node_status(s: Snapshot, last: ScanOutput | None, stream_problem: str = "") -> tuple[int, str, dict[str, Any]]:
    """(level, message, key values): ERROR for a foreign sensor, sensors interleaved on the input topic
    (``stream_problem``: :attr:`~ros2_mos.ros.processor.ScanProcessor.stream_problem`) or a streak of failures,
    WARN for stale input, overload (scans dropped within the last few seconds) or degraded labels (with the reason: a
    reset, another frame_id, ...), OK otherwise; the values carry every counter, rate and stage timing."""
    level, message = m.OK, "ok"
    stale = s.seconds_since_last_scan is None or s.seconds_since_last_scan > STALE_AFTER_S
    if last is not None and last.result.sensor_mismatch:
        level, message = m.ERROR, last.result.sensor_mismatch
    elif stream_problem and not stale:
        level, message = m.ERROR, stream_problem
    elif s.consecutive_errors >= ERROR_STREAK:
        level, message = m.ERROR, f"{s.consecutive_errors} scans failed in a row: {s.last_warning}"
    elif stale:
        level, message = m.WARN, "no input" + ("" if s.seconds_since_last_scan is None else
                                               f" for {s.seconds_since_last_scan:.1f} s")
    elif s.dropped_recent > 0:
        level, message = m.WARN, (f"overloaded: {s.dropped_recent} of {s.received_recent} scans of the last "
                                  f"{s.recent_s:g} s dropped (input {s.input_hz:.1f} Hz, capacity "
                                  f"{s.capacity_hz:.1f} Hz): the newest scan is labelled, the oldest waiting one "
                                  "dropped")
    elif last is not None and last.result.degraded:
        level, message = m.WARN, "labels degraded: " + ("; ".join(last.notes or last.result.warnings) or
                                                        f"{last.result.n_past_available} of "
                                                        f"{last.result.n_past_required} past scans available")
    values: dict[str, Any] = {
        "rate_hz": s.rate_hz, "input_hz": s.input_hz, "capacity_hz": s.capacity_hz,
        "received": s.received, "processed": s.processed, "dropped": s.dropped,
        "dropped_recent": s.dropped_recent, "overloaded": s.dropped_recent > 0,
        "lost_in_transport": s.lost_in_transport,
        "skipped": s.skipped_total, **{f"skipped.{k}": v for k, v in s.skipped.items()},
        "errors": s.errors, "resets": s.resets, "degraded_scans": s.degraded,
        "latency_ms_mean": s.latency_ms[0], "latency_ms_max": s.latency_ms[1],
        **{f"{stage}_ms_mean": v[0] for stage, v in s.stage_ms.items()},
        **{f"{stage}_ms_median": v for stage, v in s.stage_median_ms.items()},
        **{f"{stage}_ms_max": v[1] for stage, v in s.stage_ms.items()},
        "last_warning": s.last_warning,
    }
    if last is not None:
        values.update(frame_id=last.frame_id, points=len(last.valid_index), moving_points=last.n_moving,
                      residuals_complete=last.result.residuals_complete, degraded=last.result.degraded)
    return level, message, values
