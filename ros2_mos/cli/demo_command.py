"""``demo``: the README's first command — simulate a held-out street, run mos_node on it, score it.

What a user does with a real robot, end to end: a LiDAR bag is replayed through a
running ``mos_node`` process (``ros2-mos replay`` here, ``ros2 bag play`` on a ROS
install), and the node's ``/mos/labels`` are compared with the ground truth.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any, Optional

import typer

from ros2_mos.cli.app import app, fail

DEMO_SEQUENCE = "demo"  # a name never used for training: the simulator seeds each sequence by its name
DEMO_SEED = 2026
#: Clouds sent in lock-step before the measured replay: the node's first scans pay for lazy initialisation.
DEMO_WARMUP = 5


def ensure_sequence(root: Path, name: str, scans: int, seed: int, preset: str = "benchmark",
                    sensor: str = "hdl64") -> tuple[Path, Path]:
    """A simulated sequence of ``sensor`` and its bag under ``root``, simulated on first use.

    Other sensors than the HDL-64E get their own folder (``NAME-SENSOR``)."""
    if sensor != "hdl64":
        name = f"{name}-{sensor}"
    from tqdm import tqdm

    from ros2_mos.sim import sequence_dir, simulate_sequence, write_sequence_bag

    seq = sequence_dir(root, name)
    bag = root / "bags" / name
    if not (seq / "times.txt").is_file() or len(list((seq / "velodyne").glob("*.bin"))) != scans:
        import shutil

        shutil.rmtree(seq, ignore_errors=True)  # another length before: no stale scans beyond this one's end
        with tqdm(total=scans, desc=f"simulating street '{name}'", unit="scan") as bar:
            simulate_sequence(root, name, scans, preset, seed, sensor, progress=bar.update)
        if bag.exists():
            shutil.rmtree(bag)
    if not bag.exists():
        bag.parent.mkdir(parents=True, exist_ok=True)
        write_sequence_bag(seq, bag)
    return seq, bag


@app.command()
def demo(
    data: Path = typer.Option(Path("data/demo"), help="Where the demo sequence and bag are (simulated if missing)"),
    scans: int = typer.Option(100, min=10, help="Scans in the demo sequence (10 Hz)"),
    model: Optional[Path] = typer.Option(None, help="ONNX model (default: the shipped one)"),
    rate: float = typer.Option(1.0, help="Replay speed factor (1.0 = the sensor's 10 Hz; "
                                         "0 = lock-step, as fast as the node goes)"),
    sensor: str = typer.Option("hdl64", help="Sensor preset to simulate and label (hdl64, vlp16, vlp32c, os1-64, "
                                             "os1-128); the node uses the model shipped for it"),
) -> None:
    """Simulate a street, replay it as a bag through a running mos_node, print Hz, stage ms and moving IoU."""
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.tools.harness import NodeProcess, isolate_ros_domain, replay_through_node

    sensor = sensor_preset(sensor).name  # a clear error for an unknown name, before any simulation
    seq_dir, bag = ensure_sequence(data, DEMO_SEQUENCE, scans, DEMO_SEED, sensor=sensor)
    domain = isolate_ros_domain()
    params = {"qos.reliability": "reliable", "qos.depth": "1", "sensor.preset": sensor}
    if model is not None:
        params["model"] = str(model.resolve())
    typer.echo(f"starting mos_node (ROS_DOMAIN_ID={domain}) and replaying {bag} at rate {rate}")
    with NodeProcess(params) as node:
        try:
            report = replay_through_node(bag, rate, restamp=True, warmup=DEMO_WARMUP)
        except RuntimeError as exc:
            node.stop()
            fail(f"{exc}\n" + "".join(node.log[-20:]))
    d = report.diagnostics
    typer.echo(f"replayed {report.sent} clouds ({report.input_s:.1f} s of input) after {report.warmup} warm-up clouds "
               f"in lock-step (not counted); mos_node published labels for {len(report.labels)} "
               f"({report.processed_per_input_s:.1f} per second of input time)")
    if d:
        typer.echo(f"mos_node: capacity {d.get('capacity_hz', '?')} Hz (mean {d.get('total_ms_mean', '?')} ms per "
                   f"scan); lost {d.get('dropped', '?')} in its one-scan queue while busy, "
                   f"~{d.get('lost_in_transport', '?')} on the way in (estimated from gaps in the stamps)")
    if report.latency_ms:
        typer.echo(f"latency stamp -> /mos/labels received: median {statistics.median(report.latency_ms):.0f} ms, "
                   f"max {max(report.latency_ms):.0f} ms")
    typer.echo(score_line(seq_dir, report.labels))
    if node.final_statistics():
        typer.echo(f"mos_node: {node.final_statistics()}")


def score_line(seq_dir: Path, labels: dict[int, Any]) -> str:
    """Moving IoU of the node's labels (by scan index) against the simulator's ground truth."""
    from ros2_mos.io.labels import to_moving_classes
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
    from ros2_mos.scoring.metrics import MovingIoU

    seq = SemanticKittiSequence(seq_dir)
    score, matched = MovingIoU(), 0
    for index, pred in sorted(labels.items()):
        gt = to_moving_classes(read_label(seq.label_path(index)))
        if len(gt) != len(pred):  # the simulator never writes NaN points: every point comes back
            continue
        score.update(pred, gt)
        matched += 1
    iou = "n/a" if matched == 0 else f"{100 * score.iou:.1f}"
    return (f"moving IoU of mos_node's /mos/labels over {matched} scans: {iou} "
            f"(TP {score.tp}, FP {score.fp}, FN {score.fn})")
