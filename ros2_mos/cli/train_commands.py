"""``train``, ``export`` and ``ablation``: thin CLI wrappers over :mod:`ros2_mos.training`.

torch is imported inside the commands, so the rest of the CLI works without it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import app, check_choice, check_output, fail


@app.command()
def train(
    config: Path = typer.Option(..., "--config", help="Training YAML (see configs/*.yaml)"),
    data: Path = typer.Option(..., "--data", help="SemanticKITTI-format root (…/sequences/XX) with labels and poses"),
    out: Optional[Path] = typer.Option(None, "--out", help="Run folder (overrides the config's out_dir)"),
    epochs: Optional[int] = typer.Option(None, help="Override the config's epochs"),
    max_minutes: Optional[float] = typer.Option(None, help="Override the config's wall-clock budget (minutes per run)"),
    export_to: Optional[Path] = typer.Option(None, "--export", help="Export best.pt to this ONNX file at the end"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="tqdm progress bar"),
    overrides: Optional[list[str]] = typer.Option(None, "--set", help="Override a config key: --set KEY=VALUE "
                                                  "(VALUE in YAML, e.g. --set signed_residuals=false; repeatable)"),
) -> None:
    """Train a MOS network; resumes from OUT/last.pt.

    Multi-GPU / multi-process: ``torchrun --nproc_per_node=G $(which ros2-mos) train ...`` \
(DDP, NCCL on GPUs, gloo on CPU).
    """
    import dataclasses

    from ros2_mos.training.trainer import TrainConfig, Trainer, export_checkpoint

    cfg = TrainConfig.from_yaml(config)
    if overrides:
        cfg = TrainConfig.from_dict({**cfg.to_dict(), **parse_overrides(overrides)})
    if out is not None:
        cfg = dataclasses.replace(cfg, out_dir=str(out))
    if epochs is not None:
        cfg = dataclasses.replace(cfg, epochs=epochs)
    if max_minutes is not None:
        cfg = dataclasses.replace(cfg, max_minutes=max_minutes)
    check_output(Path(cfg.out_dir), "out_dir", folder=True)
    if export_to is not None:
        check_output(export_to, "--export")
    trainer = Trainer(cfg, data, log=typer.echo, show_progress=progress)
    if trainer.dist.main:
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


def parse_overrides(items: list[str]) -> dict:
    """``KEY=VALUE`` strings (VALUE parsed as YAML) as a dict; a malformed item is a one-line error."""
    import yaml

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            fail(f"--set takes KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            fail(f"--set {key}: the value is not valid YAML ({exc.__class__.__name__})")
    return out


@app.command()
def export(
    checkpoint: Path = typer.Argument(..., help="Training checkpoint (best.pt / last.pt)"),
    out: Path = typer.Option(..., "--out", help="ONNX file to write"),
    threshold: Optional[float] = typer.Option(None, help="Store a validation-tuned moving threshold in the metadata"),
) -> None:
    """Export a checkpoint to ONNX (softmax head, metadata inside), checked against PyTorch."""
    from ros2_mos.training.trainer import export_checkpoint

    if not checkpoint.is_file():
        fail(f"checkpoint not found: {checkpoint}")
    if threshold is not None and not 0.0 < threshold < 1.0:  # NaN fails this too
        fail(f"--threshold must be in (0, 1), got {threshold}")
    check_output(out, "--out")
    extra = None if threshold is None else {"recommended_threshold": threshold}
    report = export_checkpoint(checkpoint, out, extra=extra)
    typer.echo(f"exported {report.path} ({report.size_bytes / 1e6:.2f} MB, "
               f"ONNX vs PyTorch max abs diff {report.max_abs_diff:.1e})")


@app.command()
def ablation(
    config: Path = typer.Option(..., "--config", help="Base training YAML; each variant changes only network/input"),
    data: Path = typer.Option(..., "--data", help="SemanticKITTI-format root"),
    test: list[str] = typer.Option(..., "--test", help="Held-out test sequences (repeat the option)"),
    test_data: Optional[Path] = typer.Option(None, "--test-data",
                                             help="SemanticKITTI-format root of the test sequences (default: --data)"),
    variant: list[str] = typer.Option(
        ["fastmos:residual:0", "fastmos:frames:1", "fastmos:residual:1", "fastmos:residual:8"],
        "--variant", help="NETWORK:residual|frames:N or NETWORK:residual:O1,O2,... rows (repeat the option)",
    ),
    runs: Path = typer.Option(Path("runs/ablation"), help="Run folders of the variants (resumed if present)"),
    epochs: Optional[int] = typer.Option(None, help="Override the base config's epochs"),
    max_minutes: Optional[float] = typer.Option(None, help="Override the wall-clock budget per variant (minutes)"),
    baselines: bool = typer.Option(True, "--baselines/--no-baselines", help="Include the Residual / Residual+RG rows"),
    out: Optional[Path] = typer.Option(None, "--out", help="Also write the table to this Markdown file"),
    test_stride: int = typer.Option(1, help="Score every k-th test scan only (faster; residuals still use all scans)"),
) -> None:
    """The paper's ablation (Tables I/II) on held-out sequences: point moving IoU with kNN back-projection."""
    import dataclasses

    from ros2_mos.training.ablation import Variant, format_table, run_ablation
    from ros2_mos.training.trainer import TrainConfig

    base = TrainConfig.from_yaml(config)
    if epochs is not None:
        base = dataclasses.replace(base, epochs=epochs)
    if max_minutes is not None:
        base = dataclasses.replace(base, max_minutes=max_minutes)
    variants = [Variant.parse(v) for v in variant]
    rows = run_ablation(base, data, [t.zfill(2) if t.isdigit() else t for t in test], variants, runs,
                        baselines=baselines, log=typer.echo, test_stride=test_stride, test_root=test_data)
    table = format_table(rows)
    typer.echo(table)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        from ros2_mos.core.atomic import write_text_atomically

        write_text_atomically(out, table + "\n")


@app.command("import-lidar-mos")
def import_lidar_mos(
    model_dir: Path = typer.Argument(...,
                                     help="A released LiDAR-MOS model folder (arch_cfg.yaml + SalsaNext_valid_best, "
                                          "or + backbone, segmentation_decoder, segmentation_head)"),
    out: Path = typer.Option(..., "--out", help="ONNX file to write (run it with -p model:=FILE / --model FILE)"),
) -> None:
    """Turn the LiDAR-MOS authors' SalsaNext or RangeNet++ (N = 1 or 8) into a model the node runs unchanged."""
    from ros2_mos.training.lidar_mos import import_lidar_mos as run_import

    if out.exists() and not out.is_file():
        fail(f"--out {out} exists and is not a file")
    report = run_import(model_dir, out)
    typer.echo(f"exported {report.path} ({report.size_bytes / 1e6:.1f} MB, ONNX vs PyTorch max abs diff "
               f"{report.max_abs_diff:.1e}); trained on KITTI's HDL-64E: other sensors need their own model")


@app.command()
def adapt(
    drives: list[Path] = typer.Argument(..., help="Unlabelled drives of one sensor: SemanticKITTI sequence folders "
                                                  "(velodyne/*.bin) or rosbag2 bags"),
    out: Path = typer.Option(..., "--out", help="The adapted ONNX model to write"),
    model: Optional[Path] = typer.Option(None, help="BASE model to fine-tune (default: the shipped model of the "
                                                    "sensor)"),
    sensor: Optional[str] = typer.Option(None, help="Sensor preset of the drives (default: BASE's)"),
    work: Optional[Path] = typer.Option(None, help="Work folder: labels, data, caches, checkpoints; an interrupted "
                                                   "run resumes from it (default: OUT's name + .work/)"),
    epochs: int = typer.Option(6, min=1, max=100, help="Fine-tuning epochs"),
    sim_drives: int = typer.Option(4, min=0, max=40, help="Simulated drives of the same sensor mixed in"),
    holdout: float = typer.Option(0.25, help="Share of each drive (its last scans) held out to pick the epoch and "
                                             "the threshold"),
    max_minutes: float = typer.Option(50.0, help="Wall-clock budget of the training (minutes)"),
    topic: Optional[str] = typer.Option(None, help="PointCloud2 topic of bags (default: their only one)"),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the plan (scans, epochs, expected minutes); "
                                                          "do nothing"),
    deskew: str = typer.Option("auto", help="autolabel's --deskew for the drives' labels: on for sweeps no driver "
                               "compensated (KITTI raw's), off for compensated ones; auto: where a folder's sweep.txt "
                               "says skewed or a bag's clouds carry per-point times"),
) -> None:
    """Fine-tune the online model on your own unlabelled drives, with labels made by `ros2-mos autolabel`."""
    import math

    from ros2_mos.core.config import lidar_of, sensor_preset
    from ros2_mos.core.inference import MosModel, default_model_path
    from ros2_mos.offline.drives import open_drive
    from ros2_mos.training.adapt import AdaptConfig, plan_adaptation
    from ros2_mos.training.adapt import adapt as run_adapt

    if not math.isfinite(holdout) or not 0 < holdout < 0.9:
        fail(f"--holdout must be in (0, 0.9), got {holdout}")
    if not math.isfinite(max_minutes) or max_minutes <= 0:
        fail(f"--max-minutes must be a positive number, got {max_minutes}")
    from ros2_mos.core.deskew import DESKEW_MODES

    check_choice(deskew, DESKEW_MODES, "--deskew")
    if out.suffix != ".onnx":
        fail(f"--out must end in .onnx, got {out.name}")
    check_output(out, "--out")
    if sensor is not None:
        spec = sensor_preset(sensor)
        base = model if model is not None else default_model_path(spec.name)
    else:
        base = model if model is not None else default_model_path(None)
        spec = lidar_of(MosModel(str(base)).metadata.sensor)  # the LiDAR's clouds, not the model's image
    opened = [open_drive(d, topic) for d in drives]
    config = AdaptConfig(epochs=epochs, holdout=holdout, sim_drives=sim_drives, max_minutes=max_minutes, deskew=deskew)
    plan = plan_adaptation(opened, Path(base), spec, config)
    typer.echo(plan.describe())
    if dry_run:
        return
    work_dir = work if work is not None else out.with_name(out.stem + ".work")
    check_output(work_dir, "--work", folder=True)
    work_dir.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm

    from ros2_mos.offline.autolabel import AutolabelConfig, progress_steps

    steps = (sum(progress_steps(d.scans, AutolabelConfig()) for d in plan.drives) + plan.sim_train
             + config.sim_holdout * config.sim_scans)
    with tqdm(total=steps, desc="prepare (labels, simulated drives)", unit="scan") as bar:
        def step(stage: str, n: int) -> None:
            bar.set_postfix_str(stage, refresh=False)
            bar.update(n)

        result = run_adapt(opened, out, plan, work_dir, progress=step, log=typer.echo)
    typer.echo(f"wrote {result.model}: best epoch {result.best_epoch}, held-out IoU {100 * result.best_valid_iou:.1f} "
               f"(real scans against their automatic labels, and simulated drives), threshold {result.threshold:.2f}, "
               f"{result.minutes:.1f} min")
