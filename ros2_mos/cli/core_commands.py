"""``infer`` and ``eval``: the pipeline over a sequence folder, and the benchmark's score."""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import PARAMS_OPTION, app, check_choice, fail
from ros2_mos.scoring.breakdown import ErrorBreakdown, class_name


def load_config(params: Optional[Path], model: Optional[Path], sensor: Optional[str] = None):
    """The pipeline configuration of the node's params file (or the defaults), with ``--model`` on top.

    One file format for the node and the offline tools, so that offline results are
    those the node gives with the same file.
    """
    from ros2_mos.ros.params import load_params, mos_config

    return mos_config(load_params(params, model, sensor))


#: The --sensor option of infer, process, bench and demo.
SENSOR_HELP = ("Sensor preset (hdl64, vlp16, vlp32c, os1-64, os1-128): its range image and shipped model "
               "(overrides the params file's sensor.preset; default: the model's own sensor)")


@app.command()
def infer(
    sequence_dir: Path = typer.Argument(..., help="SemanticKITTI sequence folder (needs only velodyne/*.bin) "
                                                  "or a dataset root"),
    out: Path = typer.Option(..., "--out", help="Output root: writes sequences/XX/predictions/*.label"),
    model: Optional[Path] = typer.Option(None,
                                         help="ONNX model exported by `ros2-mos export` (default: the shipped model)"),
    params: Optional[Path] = PARAMS_OPTION,
    sequences: Optional[list[str]] = typer.Option(None, "--sequence", help="Only these sequences of a dataset root"),
    use_poses: bool = typer.Option(False, "--use-poses", help="Use the dataset's poses.txt instead of KISS-ICP"),
    sensor: Optional[str] = typer.Option(None, help=SENSOR_HELP),
) -> None:
    """Label every scan of a sequence (moving 251 / static 9, the benchmark's submission format)."""
    from tqdm import tqdm

    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence, sequence_dirs
    from ros2_mos.scoring.evaluation import predict_sequence, write_prediction
    from ros2_mos.scoring.metrics import MovingIoU

    pipeline = MosPipeline(load_config(params, model, sensor))
    typer.echo(f"model {pipeline.model.path.name}: {pipeline.model.metadata.network}, "
               f"{pipeline.setup.label}, residuals to {pipeline.residual_window.upper:g} m, "
               f"sensor {pipeline.sensor.name}, provider {pipeline.model.provider}")
    for seq_dir in sequence_dirs(sequence_dir, sequences):
        seq = SemanticKittiSequence(seq_dir)
        score = MovingIoU()
        totals: list[float] = []
        for pred in tqdm(predict_sequence(pipeline, seq, use_poses), total=len(seq), desc=f"sequence {seq.name}"):
            if pred.result.sensor_mismatch:  # every label would be wrong: stop before writing any
                fail(f"{seq.name} scan {pred.index}: {pred.result.sensor_mismatch}")
            write_prediction(out, seq, pred.index, pred.result.labels)
            totals.append(pred.result.timings["total"])
            if pred.gt_classes is not None:
                score.update(pred.result.labels, pred.gt_classes)
        line = f"sequence {seq.name}: {len(seq)} scans, median {statistics.median(totals):.1f} ms/scan"
        if seq.has_labels:
            line += f", moving IoU {100 * score.iou:.1f}"
        typer.echo(line)


@app.command("eval")
def evaluate(
    pred_dir: Path = typer.Argument(..., help="Predictions root (sequences/XX/predictions/*.label)"),
    gt_dir: Path = typer.Argument(..., help="Ground-truth root (sequences/XX/labels/*.label) or one sequence folder"),
    sequences: Optional[list[str]] = typer.Option(None, "--sequence", help="Only these sequences"),
    by_instance: bool = typer.Option(False, "--by-instance", help="Also where the errors sit: the movers with "
                                     "the most missed points (range, speed), recall and false positives by range, "
                                     "false positives by class"),
    top: int = typer.Option(15, "--top", help="--by-instance: how many movers to list", min=1),
    convention: Optional[str] = typer.Option(None, help="Score against this label convention only "
                                             "(semantickitti or instant; default: every one the ground truth has)"),
) -> None:
    """Moving IoU per sequence and over all, as the SemanticKITTI MOS benchmark defines it.

    Simulated ground truth carries both label conventions (SemanticKITTI's: an object that moved while observed is
    moving throughout; instant: moving while it moves); each is scored and named.
    """
    from ros2_mos.io.conventions import CONVENTIONS
    from ros2_mos.scoring.evaluation import evaluate_predictions, gt_conventions
    from ros2_mos.scoring.metrics import MovingIoU

    if convention is not None:
        check_choice(convention, CONVENTIONS, "--convention")
    available = gt_conventions(gt_dir, sequences)
    if convention is not None and convention not in available:
        fail(f"{gt_dir}: no ground truth in the {convention} convention (has: {', '.join(available) or 'none'})")
    chosen = [convention] if convention else (available or [None])
    warnings: list[str] = []
    for k, name in enumerate(chosen):
        skipped: list[str] = []
        breakdown = ErrorBreakdown() if by_instance else None
        scores = evaluate_predictions(pred_dir, gt_dir, sequences, skipped=skipped, breakdown=breakdown,
                                      convention=name, warnings=warnings if k == 0 else None)
        if k == 0:
            for line in warnings:
                typer.secho(f"warning: {line}", err=True, fg=typer.colors.YELLOW)
        if name is not None:
            typer.echo(f"{'' if k == 0 else chr(10)}label convention: {name}")
        total = MovingIoU()
        typer.echo(f"{'sequence':>10} {'IoU':>7} {'TP':>10} {'FP':>10} {'FN':>10}")
        for seq_name, s in scores.items():
            total = total + s
            typer.echo(f"{seq_name:>10} {_pct(s.iou):>7} {s.tp:>10} {s.fp:>10} {s.fn:>10}")
        typer.echo(f"{'all':>10} {_pct(total.iou):>7} {total.tp:>10} {total.fp:>10} {total.fn:>10}")
        if skipped:
            typer.echo(f"note: 'all' covers {len(scores)} of {len(scores) + len(skipped)} ground-truth sequences; "
                       f"no predictions for {', '.join(skipped)}")
        if breakdown is not None:
            print_breakdown(breakdown, top)


def print_breakdown(breakdown: ErrorBreakdown, top: int) -> None:
    """The tables of ``--by-instance`` (``eval`` and ``suite``)."""
    movers = breakdown.movers()
    shown = movers[:top]
    typer.echo(f"\nmovers with the most missed points ({len(shown)} of {len(movers)}; range of the centroid, "
               "speed in the world frame):")
    width = max([len("sequence")] + [len(m.sequence) for m in shown])
    typer.echo(f"{'sequence':<{width}} {'instance':>8} {'class':<19} {'scans':>5} {'points':>8} {'missed':>8} "
               f"{'recall':>6} {'range m':>7} {'m/s':>5}")
    for m in shown:
        speed = "n/a" if math.isnan(m.speed) else f"{m.speed:.1f}"
        typer.echo(f"{m.sequence:<{width}} {m.instance:>8} {m.label:<19} {m.scans:>5} {m.points:>8} {m.missed:>8} "
                   f"{_pct(m.recall):>6} {m.median_range:>7.1f} {speed:>5}")
    typer.echo(f"\nby range of the point ({breakdown.scans} scans):")
    typer.echo(f"{'range':>10} {'moving':>9} {'recall':>6} {'FP points':>10}")
    for band in breakdown.by_range():
        typer.echo(f"{band.name:>10} {band.moving:>9} {_pct(band.recall):>6} {band.false_positives:>10}")
    false_positives = breakdown.false_positives_by_class()
    total = sum(n for _, n in false_positives)
    typer.echo("\nfalse positives by class (static points labelled moving):")
    if not false_positives:
        typer.echo("  none")
    for semantic, n in false_positives:
        typer.echo(f"{class_name(semantic):>19} {n:>9} {100 * n / total:>5.1f} %")


def _pct(x: float) -> str:
    return "n/a" if math.isnan(x) else f"{100 * x:.1f}"
