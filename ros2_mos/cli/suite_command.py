"""``suite``: score a model on the fixed evaluation suite (held-out simulated presets + real scans)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import PARAMS_OPTION, app, fail


@app.command()
def suite(
    model: Optional[Path] = typer.Option(None, help="ONNX model (default: the shipped model)"),
    params: Optional[Path] = PARAMS_OPTION,
    data: Path = typer.Option(Path("data/suite"),
                              help="Where the suite's simulated sequences live (simulated on first use)"),
    real: Path = typer.Option(Path("data/real-kitti08-dev"),
                              help="Real development scans (../shared/real/unpack.sh DEST); skipped where absent"),
    scans: int = typer.Option(100, min=10, max=2000, help="Scans per simulated sequence"),
    quick: bool = typer.Option(False, "--quick", help="One seed per preset (a smoke test, not the suite's figures)"),
    out: Optional[Path] = typer.Option(None, "--out", help="Also write the table (Markdown) to this file"),
    sensor: str = typer.Option("hdl64", help="Sensor preset: its held-out drives are simulated into DATA/SENSOR "
                                             "(other than hdl64) and scored with its model; real scans: hdl64 only"),
    by_instance: bool = typer.Option(False, "--by-instance", help="After the table, where the model's errors sit "
                                     "over all rows (as `eval --by-instance`; not written to --out)"),
    top: int = typer.Option(15, "--top", help="--by-instance: how many movers to list", min=1),
) -> None:
    """Moving IoU, precision, recall and false positives of a model beside the Residual and Residual + RG baselines."""
    from datetime import date

    from tqdm import tqdm

    from ros2_mos.cli.core_commands import load_config, print_breakdown
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.scoring.breakdown import ErrorBreakdown
    from ros2_mos.scoring.suite import SIM_SEEDS, format_table, run_suite

    if out is not None and out.exists() and not out.is_file():
        fail(f"--out {out} exists and is not a file")
    from ros2_mos.core.config import sensor_preset

    spec = sensor_preset(sensor)
    if spec.name != "hdl64":
        data, real = data / spec.name, None
    pipeline = MosPipeline(load_config(params, model, spec.name))
    seeds = {k: v[:1] for k, v in SIM_SEEDS.items()} if quick else SIM_SEEDS
    typer.echo(f"model {pipeline.model.path.name}: {pipeline.model.metadata.network}, {pipeline.setup.label}, "
               f"threshold {pipeline.threshold:.2f}, sensor {pipeline.sensor.name}")
    breakdown = ErrorBreakdown() if by_instance else None
    with tqdm(desc="suite", unit="scan", leave=False) as bar:
        tables = run_suite(pipeline, data, real, scans, seeds, log=typer.echo, progress=bar.update,
                         sensor=spec.name, breakdown=breakdown)
    pipeline.close()
    title = (f"Evaluation suite, {date.today().isoformat()}: model `{pipeline.model.path.name}` "
             f"({pipeline.setup.label}, threshold {pipeline.threshold:.2f}), sensor {pipeline.sensor.name}, "
             f"KISS-ICP poses, {scans} scans per "
             "simulated sequence (seeds " + ", ".join(f"{k} {'/'.join(map(str, v))}" for k, v in seeds.items()) + ")\n")
    table = "\n\n".join(format_table(rows, f"{title}\nLabel convention: **{convention}**\n")
                         for convention, rows in tables.items())
    typer.echo(table)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        from ros2_mos.core.atomic import write_text_atomically

        write_text_atomically(out, table + "\n")
    if breakdown is not None:
        print_breakdown(breakdown, top)


@app.command()
def calibrate(
    data: Path = typer.Argument(..., help="SemanticKITTI-format root or one labelled sequence folder"),
    sequences: Optional[list[str]] = typer.Option(None, "--sequence", help="Only these sequences (repeat the option)"),
    model: Optional[Path] = typer.Option(None, help="ONNX model (default: the shipped model)"),
    params: Optional[Path] = PARAMS_OPTION,
    use_poses: bool = typer.Option(False, "--use-poses", help="The dataset's poses.txt instead of KISS-ICP"),
    sensor: Optional[str] = typer.Option(None, help="Sensor preset (default: the model's own)"),
    write: bool = typer.Option(False, "--write", help="Store the best threshold in the model file's metadata"),
) -> None:
    """The moving threshold of best point IoU (after the kNN vote) on labelled validation sequences."""
    from tqdm import tqdm

    from ros2_mos.cli.core_commands import load_config
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence, sequence_dirs
    from ros2_mos.scoring.calibration import threshold_curve

    pipeline = MosPipeline(load_config(params, model, sensor))
    seqs = [SemanticKittiSequence(d) for d in sequence_dirs(data, sequences)]
    with tqdm(total=sum(len(s) for s in seqs), desc="calibrate", unit="scan", leave=False) as bar:
        curve = threshold_curve(pipeline, seqs, use_poses, progress=bar.update)
    pipeline.close()
    for t in (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9):
        typer.echo(f"threshold {t:.2f}: moving IoU {100 * curve.iou_at(t):.1f}")
    best, best_iou = curve.best()
    typer.echo(f"best threshold {best:.2f}: moving IoU {100 * best_iou:.1f} "
               f"({', '.join(s.name for s in seqs)}; at the model's own {pipeline.threshold:.2f}: "
               f"{100 * curve.iou_at(pipeline.threshold):.1f})")
    if write:
        from ros2_mos.core.metadata import write_recommended_threshold

        path = pipeline.model.path
        write_recommended_threshold(path, best)
        typer.echo(f"stored recommended_threshold {best:.2f} in {path}")
