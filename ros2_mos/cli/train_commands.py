"""``train``, ``export`` and ``ablation``: thin CLI wrappers over :mod:`ros2_mos.training`.

torch is imported inside the commands, so the rest of the CLI works without it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import app, fail


@app.command()
def train(
    config: Path = typer.Option(..., "--config", help="Training YAML (see configs/*.yaml)"),
    data: Path = typer.Option(..., "--data", help="SemanticKITTI-format root (…/sequences/XX) with labels and poses"),
    out: Optional[Path] = typer.Option(None, "--out", help="Run folder (overrides the config's out_dir)"),
    epochs: Optional[int] = typer.Option(None, help="Override the config's epochs"),
    export_to: Optional[Path] = typer.Option(None, "--export", help="Export best.pt to this ONNX file at the end"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="tqdm progress bar"),
) -> None:
    """Train a MOS network; resumes from OUT/last.pt. Runs DDP when launched by torchrun."""
    import dataclasses

    from ros2_mos.training.trainer import TrainConfig, Trainer, export_checkpoint

    cfg = TrainConfig.from_yaml(config)
    if out is not None:
        cfg = dataclasses.replace(cfg, out_dir=str(out))
    if epochs is not None:
        cfg = dataclasses.replace(cfg, epochs=epochs)
    trainer = Trainer(cfg, data, log=typer.echo, show_progress=progress)
    typer.echo(
        f"{cfg.network} {cfg.setup.label}: {len(trainer.train_set)} train / {len(trainer.valid_set)} valid scans, "
        f"class weights {[round(float(w), 2) for w in trainer.class_weights]}, out {cfg.out_dir}"
    )
    history = trainer.fit()
    if not trainer.dist.main:
        return
    if history:
        best = max(history, key=lambda h: h.valid_iou if h.valid_iou == h.valid_iou else -1)
        typer.echo(f"best valid IoU {100 * best.valid_iou:.1f} at epoch {best.epoch}")
    if export_to is not None:
        report = export_checkpoint(Path(cfg.out_dir) / "best.pt", export_to)
        typer.echo(f"exported {report.path} ({report.size_bytes / 1e6:.2f} MB, max abs diff {report.max_abs_diff:.1e})")


@app.command()
def export(
    checkpoint: Path = typer.Argument(..., help="Training checkpoint (best.pt / last.pt)"),
    out: Path = typer.Option(..., "--out", help="ONNX file to write"),
) -> None:
    """Export a checkpoint to ONNX (softmax head, metadata inside), checked against PyTorch."""
    from ros2_mos.training.trainer import export_checkpoint

    if not checkpoint.is_file():
        fail(f"checkpoint not found: {checkpoint}")
    report = export_checkpoint(checkpoint, out)
    typer.echo(f"exported {report.path} ({report.size_bytes / 1e6:.2f} MB, ONNX vs PyTorch max abs diff {report.max_abs_diff:.1e})")
