"""Running the pipeline over SemanticKITTI sequences and scoring predictions as the benchmark does.

Predictions are written in the MOS benchmark's submission layout,
``<out>/sequences/XX/predictions/NNNNNN.label`` with 9 = static and 251 = moving.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ros2_mos.core.errors import DatasetError, ScanError, scan_refused
from ros2_mos.core.pipeline import MosPipeline, MosResult
from ros2_mos.io.conventions import label_dirs
from ros2_mos.io.labels import MOVING, check_prediction_ids, to_moving_classes, to_submission
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label, read_scan, sequence_dirs, write_label
from ros2_mos.scoring.breakdown import ErrorBreakdown
from ros2_mos.scoring.metrics import MovingIoU


@dataclass
class ScanPrediction:
    index: int
    result: MosResult
    gt_classes: np.ndarray | None


def predict_sequence(
    pipeline: MosPipeline, sequence: SemanticKittiSequence, use_dataset_poses: bool = False
) -> Iterator[ScanPrediction]:
    """Label every scan of a sequence in order (the pipeline is reset first); a scan the pipeline refuses (no points,
    none finite) stops it (:func:`~ros2_mos.core.errors.scan_refused`)."""
    if use_dataset_poses:
        sequence.require_poses("--use-poses")
    pipeline.reset()
    for frame in sequence:
        pose = frame.pose if use_dataset_poses else None
        try:
            result = pipeline.process(frame.points, frame.remission, frame.timestamp, pose=pose)
        except ScanError as exc:
            raise scan_refused(exc, sequence.scan_place(frame.index)) from exc
        gt = None if frame.labels is None else to_moving_classes(frame.labels)
        yield ScanPrediction(frame.index, result, gt)


def prediction_dir(out_root: str | Path, sequence_name: str) -> Path:
    return Path(out_root) / "sequences" / sequence_name / "predictions"


def write_prediction(out_root: str | Path, sequence: SemanticKittiSequence, index: int, moving: np.ndarray) -> None:
    path = prediction_dir(out_root, sequence.name) / (sequence.scan_files[index].stem + ".label")
    write_label(path, to_submission(moving))


def gt_conventions(gt_root: str | Path, sequences: list[str] | None = None) -> list[str]:
    """The label conventions every ground-truth sequence has (main one first; see :mod:`ros2_mos.io.conventions`)."""
    found: list[str] | None = None
    for seq_dir in sequence_dirs(gt_root, sequences):
        names = list(label_dirs(seq_dir))
        found = names if found is None else [n for n in found if n in names]
    return found or []


def evaluate_predictions(
    pred_root: str | Path,
    gt_root: str | Path,
    sequences: list[str] | None = None,
    progress: Callable[[Iterator], Iterator] = lambda it: it,
    skipped: list[str] | None = None,
    breakdown: ErrorBreakdown | None = None,
    convention: str | None = None,
    warnings: list[str] | None = None,
) -> dict[str, MovingIoU]:
    """Moving IoU per sequence for a submission folder against SemanticKITTI ground truth.

    Predictions are read as the benchmark reads them: every id 251-259 is moving, 0 and 1 are no prediction;
    a file of non-SemanticKITTI ids (binary 0/1, class indices) or a damaged file is a DatasetError.
    Without ``sequences`` every ground-truth sequence that has predictions is scored;
    the names of those without predictions are appended to ``skipped`` (so that a
    caller can say the total covers only part of the data). ``convention`` picks the ground-truth labels of that
    convention (default: the sequence's ``labels/``). Prediction files without a scan are named in ``warnings``.
    With ``breakdown`` every scored scan is also added to it (this reads the points, not only their count).
    """
    gt_dirs = {p.name: p for p in sequence_dirs(gt_root, sequences)}
    scores: dict[str, MovingIoU] = {}
    for name, gt_dir in gt_dirs.items():
        pred_dir = prediction_dir(pred_root, name)
        if not pred_dir.is_dir():
            if sequences is None:
                if skipped is not None:
                    skipped.append(name)
                continue
            raise DatasetError(f"no predictions for sequence {name}: {pred_dir} is missing")
        gt_seq = SemanticKittiSequence(gt_dir)
        folders = label_dirs(gt_dir)
        if convention is None:
            label_folder = gt_dir / "labels"
        elif convention in folders:
            label_folder = folders[convention]
        else:
            raise DatasetError(f"{gt_dir}: no labels in the {convention} convention (has: "
                               f"{', '.join(folders) or 'none'})")
        if not (label_folder.is_dir() and any(label_folder.glob("*.label"))):
            raise DatasetError(f"{gt_dir}: no labels/ to evaluate against")
        if warnings is not None:
            stems = {f.stem for f in gt_seq.scan_files}
            extra = sorted(f.name for f in pred_dir.glob("*.label") if f.stem not in stems)
            if extra:
                warnings.append(f"sequence {name}: {len(extra)} prediction file(s) without a scan, ignored "
                                f"({', '.join(extra[:3])}{' ...' if len(extra) > 3 else ''})")
        score = MovingIoU()
        for i in progress(range(len(gt_seq))):
            n_points = gt_seq.scan_files[i].stat().st_size // 16
            stem = gt_seq.scan_files[i].stem
            gt = read_label(label_folder / (stem + ".label"), n_points)  # a short ground-truth file is named
            pred_file = pred_dir / (stem + ".label")
            pred = read_label(pred_file, n_points)
            check_prediction_ids(pred, str(pred_file))
            predicted_moving = to_moving_classes(pred) == MOVING
            score.update(predicted_moving, to_moving_classes(gt))
            if breakdown is not None:  # the scan's points; its labels are read above
                points = read_scan(gt_seq.scan_files[i])[:, :3]
                pose = None if gt_seq.poses is None else gt_seq.poses[i]
                breakdown.update(name, points, gt, predicted_moving, pose, float(gt_seq.times[i]))
        scores[name] = score
    if not scores:
        raise DatasetError(f"no sequence of {gt_root} has predictions under {pred_root}/sequences")
    return scores
