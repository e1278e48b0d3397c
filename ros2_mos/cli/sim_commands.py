"""``simulate``: labelled SemanticKITTI sequences (and rosbag2 bags) from the street simulator."""

from __future__ import annotations

from pathlib import Path

import typer

from ros2_mos.cli.app import app, check_choice, fail


@app.command(context_settings={"allow_extra_args": True})
def simulate(
    ctx: typer.Context,
    out_dir: Path = typer.Argument(..., help="Dataset root: writes OUT_DIR/sequences/XX/..."),
    sequences: list[str] = typer.Option(["00"], "--sequences", "-s",
                                        help="Sequence names: --sequences 00 01 02 (or repeated, or '00,01')"),
    scans: int = typer.Option(100, "--scans", "-n", min=1, help="Scans per sequence (10 Hz)"),
    preset: str = typer.Option("benchmark", help="Simulation preset: easy, benchmark, traffic_jam, narrow_street, "
                                                 "slow_traffic"),
    seed: int = typer.Option(0, min=0, help="Random seed; the same seed gives the same sequences"),
    sensor: str = typer.Option("hdl64", help="Sensor preset: hdl64, vlp16, vlp32c, os1-64, os1-128"),
    intra_sweep_motion: bool = typer.Option(False, "--intra-sweep-motion/--no-intra-sweep-motion",
                                            help="Cast each column from the ego pose at its firing time "
                                                 "(skewed scans)"),
    bag: bool = typer.Option(False, "--bag/--no-bag", help="Also write OUT_DIR/bags/XX (rosbag2, PointCloud2)"),
    bag_storage: str = typer.Option("mcap", help="Bag storage: mcap or sqlite3"),
    topic: str = typer.Option("/points", help="PointCloud2 topic in the bag"),
    frame_id: str = typer.Option("velodyne", help="frame_id of the clouds in the bag"),
    stats: bool = typer.Option(False, "--stats",
                               help="Print statistics: points/scan, moving fraction, objects, speeds"),
    convention: str = typer.Option("semantickitti", help="Label convention of labels/: semantickitti (an object "
                                   "that moves while in range is moving in every scan, also while it waits: "
                                   "SemanticKITTI's) or instant (moving while it moves); the other goes to "
                                   "labels_<other>/"),
    randomize: bool = typer.Option(False, "--randomize/--no-randomize",
                                   help="Draw each sequence's sensor noise, dropout, skew and mounting at random "
                                        "(training data; seeded by --seed and the sequence name)"),
) -> None:
    """Simulate a rotating LiDAR driving through traffic; write SemanticKITTI sequences with MOS labels."""
    from tqdm import tqdm

    from ros2_mos.core.config import sensor_preset
    from ros2_mos.io.conventions import CONVENTIONS
    from ros2_mos.sim import format_stats, sequence_dir, sim_preset, simulate_sequence, with_effects, write_sequence_bag
    from ros2_mos.sim.presets import randomized_for_sequence

    # `--sequences 00 01`: click takes one value per option, the rest arrive as extra arguments.
    extra = list(ctx.args)
    bad = [a for a in extra if a.startswith("-")]
    if bad:
        fail(f"unexpected arguments: {' '.join(bad)}")
    names = [n for item in [*sequences, *extra] for n in item.replace(",", " ").split()]
    check_choice(convention, CONVENTIONS, "--convention")
    if len(set(names)) != len(names):
        fail(f"sequence names repeat: {' '.join(names)}")
    if not names:
        fail("no sequence names given")
    if bag and (out_dir / "bags").exists():
        clash = [n for n in names if (out_dir / "bags" / n).exists()]
        if clash:
            fail("bag folders already exist (remove them first): "
                 f"{', '.join(str(out_dir / 'bags' / n) for n in clash)}")
    sim = sim_preset(preset)
    if intra_sweep_motion:
        sim = with_effects(sim, intra_sweep_motion=True)
    sensor_cfg = sensor_preset(sensor)
    results = []
    for name in names:
        preset_used = randomized_for_sequence(sim, seed, name) if randomize else sim
        with tqdm(total=scans, desc=f"sequence {name}", unit="scan") as bar:
            results.append(simulate_sequence(out_dir, name, scans, preset_used, seed, sensor_cfg, progress=bar.update,
                                               convention=convention))
        if bag:
            bag_path = out_dir / "bags" / name
            bag_path.parent.mkdir(parents=True, exist_ok=True)
            count = write_sequence_bag(sequence_dir(out_dir, name), bag_path, topic, frame_id, bag_storage)
            typer.echo(f"wrote {bag_path} ({count} PointCloud2 messages on {topic}, {bag_storage})")
    for r in results:
        typer.echo(f"wrote {sequence_dir(out_dir, r.name)}: {r.n_scans} scans, "
                   f"{r.n_scans / max(r.seconds, 1e-9):.1f} scans/s, {100 * r.moving_fraction:.2f} % moving points "
                   f"(instant), labels/ in the {convention} convention")
    if stats:
        typer.echo(format_stats(results))
