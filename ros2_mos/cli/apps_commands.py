"""``odometry`` and ``map``: the paper's applications (MOS-masked KISS-ICP, raw vs cleaned maps)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import PARAMS_OPTION, app, check_choice, check_output, fail


def _fmt(value: float, digits: int = 2) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def _lengths(segments: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in segments.split(",") if v.strip())
    except ValueError:
        fail(f"--segments must be comma-separated metres, got {segments!r}")
    if not values or min(values) <= 0:
        fail(f"--segments needs positive lengths, got {segments!r}")
    return values


@app.command()
def odometry(
    sequence_dir: Path = typer.Argument(..., help="SemanticKITTI sequence folder with poses.txt "
                                                  "(labels/ for gt masks), or a dataset root"),
    mask: str = typer.Option("all",
                             help="none | mos | gt | gt-map | all (or a comma list): what is kept out of KISS-ICP"),
    model: Optional[Path] = typer.Option(None, help="ONNX model for --mask mos (default: the shipped model)"),
    params: Optional[Path] = PARAMS_OPTION,
    sequences: Optional[list[str]] = typer.Option(None, "--sequence", help="Only these sequences of a dataset root"),
    segments: str = typer.Option("100,200,300,400,500,600,700,800", help="Segment lengths in m (KITTI: 100..800)"),
    alignment: str = typer.Option("se3", help="ATE alignment: se3 (Umeyama, no scale) | first | none"),
    save_poses: Optional[Path] = typer.Option(None,
                                              help="Write each run's poses as KITTI poses.txt: DIR/<seq>/<mask>.txt"),
) -> None:
    """KISS-ICP with raw, MOS-masked and ground-truth-masked scans; KITTI relative errors and ATE.

    mos: every scan is registered with all its points, then only its MOS-static points enter
    KISS-ICP's map (causal, as the node runs). gt: ground-truth movers removed before
    registration and from the map (oracle). gt-map: ground-truth movers kept only out of the map.
    """
    from tqdm import tqdm

    from ros2_mos.apps.kitti_metrics import SegmentErrors
    from ros2_mos.apps.odometry import evaluate_run, parse_masks, run_odometry
    from ros2_mos.cli.core_commands import load_config
    from ros2_mos.core.inference import MosModel
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_calib, sequence_dirs, write_poses

    masks = parse_masks(mask)
    lengths = _lengths(segments)
    cfg = load_config(params, model)
    mos_model = MosModel(cfg.model, intra_op_threads=cfg.intra_op_threads) if "mos" in masks else None
    if mos_model is not None:
        typer.echo(f"model {mos_model.path}: {mos_model.metadata.network}, {mos_model.metadata.input.label}, "
                   f"sensor {mos_model.metadata.sensor.name}")
    header = (f"{'sequence':>9} {'mask':>7} {'t_err %':>8} {'r_err deg/100m':>15} {'ATE m':>7} "
              f"{'segments':>8} {'path m':>7} {'masked %':>8} {'ms/scan':>8}")
    rows: list[str] = []
    pooled: dict[str, list[SegmentErrors]] = {m: [] for m in masks}
    for seq_dir in sequence_dirs(sequence_dir, sequences):
        seq = SemanticKittiSequence(seq_dir)
        for m in masks:
            if m.startswith("gt") and not seq.has_labels and mask == "all":
                typer.echo(f"{seq.name}: no labels/, skipping mask {m}", err=True)
                continue
            run = run_odometry(seq, m, cfg, mos_model,
                               progress=lambda it, m=m, seq=seq: tqdm(it, total=len(seq), desc=f"{seq.name} {m}",
                                                                      leave=False))
            err = evaluate_run(run, seq, lengths, alignment=alignment)
            pooled[m].append(err.segments)
            rows.append(f"{seq.name:>9} {m:>7} {_fmt(err.translation_pct):>8} {_fmt(err.rotation_deg_per_100m):>15} "
                        f"{_fmt(err.ate_rmse, 3):>7} {err.n_segments:>8} {err.path_length:>7.1f} "
                        f"{100 * run.masked_share:>8.1f} {float(run.milliseconds.mean()):>8.1f}")
            if save_poses is not None:
                calib = seq.root / "calib.txt"
                out = save_poses / seq.name / f"{m}.txt"
                out.parent.mkdir(parents=True, exist_ok=True)
                write_poses(out, run.poses, read_calib(calib) if calib.is_file() else None)
    typer.echo(f"segments {', '.join(f'{v:g}' for v in lengths)} m (every 10th frame); ATE after {alignment} alignment")
    typer.echo(header)
    for row in rows:
        typer.echo(row)
    if len({r.split()[0] for r in rows}) > 1:
        for m in masks:
            seg = SegmentErrors.concatenate(pooled[m])
            typer.echo(f"{'all':>9} {m:>7} {_fmt(seg.translation_pct):>8} {_fmt(seg.rotation_deg_per_100m):>15} "
                       f"{'':>7} {len(seg):>8}")


@app.command("map")
def map_command(
    sequence_dir: Path = typer.Argument(..., help="SemanticKITTI sequence folder (labels/ give the ghost share) or "
                                        "rosbag2 bag"),
    out: Path = typer.Option(..., "--out", help="map.ply or map.pcd: writes map_raw.<ext> and map_cleaned.<ext>"),
    png: Optional[Path] = typer.Option(None, "--png", help="Bird's-eye view of raw and cleaned map side by side"),
    model: Optional[Path] = typer.Option(None, help="ONNX model (default: the shipped model)"),
    params: Optional[Path] = PARAMS_OPTION,
    voxel_size: float = typer.Option(0.1, help="Map voxel size in m (one point kept per voxel)"),
    max_range: float = typer.Option(50.0, help="Scan points farther than this (m) stay out of the maps"),
    poses: str = typer.Option("estimated", help="estimated (the pipeline's KISS-ICP) | gt (the dataset's poses.txt)"),
    labels: Optional[Path] = typer.Option(None, "--labels", help="Clean with labels written before instead of the "
                                          "online model: the --out root of `ros2-mos autolabel` (or `infer`); "
                                          "estimated poses are then the poses.txt written beside them"),
    deskew: str = typer.Option("auto", help="Deskew each scan before it enters the maps (its motion from the poses "
                               "before and after it): on, off, or auto: as autolabel took the sweeps (the sweep.txt "
                               "beside --labels), else where the drive says skewed (a folder's sweep.txt, a bag's "
                               "per-point times)"),
    topic: Optional[str] = typer.Option(None, help="PointCloud2 topic of a bag (default: its only one)"),
) -> None:
    """Accumulate the scans into a raw and a MOS-cleaned voxel map; ghost share on labelled data."""
    from tqdm import tqdm

    from ros2_mos.apps.mapping import (
        MappingConfig,
        build_maps,
        build_maps_from_labels,
        ghost_share,
        has_ground_truth,
        map_paths,
        write_bev_png,
        write_map,
    )
    from ros2_mos.cli.core_commands import load_config
    from ros2_mos.core.deskew import DESKEW_MODES
    from ros2_mos.offline.drives import open_drive

    if out.suffix.lower() not in (".ply", ".pcd"):
        fail(f"--out must end in .ply or .pcd, got {out.name}")
    check_choice(deskew, DESKEW_MODES, "--deskew")
    for path in map_paths(out):
        check_output(path, "--out")
    if png is not None:
        check_output(png, "--png")
    drive = open_drive(sequence_dir, topic)
    mapping = MappingConfig(voxel_size=voxel_size, max_range=max_range, poses=poses, deskew=deskew)
    bar = lambda it: tqdm(it, total=len(drive), desc=f"map {drive.name}")  # noqa: E731
    if labels is not None:
        result = build_maps_from_labels(drive, labels, mapping, progress=bar)
    else:
        result = build_maps(drive, load_config(params, model), mapping, progress=bar)
    truth = has_ground_truth(drive)
    raw_path, clean_path = map_paths(out)
    write_map(raw_path, result.raw.points)
    write_map(clean_path, result.cleaned.points)
    typer.echo(f"{drive.name}: {len(drive)} scans{', deskewed' if result.deskewed else ''}, "
               f"{100 * result.moving_share:.1f} % of points labelled moving")
    typer.echo(f"{'map':>8} {'points':>10} {'ghost %':>8}  file")
    for name, vm, path in (("raw", result.raw, raw_path), ("cleaned", result.cleaned, clean_path)):
        typer.echo(f"{name:>8} {len(vm):>10} {_fmt(100 * ghost_share(vm), 3) if truth else '-':>8}  {path}")
    if truth:
        typer.echo("static voxels of the raw map kept in the cleaned map: "
                   f"{_fmt(100 * result.builder.static_kept(), 1)} %")
    if png is not None:
        cleaned = "autolabel-cleaned" if labels is not None else "MOS-cleaned"
        typer.echo(f"wrote {write_bev_png(png, {'raw': result.raw, cleaned: result.cleaned})}")
