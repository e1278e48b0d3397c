"""``autolabel``: offline moving / static labels of whole drives, from their past and their future."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import app, check_choice, check_output, fail


@app.command()
def autolabel(
    drives: list[Path] = typer.Argument(..., help="SemanticKITTI sequence folders (velodyne/*.bin) or rosbag2 bags"),
    out: Path = typer.Option(..., "--out", help="Output root: writes OUT/sequences/<drive>/predictions/*.label, "
                                                "poses.txt, objects.csv (the layout `infer` writes; `eval` scores it)"),
    convention: str = typer.Option("semantickitti", help="semantickitti: a mover is moving in every scan in which "
                                   "it is seen, also while it waits (SemanticKITTI's); instant: while it moves"),
    sensor: Optional[str] = typer.Option(None, help="Sensor preset (hdl64, vlp16, vlp32c, os1-64, os1-128; "
                                                    "default: told from the first scan's rings)"),
    topic: Optional[str] = typer.Option(None, help="PointCloud2 topic of a bag (default: its only one)"),
    use_poses: bool = typer.Option(False, "--use-poses", help="The drive's poses.txt instead of KISS-ICP"),
    png: bool = typer.Option(False, "--png", help="Also write movers.png: a bird's-eye picture, movers by track"),
    deskew: str = typer.Option("auto", help="Deskew each scan first (its motion from the poses around it, each "
                               "point at its firing time: a bag's per-point times, else its azimuth, the sweep from "
                               "behind, clockwise): on for sweeps no driver compensated (KITTI raw's), off for "
                               "compensated ones (SemanticKITTI's); auto: where a folder's sweep.txt says skewed (the "
                               "simulator writes it) or a bag's clouds carry per-point times, else off"),
) -> None:
    """Label every scan of whole drives moving (251) / static (9) using past AND future scans (offline)."""
    import time

    from tqdm import tqdm

    from ros2_mos.core.config import sensor_preset
    from ros2_mos.core.deskew import DESKEW_MODES
    from ros2_mos.core.sensor_check import closest_preset, cloud_shape
    from ros2_mos.io.conventions import CONVENTIONS
    from ros2_mos.offline.autolabel import AutolabelConfig, autolabel_drive, progress_steps
    from ros2_mos.offline.drives import open_drive

    check_choice(convention, CONVENTIONS, "--convention")
    check_choice(deskew, DESKEW_MODES, "--deskew")
    check_output(out, "--out", folder=True)
    opened = [open_drive(d, topic) for d in drives]
    names = [d.name for d in opened]
    if len(set(names)) != len(names):
        fail(f"drive names repeat: {' '.join(names)} (each becomes OUT/sequences/<name>)")
    for d in opened:
        if (out / "sequences" / d.name).exists():
            fail(f"{out / 'sequences' / d.name} already exists; remove it or choose another --out")
    config = AutolabelConfig(use_poses=use_poses, deskew=deskew)
    for drive in opened:
        if sensor is None:
            first = next(iter(drive))
            shape = cloud_shape(first.points)
            guess = closest_preset(shape) if shape is not None else None
            if guess is None:
                fail(f"{drive.name}: cannot tell the sensor from its first scan; give --sensor")
            spec = sensor_preset(guess)
        else:
            spec = sensor_preset(sensor)
        n = len(drive)
        start = time.perf_counter()
        with tqdm(total=progress_steps(n, config), desc=f"{drive.name} ({spec.name})", unit="step") as bar:
            def step(stage: str, done: int) -> None:
                bar.set_postfix_str(stage, refresh=False)
                bar.update(done)
            folder, result = autolabel_drive(drive, out, spec, convention, config, png, step)
        seconds = time.perf_counter() - start
        share = sum(result.moving_points) / max(sum(result.points), 1)
        cue = f"online cue {result.cue_model}" if result.cue_model else "no online cue"
        if result.cue_skipped:
            cue += f" ({result.cue_skipped} scans it refused went without)"
        backwards = result.odometry_followed == "b"
        poses = ", poses from KISS-ICP run backwards (forwards it fell behind)" if backwards else ""
        poses += ", scans deskewed" if result.deskewed else ""
        if deskew == "auto" and drive.skewed is None:  # a real folder says nothing: say what was taken
            poses += (", sweeps taken as compensated (nothing says they are skewed: --deskew on, or 'skewed' in "
                      "sweep.txt, where the driver did not compensate them)")
        typer.echo(f"wrote {folder}: {n} scans, {len(result.movers)} movers, {100 * share:.2f} % of points moving "
                   f"({convention}), {cue}{poses}, {n / seconds:.1f} scans/s")
