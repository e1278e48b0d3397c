"""``demo``: the README's first command — simulate a held-out street, run mos_node on it, score it.

What a user does with a real robot, end to end: a LiDAR bag is replayed through a
running ``mos_node`` process (``ros2-mos replay`` here, ``ros2 bag play`` on a ROS
install), and the node's ``/mos/labels`` are compared with the ground truth.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Optional

import typer

from ros2_mos.cli.app import app, fail

DEMO_SEQUENCE = "demo"  # a name never used for training: the simulator seeds each sequence by its name
DEMO_SEED = 2026


def ensure_demo_data(root: Path, scans: int) -> tuple[Path, Path]:
    """The demo sequence and its bag under ``root``, simulated on first use."""
    from tqdm import tqdm

    from ros2_mos.sim import sequence_dir, simulate_sequence, write_sequence_bag

    seq = sequence_dir(root, DEMO_SEQUENCE)
    bag = root / "bags" / DEMO_SEQUENCE
    if not (seq / "times.txt").is_file() or len(list((seq / "velodyne").glob("*.bin"))) != scans:
        with tqdm(total=scans, desc="simulating the demo street", unit="scan") as bar:
            simulate_sequence(root, DEMO_SEQUENCE, scans, "benchmark", DEMO_SEED, "hdl64", progress=bar.update)
        if bag.exists():
            import shutil

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
    rate: float = typer.Option(1.0, help="Replay speed factor (1.0 = the sensor's 10 Hz; 0 = lock-step, as fast as the node goes)"),
) -> None:
    """Simulate a street, replay it as a bag through a running mos_node, print Hz, stage ms and moving IoU."""
    import numpy as np

    seq_dir, bag = ensure_demo_data(data, scans)
    domain = str(random.randint(100, 200))
    os.environ["ROS_DOMAIN_ID"] = domain
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    node_cmd = [str(Path(sys.executable).parent / "mos_node"), "--ros-args", "-p", "qos.reliability:=reliable",
                "-p", "qos.depth:=1"]
    if model is not None:
        node_cmd += ["-p", f"model:={model.resolve()}"]
    typer.echo(f"starting mos_node (ROS_DOMAIN_ID={domain}) and replaying {bag} at rate {rate}")
    node = subprocess.Popen(node_cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log: list[str] = []
    reader = threading.Thread(target=lambda: log.extend(node.stdout), daemon=True)  # type: ignore[arg-type]
    reader.start()
    try:
        labels, summary = _replay_and_listen(bag, rate)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
        reader.join(timeout=2)
    if node.returncode not in (0, -signal.SIGINT) and not labels:
        fail("mos_node failed:\n" + "".join(log[-20:]))
    typer.echo(summary)
    _print_score(seq_dir, labels, np)
    final = [line.strip() for line in log if "processed" in line]
    if final:
        typer.echo(f"mos_node: {final[-1]}")


def _replay_and_listen(bag: Path, rate: float) -> tuple[dict[int, Any], str]:
    """Replay the bag and collect each scan's published per-point moving labels, keyed by stamp."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from ros2_mos.datasets.bags import pointcloud_topic
    from ros2_mos.pointcloud2 import view_cloud
    from ros2_mos.ros.messages import MessageTypes
    from ros2_mos.ros.replayer import Replayer

    labels: dict[int, Any] = {}
    rclpy.init()
    replayer = None
    listener = None
    executor = SingleThreadedExecutor()
    spin = threading.Thread(target=executor.spin, daemon=True)
    try:
        types = MessageTypes.rclpy()
        listener = rclpy.create_node("mos_demo_listener")

        def on_labels(msg: Any) -> None:
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            labels[stamp] = view_cloud(msg).records["moving"].astype(bool)

        listener.create_subscription(types.point_cloud2, "/mos/labels", on_labels,
                                     QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        executor.add_node(listener)
        spin.start()
        topic = pointcloud_topic(bag, None)
        replayer = Replayer(topic, reliable=True, sync_topic="/mos/labels" if rate == 0 else None)
        if not replayer.wait_for_subscriber(30.0):
            raise RuntimeError("mos_node did not subscribe within 30 s")
        start = time.monotonic()
        sent = replayer.play(bag, topic, rate=rate)
        deadline = time.monotonic() + 10.0
        while len(labels) < sent and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.5)  # one more diagnostics period
        elapsed = time.monotonic() - start
        summary = (f"replayed {sent} clouds in {elapsed:.1f} s; mos_node published labels for {len(labels)} "
                   f"({len(labels) / elapsed:.1f} Hz)")
        if replayer.last_diagnostics:
            summary += f"\nmos_node diagnostics: {replayer.last_diagnostics}"
        return labels, summary
    finally:
        if replayer is not None:
            replayer.close()
        executor.shutdown()
        if listener is not None:
            listener.destroy_node()
        rclpy.try_shutdown()
        spin.join(timeout=2)


def _print_score(seq_dir: Path, labels: dict[int, Any], np: Any) -> None:
    """Moving IoU of the node's labels against the simulator's ground truth, scan by scan."""
    from ros2_mos.datasets.bags import iter_pointclouds
    from ros2_mos.datasets.semantic_kitti import SemanticKittiSequence, read_label
    from ros2_mos.labels import to_moving_classes
    from ros2_mos.metrics import MovingIoU

    seq = SemanticKittiSequence(seq_dir)
    bag = seq_dir.parents[1] / "bags" / seq_dir.name
    stamps = [stamp for stamp, _ in iter_pointclouds(bag)]
    score, matched = MovingIoU(), 0
    for index, stamp in enumerate(stamps):
        pred = labels.get(stamp)
        if pred is None:
            continue
        gt = to_moving_classes(read_label(seq.label_path(index)))
        if len(gt) != len(pred):  # the simulator never writes NaN points: every point comes back
            continue
        score.update(pred, gt)
        matched += 1
    iou = "n/a" if matched == 0 else f"{100 * score.iou:.1f}"
    typer.echo(f"moving IoU of mos_node's /mos/labels over {matched} scans: {iou} "
               f"(TP {score.tp}, FP {score.fp}, FN {score.fn})")
