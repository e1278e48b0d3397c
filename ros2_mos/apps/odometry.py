"""KISS-ICP over a sequence with moving points masked three ways (the paper's SuMa vs SuMa+MOS).

``none``    plain KISS-ICP: every valid point is registered and enters the local map.
``mos``     the MOS pipeline with ``map_update='static'``: each scan is registered with all its
            points (its pose must exist before its residuals and labels can), then only the points
            MOS labelled static enter KISS-ICP's local map. Causal: usable online, as the node runs.
``gt``      oracle: ground-truth moving points are removed before registration *and* from the map.
            An upper bound of what any mask can give.
``gt-map``  ground-truth mask applied only where ``mos`` applies its mask (the map update): the
            best the causal ``mos`` design can reach with a perfect segmentation. ``mos`` vs
            ``gt-map`` measures segmentation errors; ``gt-map`` vs ``gt`` the price of causality.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import numpy as np

from ros2_mos.apps.kitti_metrics import SEGMENT_LENGTHS, STEP_SIZE, OdometryErrors, evaluate_trajectory, to_camera_frame
from ros2_mos.core.config import MosConfig
from ros2_mos.core.errors import ConfigError, DatasetError, ScanError, scan_refused
from ros2_mos.core.inference import MosModel
from ros2_mos.core.odometry import KissIcpOdometry
from ros2_mos.core.projection import finite_mask
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import Frame, SemanticKittiSequence, read_calib

MASKS: tuple[str, ...] = ("none", "mos", "gt", "gt-map")
Progress = Callable[[Iterable[Frame]], Iterable[Frame]]


def _no_progress(frames: Iterable[Frame]) -> Iterable[Frame]:
    return frames


@dataclass
class OdometryRun:
    """Estimated LiDAR poses of every scan of one sequence under one mask."""

    sequence: str
    mask: str
    poses: np.ndarray  # (N, 4, 4) world poses of the LiDAR; the first scan is the origin
    milliseconds: np.ndarray  # (N,) wall-clock time per scan (for 'mos' the whole pipeline)
    masked_share: float  # share of valid points kept out of the map ('mos': labelled moving)


def parse_masks(mask: str) -> list[str]:
    """``'all'`` or one of :data:`MASKS` (comma-separated lists too) to a list of masks."""
    names = list(MASKS) if mask == "all" else [m.strip() for m in mask.split(",") if m.strip()]
    unknown = [m for m in names if m not in MASKS]
    if unknown or not names:
        raise ConfigError(f"unknown mask {mask!r}; choose from {', '.join(MASKS)} or 'all'")
    return names


def _gt_moving(frame: Frame, valid: np.ndarray, sequence: SemanticKittiSequence) -> np.ndarray:
    if frame.labels is None:
        raise DatasetError(f"{sequence.root}: the ground-truth masks need labels/ (scan {frame.index} has none)")
    return to_moving_classes(frame.labels)[valid] == MOVING


def _kiss_frames(
    sequence: SemanticKittiSequence, mask: str, config: MosConfig, progress: Progress
) -> Iterator[tuple[np.ndarray, float, float]]:
    """Plain KISS-ICP with an optional ground-truth mask: yields (pose, ms, masked share) per scan."""
    odometry = KissIcpOdometry(config.odometry)
    for frame in progress(sequence):
        start = time.perf_counter()
        valid = finite_mask(frame.points)
        points = frame.points[valid]
        if mask == "none":
            pose = odometry.register(points)
            masked = 0.0
        else:
            static = ~_gt_moving(frame, valid, sequence)
            if mask == "gt":
                pose = odometry.register(points[static])
            else:  # gt-map
                pose = odometry.estimate(points)
                odometry.update_map(points[static])
            masked = 1.0 - float(static.mean()) if len(static) else 0.0
        yield pose, (time.perf_counter() - start) * 1e3, masked


def _mos_frames(
    sequence: SemanticKittiSequence, config: MosConfig, model: MosModel | None, progress: Progress
) -> Iterator[tuple[np.ndarray, float, float]]:
    from ros2_mos.core.pipeline import MosPipeline

    cfg = dataclasses.replace(config, odometry=dataclasses.replace(config.odometry, map_update="static"))
    pipeline = MosPipeline(cfg, model)
    pipeline.reset()
    for frame in progress(sequence):
        start = time.perf_counter()
        try:
            result = pipeline.process(frame.points, frame.remission, frame.timestamp)
        except ScanError as exc:
            raise scan_refused(exc, sequence.scan_place(frame.index)) from exc
        n_valid = int(result.valid.sum())
        masked = float(result.labels[result.valid].sum()) / n_valid if n_valid else 0.0
        yield result.pose, (time.perf_counter() - start) * 1e3, masked


def run_odometry(
    sequence: SemanticKittiSequence,
    mask: str,
    config: MosConfig = MosConfig(),
    model: MosModel | None = None,
    progress: Progress = _no_progress,
) -> OdometryRun:
    """KISS-ICP over every scan of ``sequence`` under ``mask`` (see the module docstring).

    ``config.odometry`` is used for every mask, so the runs differ only in what is masked;
    ``model`` (or ``config.model``, or the shipped model) is only loaded for ``mos``.
    """
    if mask not in MASKS:
        raise ConfigError(f"unknown mask {mask!r}; choose from {', '.join(MASKS)}")
    if mask.startswith("gt") and not sequence.has_labels:
        raise DatasetError(f"{sequence.root}: mask {mask!r} needs ground-truth labels/ and there are none")
    frames = (
        _mos_frames(sequence, config, model, progress)
        if mask == "mos"
        else _kiss_frames(sequence, mask, config, progress)
    )
    poses, ms, masked = [], [], []
    for pose, t, share in frames:
        poses.append(pose)
        ms.append(t)
        masked.append(share)
    return OdometryRun(sequence.name, mask, np.array(poses), np.array(ms), float(np.mean(masked)))


def ground_truth_camera_poses(sequence: SemanticKittiSequence) -> tuple[np.ndarray, np.ndarray | None]:
    """The sequence's ground truth in the devkit's frame, and the calibration to get there (or None)."""
    gt = sequence.require_poses("the odometry's ground truth")
    calib = sequence.root / "calib.txt"
    tr = read_calib(calib) if calib.is_file() else None
    return (gt if tr is None else to_camera_frame(gt, tr)), tr


def evaluate_run(
    run: OdometryRun,
    sequence: SemanticKittiSequence,
    lengths: tuple[float, ...] = SEGMENT_LENGTHS,
    step: int = STEP_SIZE,
    alignment: str = "se3",
) -> OdometryErrors:
    """KITTI errors of a run, in the camera frame as the devkit evaluates them when calib.txt exists."""
    gt, tr = ground_truth_camera_poses(sequence)
    est = run.poses if tr is None else to_camera_frame(run.poses, tr)
    return evaluate_trajectory(gt, est, lengths, step, alignment)
