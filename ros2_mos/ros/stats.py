"""Running statistics of the node: counts, rate, per-stage timings, latency.

Updated by the worker thread, read by the diagnostics timer on the executor
thread, hence the lock. Timings are kept over a sliding window so the reported
means and maxima describe the recent past, not the whole run.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class Snapshot:
    """A consistent copy of the statistics at one moment."""

    received: int
    processed: int
    dropped: int
    skipped: dict[str, int]
    errors: int
    resets: int
    degraded: int
    rate_hz: float
    stage_ms: dict[str, tuple[float, float]]  # stage -> (mean, max) over the window
    latency_ms: tuple[float, float]  # (mean, max) receive -> published
    last_warning: str
    consecutive_errors: int
    seconds_since_last_scan: float | None
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def skipped_total(self) -> int:
        return sum(self.skipped.values())


class NodeStats:
    """Thread-safe counters and sliding windows (``window`` scans) of timings."""

    def __init__(self, window: int = 50, clock: Callable[[], float] = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._clock = clock
        self._window = window
        self.received = 0
        self.processed = 0
        self.dropped = 0
        self.errors = 0
        self.resets = 0
        self.degraded = 0
        self.consecutive_errors = 0
        self.skipped: Counter[str] = Counter()
        self.last_warning = ""
        self._stages: dict[str, deque[float]] = {}
        self._latency: deque[float] = deque(maxlen=window)
        self._done_times: deque[float] = deque(maxlen=window)
        self._last_received: float | None = None

    def on_received(self) -> None:
        with self._lock:
            self.received += 1
            self._last_received = self._clock()

    def on_dropped(self) -> None:
        with self._lock:
            self.dropped += 1

    def on_skipped(self, reason: str, message: str) -> None:
        with self._lock:
            self.skipped[reason] += 1
            self.last_warning = message
            self.consecutive_errors = 0

    def on_error(self, message: str) -> None:
        with self._lock:
            self.errors += 1
            self.consecutive_errors += 1
            self.last_warning = message

    def on_reset(self, message: str) -> None:
        with self._lock:
            self.resets += 1
            self.last_warning = message

    def on_processed(self, timings: dict[str, float], latency_ms: float, degraded: bool) -> None:
        with self._lock:
            self.processed += 1
            self.consecutive_errors = 0
            self.degraded += int(degraded)
            for stage, ms in timings.items():
                self._stages.setdefault(stage, deque(maxlen=self._window)).append(float(ms))
            self._latency.append(latency_ms)
            self._done_times.append(self._clock())

    def snapshot(self) -> Snapshot:
        with self._lock:
            now = self._clock()
            times = list(self._done_times)
            rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 and times[-1] > times[0] else 0.0
            if times and now - times[-1] > 5.0:
                rate = 0.0  # nothing processed lately: do not report a stale rate
            stages = {k: (sum(v) / len(v), max(v)) for k, v in self._stages.items() if v}
            lat = (sum(self._latency) / len(self._latency), max(self._latency)) if self._latency else (0.0, 0.0)
            return Snapshot(
                received=self.received, processed=self.processed, dropped=self.dropped,
                skipped=dict(self.skipped), errors=self.errors, resets=self.resets, degraded=self.degraded,
                rate_hz=rate, stage_ms=stages, latency_ms=lat, last_warning=self.last_warning,
                consecutive_errors=self.consecutive_errors,
                seconds_since_last_scan=None if self._last_received is None else now - self._last_received,
            )


def summary_line(s: Snapshot) -> str:
    """One log line: rate, counts and the mean ms of the main stages."""
    stages = ", ".join(f"{k} {v[0]:.1f}" for k, v in s.stage_ms.items())
    return (f"{s.rate_hz:.1f} Hz, {s.processed}/{s.received} scans processed, {s.dropped} dropped, "
            f"{s.skipped_total} skipped, {s.errors} errors, {s.resets} resets, {s.degraded} degraded; "
            f"latency {s.latency_ms[0]:.0f} ms (max {s.latency_ms[1]:.0f}); ms: {stages}")
