"""``suite``: score a model on the fixed evaluation suite (held-out simulated presets + real scans)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import app, fail


@app.command()
def suite(
    model: Optional[Path] = typer.Option(None, help="ONNX model (default: the shipped model)"),
    config: Optional[Path] = typer.Option(None, help="The node's ROS params file (config/mos.yaml); default: built-in defaults"),
    data: Path = typer.Option(Path("data/suite"), help="Where the suite's simulated sequences live (simulated on first use)"),
    real: Path = typer.Option(Path("data/real-kitti08-dev"),
                              help="Real development scans (../shared/real/unpack.sh DEST); skipped where absent"),
    scans: int = typer.Option(100, min=10, max=2000, help="Scans per simulated sequence"),
    quick: bool = typer.Option(False, "--quick", help="One seed per preset (a smoke test, not the suite's figures)"),
    out: Optional[Path] = typer.Option(None, "--out", help="Also write the table (Markdown) to this file"),
) -> None:
    """Moving IoU, precision, recall and false positives of a model beside the Residual and Residual + RG baselines."""
    from datetime import date

    from tqdm import tqdm

    from ros2_mos.cli.core_commands import load_config
    from ros2_mos.pipeline import MosPipeline
    from ros2_mos.scoring.suite import SIM_SEEDS, format_table, run_suite

    if out is not None and out.exists() and not out.is_file():
        fail(f"--out {out} exists and is not a file")
    pipeline = MosPipeline(load_config(config, model))
    seeds = {k: v[:1] for k, v in SIM_SEEDS.items()} if quick else SIM_SEEDS
    typer.echo(f"model {pipeline.model.path.name}: {pipeline.model.metadata.network}, {pipeline.setup.label}, "
               f"threshold {pipeline.threshold:.2f}, sensor {pipeline.sensor.name}")
    with tqdm(desc="suite", unit="scan", leave=False) as bar:
        rows = run_suite(pipeline, data, real, scans, seeds, log=typer.echo, progress=bar.update)
    pipeline.close()
    title = (f"Evaluation suite, {date.today().isoformat()}: model `{pipeline.model.path.name}` "
             f"({pipeline.setup.label}, threshold {pipeline.threshold:.2f}), KISS-ICP poses, {scans} scans per "
             "simulated sequence (seeds " + ", ".join(f"{k} {'/'.join(map(str, v))}" for k, v in seeds.items()) + ")\n")
    table = format_table(rows, title)
    typer.echo(table)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(table + "\n")
