"""Running statistics of the node: counts, rates, losses, per-stage timings, latency.

Updated by the worker thread, read by the diagnostics timer on the executor
thread, hence the lock. Timings are kept over a sliding window so the reported
means and maxima describe the recent past, not the whole run.

Rates mean what they say:

* ``rate_hz``: scans processed per second of *input* time (the clouds' header stamps,
  first to last received), over the whole run, so it stays true after the input stops
  and does not depend on how long the node waited before or after;
* ``input_hz``: clouds received per second of input time;
* ``capacity_hz``: what the node could sustain, 1000 / mean ms per processed scan.

Losses say where they happened: ``dropped`` clouds were replaced in the node's one-scan
queue while it was busy; ``lost_in_transport`` is estimated from gaps in the received
stamps (a gap of k nominal periods is k - 1 clouds that never arrived; the nominal period is a low quantile of
the recent steps, so regular losses do not hide themselves).
"""

from __future__ import annotations

import math
import statistics
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
    rate_hz: float  # processed per second of input time
    input_hz: float  # received per second of input time
    capacity_hz: float  # 1000 / mean total ms per processed scan (window)
    lost_in_transport: int  # clouds missing from the received stamps' sequence
    stage_ms: dict[str, tuple[float, float]]  # stage -> (mean, max) over the window
    latency_ms: tuple[float, float]  # (mean, max) receive -> published
    last_warning: str
    consecutive_errors: int
    seconds_since_last_scan: float | None
    extra: dict[str, str] = field(default_factory=dict)
    #: stage -> median ms over the window (comparable with ``ros2-mos bench``'s medians).
    stage_median_ms: dict[str, float] = field(default_factory=dict)
    #: Clouds dropped from the node's queue / received within the last ``recent_s`` seconds (wall clock): the node
    #: is overloaded *now* when some were dropped (it then labels the newest scan and lets the older ones go).
    dropped_recent: int = 0
    received_recent: int = 0
    recent_s: float = 0.0

    @property
    def skipped_total(self) -> int:
        return sum(self.skipped.values())


class NodeStats:
    """Thread-safe counters and sliding windows (``window`` scans) of timings."""

    def __init__(self, window: int = 50, clock: Callable[[], float] = time.monotonic, max_gap_s: float = 1.0,
                 recent_s: float = 5.0) -> None:
        self._lock = threading.Lock()
        self._recent_s = recent_s
        self._recent_drops: deque[float] = deque()  # wall-clock times of the drops within recent_s
        self._recent_received: deque[float] = deque()
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
        self._last_received: float | None = None
        self._first_stamp: float | None = None
        self._last_stamp: float | None = None
        self._periods: deque[float] = deque(maxlen=window)
        self._closed_span = 0.0  # input time of stretches before time last went back
        self._lost_settled = 0
        self._max_gap = max_gap_s  # a longer gap is a pause of the input (the node resets), not lost clouds; after
        # it the sensor's period is estimated afresh (a replay's first clouds sent in lock-step must not set it)

    def on_received(self, stamp: float | None = None) -> None:
        """A cloud arrived; ``stamp`` (its header stamp, s) drives the input-time rates and the loss estimate."""
        with self._lock:
            self.received += 1
            self._last_received = self._clock()
            self._recent_received.append(self._last_received)
            self._forget_old(self._last_received)
            if stamp is None or not math.isfinite(stamp):
                return
            if self._last_stamp is None or self._first_stamp is None:
                self._first_stamp = self._last_stamp = stamp
            elif stamp > self._last_stamp:
                step = stamp - self._last_stamp
                if self._is_pause(step):  # the input starts anew, perhaps at another rate: settle what came before
                    period = self._nominal_period()
                    self._lost_settled += sum(self._lost_in(s, period) for s in self._periods)
                    self._periods.clear()
                else:
                    if len(self._periods) == self._periods.maxlen:  # the oldest step leaves the window: settle it
                        self._lost_settled += self._lost_in(self._periods[0], self._nominal_period())
                    self._periods.append(step)
                self._last_stamp = stamp
            elif stamp < self._first_stamp:  # time went back (a replay restarted): a new stretch of input time
                self._closed_span += self._input_span()
                self._first_stamp = self._last_stamp = stamp

    def _is_pause(self, step: float) -> bool:
        return 0 < self._max_gap < step  # max_gap 0: the node never resets, so no step is a pause

    def _lost_in(self, step: float, period: float | None) -> int:
        if not period or step <= 1.5 * period or self._is_pause(step):
            return 0
        return max(0, round(step / period) - 1)

    @property
    def lost_in_transport(self) -> int:
        """Clouds missing between the received stamps (settled ones plus those in the current window)."""
        period = self._nominal_period()
        return self._lost_settled + sum(self._lost_in(step, period) for step in self._periods)

    def _nominal_period(self) -> float | None:
        """The sensor's period: a low quantile of the recent stamp steps (losses only ever lengthen a step,
        even when every other cloud is lost)."""
        if len(self._periods) < 3:
            return None
        return sorted(self._periods)[len(self._periods) // 20]

    def on_dropped(self) -> None:
        with self._lock:
            self.dropped += 1
            now = self._clock()
            self._recent_drops.append(now)
            self._forget_old(now)

    def _forget_old(self, now: float) -> None:
        for times in (self._recent_drops, self._recent_received):
            while times and times[0] < now - self._recent_s:
                times.popleft()

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

    def snapshot(self) -> Snapshot:
        with self._lock:
            now = self._clock()
            self._forget_old(now)
            span = self._closed_span + self._input_span()
            total = self._stages.get("total")
            capacity = 1000.0 * len(total) / sum(total) if total and sum(total) > 0 else 0.0
            stages = {k: (sum(v) / len(v), max(v)) for k, v in self._stages.items() if v}
            medians = {k: float(statistics.median(v)) for k, v in self._stages.items() if v}
            lat = (sum(self._latency) / len(self._latency), max(self._latency)) if self._latency else (0.0, 0.0)
            return Snapshot(
                received=self.received, processed=self.processed, dropped=self.dropped,
                skipped=dict(self.skipped), errors=self.errors, resets=self.resets, degraded=self.degraded,
                rate_hz=self.processed / span if span else 0.0, input_hz=self.received / span if span else 0.0,
                capacity_hz=capacity, lost_in_transport=self.lost_in_transport, stage_ms=stages, latency_ms=lat,
                stage_median_ms=medians,
                last_warning=self.last_warning,
                consecutive_errors=self.consecutive_errors,
                seconds_since_last_scan=None if self._last_received is None else now - self._last_received,
                dropped_recent=len(self._recent_drops), received_recent=len(self._recent_received),
                recent_s=self._recent_s,
            )

    def _input_span(self) -> float:
        """Seconds of input time covered by the received clouds (one nominal period per cloud at the ends)."""
        if self._first_stamp is None or self._last_stamp is None:
            return 0.0
        period = self._nominal_period() or 0.1
        return self._last_stamp - self._first_stamp + period


def summary_line(s: Snapshot) -> str:
    """One log line: rates, counts, where scans were lost, and the mean ms of the main stages."""
    stages = ", ".join(f"{k} {v[0]:.1f}" for k, v in s.stage_ms.items())
    return (f"{s.processed}/{s.received} scans processed ({s.rate_hz:.1f} per s of input time, input "
            f"{s.input_hz:.1f} Hz, node capacity {s.capacity_hz:.1f} Hz); lost: {s.dropped} in the node's queue, "
            f"~{s.lost_in_transport} on the way in; {s.skipped_total} skipped, {s.errors} errors, {s.resets} resets, "
            f"{s.degraded} degraded; latency {s.latency_ms[0]:.0f} ms (max {s.latency_ms[1]:.0f}); ms: {stages}")
