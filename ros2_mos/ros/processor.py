"""One PointCloud2 in, the node's output messages out: shared by ``mos_node`` and ``process``.

Everything between decoding the input and having the messages to publish lives
here, so the live node and the offline bag processing cannot disagree. It also
owns the input policy: which clouds are skipped (bad layout, too few finite
points, a duplicate or slightly late stamp, no plausible LiDAR scan, another sensor's frame_id with
``frame_change: skip``) and when the scan buffer is reset (a gap in the stream: the odometry is kept; another
sensor's frame_id with ``frame_change: reset``: everything is reset; time going back further than
``stamp_tolerance`` and pose jumps are handled by the pipeline). Two sensors interleaved on one topic are
detected from their frame_ids (:attr:`ScanProcessor.stream_problem`).
Skips raise :class:`~ros2_mos.core.errors.ScanError` with the reason; the caller
logs it and carries on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ros2_mos.core.errors import ImplausibleScanError, ScanError
from ros2_mos.core.pipeline import MosPipeline, MosResult
from ros2_mos.io.pointcloud2 import decode_xyz_intensity, view_cloud
from ros2_mos.ros import messages as m
from ros2_mos.ros.outputs import ScanContext, build_messages
from ros2_mos.ros.params import NodeSettings


class SkippedScan(ScanError):
    """A cloud was well-formed but not usable (too few points, duplicate stamp, no plausible scan); ``reason`` is a
    short key."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass
class ScanOutput:
    """The messages one scan produced, keyed like :data:`ros2_mos.ros.outputs.OUTPUT_KEYS` plus ``tf``."""

    stamp_ns: int
    frame_id: str
    result: MosResult
    valid_index: np.ndarray  # indices (into the input cloud) of the points that got a label
    points: np.ndarray  # (N, 3) float32 decoded finite points, sensor frame; result.* index into these
    messages: dict[str, Any]
    timings: dict[str, float]
    notes: list[str] = field(default_factory=list)  # warnings to log (resets, degraded, ...)
    reset: bool = False
    labels_withheld: bool = False

    @property
    def n_moving(self) -> int:
        return int(self.result.labels[self.result.valid].sum())

    @property
    def static_points(self) -> np.ndarray:
        """(M, 3) sensor-frame points labelled static (for the cleaned map)."""
        return self.points[self.result.valid & (self.result.labels == 0)]


#: Clouds with more points than this many per range-image pixel are refused (a 64 x 2048 sensor: 524k).
MAX_POINTS_PER_PIXEL = 4
#: Two frame_id changes within this much input time (s) are two sensors interleaved on one topic, not one sensor
#: replaced by another; the report stays until this long passes without a change.
INTERLEAVE_WINDOW_S = 2.0


class ScanProcessor:
    """Decode, label, and build the output messages of a stream of PointCloud2 from one sensor."""

    def __init__(self, pipeline: MosPipeline, settings: NodeSettings, types: m.MessageTypes) -> None:
        self.pipeline = pipeline
        self.settings = settings
        self.types = types
        self._last_stamp: int | None = None
        #: The frame_id of the sensor being labelled (None: not seen yet, or reset).
        self.frame_id: str | None = None
        self._frame_changes: list[int] = []  # input stamps (ns) of the recent frame_id changes
        self._frames_seen: dict[str, int] = {}  # frame_id -> newest stamp (ns) seen, over every cloud received
        #: Non-empty while two sensors seem to share the input topic (frame_ids alternating): one line to report.
        self.stream_problem = ""

    def reset(self) -> None:
        """Forget the past (also the pipeline's scan buffer and odometry, and the stream's frame_id)."""
        self.pipeline.reset()
        self._last_stamp = None
        self.frame_id = None

    def process(self, msg: Any, wanted: frozenset[str] | None = None) -> ScanOutput:
        """Label one cloud; ``wanted`` limits which messages are built (None = all).

        Raises ScanError (a :class:`SkippedScan` or a layout error) for clouds that are skipped.
        """
        t0 = time.perf_counter()
        stamp = m.stamp_ns(msg.header.stamp)
        frame_id = str(msg.header.frame_id)
        view = view_cloud(msg)
        sensor = self.pipeline.sensor
        limit = MAX_POINTS_PER_PIXEL * sensor.height * sensor.width
        if view.size > limit:  # refused before decoding: per-scan memory stays bounded by the sensor
            raise SkippedScan("too_many_points", f"cloud at {stamp * 1e-9:.3f} s has {view.size} points, more than "
                              f"{MAX_POINTS_PER_PIXEL} per pixel of the {sensor.name} range image "
                              f"({sensor.height} x {sensor.width}): not a scan of this sensor, skipped")
        points, intensity, valid_index = decode_xyz_intensity(view)
        t_decode = (time.perf_counter() - t0) * 1e3
        if len(points) < self.settings.min_points:
            raise SkippedScan("too_few_points", f"cloud at {stamp * 1e-9:.3f} s has {len(points)} finite points "
                              f"of {view.size} (min_points {self.settings.min_points}): skipped")
        notes: list[str] = []
        reset = self._check_frame(stamp, frame_id, notes)
        if self._last_stamp is not None and not reset:
            if stamp == self._last_stamp:
                raise SkippedScan("duplicate_stamp", f"cloud at {stamp * 1e-9:.3f} s repeats the last stamp: skipped")
            gap = (stamp - self._last_stamp) * 1e-9
            if 0 < -gap <= self.settings.stamp_tolerance:  # driver jitter, a late message: no time travel
                raise SkippedScan("late_stamp", f"cloud at {stamp * 1e-9:.3f} s is {-gap * 1e3:.1f} ms older than "
                                  f"the last scan (within stamp_tolerance {self.settings.stamp_tolerance:g} s): "
                                  "skipped, the history kept")
            if self.settings.reset_after_gap > 0 and gap > self.settings.reset_after_gap:
                # The odometry map still describes where the sensor is: only the past scans are too old to use.
                self.pipeline.forget_past_scans()
                notes.append(f"{gap:.2f} s since the last scan (> reset_after_gap): scan buffer reset, odometry kept")
                reset = True
        try:
            result = self.pipeline.process(points, intensity, stamp * 1e-9)
        except ImplausibleScanError as exc:
            raise SkippedScan("implausible_scan", f"cloud at {stamp * 1e-9:.3f} s is {exc}: skipped") from None
        self._last_stamp = stamp
        notes.extend(result.warnings)
        reset = reset or result.reset

        t1 = time.perf_counter()
        kept = valid_index[result.valid]
        moving = result.labels[result.valid].astype(bool)
        withhold = not result.residuals_complete and not self.settings.publish_incomplete
        messages = self._build(wanted, stamp, frame_id, view, kept, moving, result, withhold)
        timings = {"decode": t_decode, **{k: v for k, v in result.timings.items() if k != "total"},
                   "encode": (time.perf_counter() - t1) * 1e3}
        timings["total"] = (time.perf_counter() - t0) * 1e3
        return ScanOutput(stamp_ns=stamp, frame_id=frame_id, result=result, valid_index=kept, points=points,
                          messages=messages, timings=timings, notes=notes, reset=reset, labels_withheld=withhold)

    def _check_frame(self, stamp: int, frame_id: str, notes: list[str]) -> bool:
        """Follow the stream's frame_id: True when a change reset the pipeline; :class:`SkippedScan` for another
        sensor's cloud with ``frame_change: skip``. Keeps :attr:`stream_problem` up to date."""
        if frame_id == self.settings.odom_frame:
            raise SkippedScan("odom_frame_cloud", f"cloud at {stamp * 1e-9:.3f} s has frame_id {frame_id!r}, the "
                              "odom_frame: the node needs clouds in the sensor's own frame: skipped")
        window = int(INTERLEAVE_WINDOW_S * 1e9)
        self._frames_seen[frame_id] = max(stamp, self._frames_seen.get(frame_id, stamp))
        self._frames_seen = {f: t for f, t in self._frames_seen.items() if abs(stamp - t) <= window}  # bounded
        previous = self.frame_id
        changed = previous is not None and frame_id != previous
        if changed:
            self._frame_changes.append(stamp)
        self._frame_changes = [t for t in self._frame_changes if abs(stamp - t) <= window]
        recent = sorted(self._frames_seen)
        skip = self.settings.frame_change == "skip"
        reported = self.stream_problem
        if skip and previous is not None and previous not in self._frames_seen:
            self.stream_problem = (f"clouds of frame_id {', '.join(map(repr, recent))} arrive, none of the stream's "
                                   f"{previous!r} (frame_change: skip): nothing is labelled; restart the node for "
                                   "the new sensor, or set frame_change: reset")
        elif len(self._frame_changes) >= 2 or (skip and len(recent) > 1):
            self.stream_problem = (f"clouds of {len(recent)} sensors interleaved on one topic (frame_ids "
                                   f"{', '.join(map(repr, recent))}): give each sensor its own topic and node"
                                   + (f"; only {self.frame_id!r} is labelled" if skip
                                      else " (with frame_change: skip the first one is labelled alone)"))
        else:
            self.stream_problem = ""
        if not changed:
            self.frame_id = frame_id
            return False
        if skip:
            raise SkippedScan("other_frame", f"cloud at {stamp * 1e-9:.3f} s has frame_id {frame_id!r}, not the "
                              f"stream's {previous!r} (another sensor? frame_change: skip): skipped")
        self.reset()
        self.frame_id = frame_id
        if not (reported and self.stream_problem):  # while interleaving is reported, not one line per scan
            notes.append(f"frame_id changed from {previous!r} to {frame_id!r} (another sensor on the topic?): scan "
                         "buffer and odometry reset")
        return True

    def _build(self, wanted: frozenset[str] | None, stamp: int, frame_id: str, view: Any, kept: np.ndarray,
               moving: np.ndarray, result: MosResult, withhold: bool) -> dict[str, Any]:
        context = ScanContext(
            types=self.types, header=m.make_header(self.types, stamp, frame_id),
            odom_header=m.make_header(self.types, stamp, self.settings.odom_frame),
            child_frame=self.settings.sensor_frame or frame_id, view=view, kept=kept, moving=moving, result=result)
        return build_messages(context, wanted, withhold, self.settings.publish_tf)
