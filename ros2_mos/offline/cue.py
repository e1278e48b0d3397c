"""The online model's moving labels of each scan of a drive: the cue autolabel weighs (``AutolabelConfig.online_cue``).

The node's pipeline (:class:`~ros2_mos.core.pipeline.MosPipeline`) with autolabel's poses, so no odometry of its
own, over the scans in order: :class:`OnlineCue` labels each scan as it is added; :class:`OnlineCueProcess` does
that in a process of its own (:class:`~ros2_mos.core.worker.Worker`), ahead of the labelling. A scan the model
refuses (:class:`~ros2_mos.core.errors.ScanError`) gets no cue and is counted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import ConfigError, ScanError
from ros2_mos.core.worker import Worker


def _pipeline(model: Path, sensor: SensorConfig) -> Any:
    from ros2_mos.core.config import MosConfig
    from ros2_mos.core.pipeline import MosPipeline

    return MosPipeline(MosConfig(model=str(model), sensor=sensor))


class OnlineCue:
    """The cue in this process: each scan labelled as it is added, its labels kept until asked for."""

    def __init__(self, model: Path, sensor: SensorConfig) -> None:
        self._pipeline = _pipeline(model, sensor)
        self._labels: dict[int, np.ndarray | None] = {}
        self._added = 0
        self.skipped = 0  # scans the model refused

    def add(self, index: int, points: np.ndarray, intensity: np.ndarray, stamp: float, pose: np.ndarray) -> None:
        """Scan ``index``, the next of the drive (sensor-frame points, their intensities, seconds, world pose)."""
        self._check_order(index)
        self._labels[index] = label_scan(self._pipeline, points, intensity, stamp, pose)

    def labels(self, k: int) -> np.ndarray | None:
        """Scan k's moving labels, one per point (None where the model refused the scan); asked for once."""
        if k not in self._labels:
            raise ConfigError(f"online cue: scan {k} was not added, or was asked for already")
        labels = self._labels.pop(k)
        self.skipped += labels is None
        return labels

    def close(self) -> None:
        self._pipeline.close()

    def _check_order(self, index: int) -> None:
        if index != self._added:
            raise ConfigError(f"online cue: scan {index} arrived out of order")
        self._added += 1


class OnlineCueProcess(OnlineCue):
    """The cue in a process of its own: :meth:`add` hands the scan over, :meth:`labels` waits for its labels."""

    def __init__(self, model: Path, sensor: SensorConfig) -> None:
        self._worker = Worker("ros2_mos.offline.cue:cue_server", (Path(model), sensor), "online cue")
        self._labels = {}
        self._added = 0
        self._known = 0  # scans whose labels have come back
        self.skipped = 0

    def add(self, index: int, points: np.ndarray, intensity: np.ndarray, stamp: float, pose: np.ndarray) -> None:
        self._check_order(index)
        self._worker.send((np.asarray(points), np.asarray(intensity), float(stamp), np.asarray(pose)))

    def labels(self, k: int) -> np.ndarray | None:
        while self._known <= k < self._added:
            packed, n = self._worker.receive()
            self._labels[self._known] = None if packed is None else np.unpackbits(packed, count=n).astype(bool)
            self._known += 1
        return super().labels(k)

    def close(self) -> None:
        """Stop the process: at once where its labels are not all back."""
        self._worker.close(kill=self._known < self._added)


def label_scan(pipeline: Any, points: np.ndarray, intensity: np.ndarray, stamp: float,
               pose: np.ndarray) -> np.ndarray | None:
    """One scan's moving labels (bool, one per point) from ``pipeline``, or None where it refuses the scan."""
    try:
        return pipeline.process(points, intensity, stamp, pose=pose).labels > 0
    except ScanError:  # a scan the online model refuses gets no cue; visibility still judges it
        return None


def cue_server(setup: tuple[Path, SensorConfig]) -> Callable[[Any], list[Any]]:
    """The cue process's handler (:class:`~ros2_mos.core.worker.Worker`): a scan (points, intensity, stamp, pose)
    in, its labels (packed bits and their count, or None and 0 where refused) out."""
    pipeline = _pipeline(*setup)

    def handle(request: tuple[np.ndarray, np.ndarray, float, np.ndarray]) -> list[Any]:
        labels = label_scan(pipeline, *request)
        return [(None, 0) if labels is None else (np.packbits(labels), len(labels))]

    return handle
