"""``replay`` and ``process``: bags through the node, and the node's processing offline.

``replay`` needs rclpy (the PyPI wheels suffice) but no ROS install: it stands
in for ``ros2 bag play`` for PointCloud2 topics. ``process`` needs neither: it
runs :class:`~ros2_mos.ros.processor.ScanProcessor`, the node's own code, over a
bag with rosbags message types and writes the node's topics to a new bag.
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import statistics
import time
from pathlib import Path
from typing import Any, Optional

import typer

from ros2_mos.cli.app import PARAMS_OPTION, app, fail
from ros2_mos.cli.core_commands import SENSOR_HELP


@app.command()
def process(
    bag_in: Path = typer.Argument(..., help="Input rosbag2 folder (mcap or sqlite3) with PointCloud2 scans"),
    bag_out: Path = typer.Argument(..., help="Output rosbag2 folder to create"),
    topic: Optional[str] = typer.Option(None, help="PointCloud2 topic (default: the bag's only one)"),
    params: Optional[Path] = PARAMS_OPTION,
    model: Optional[Path] = typer.Option(None, help="ONNX model (overrides the params file)"),
    storage: str = typer.Option("mcap", help="Output storage: mcap or sqlite3"),
    copy_input: bool = typer.Option(True, help="Also write the input clouds, so the bag is self-contained"),
    sensor: Optional[str] = typer.Option(None, help=SENSOR_HELP),
) -> None:
    """Run the node's pipeline offline over a bag; write static/moving/labels/images/odometry (and /tf)."""
    from ros2_mos.core.errors import OutputError
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.bags import BagWriter, pointcloud_topic
    from ros2_mos.ros.messages import MessageTypes
    from ros2_mos.ros.params import load_params, mos_config, node_settings
    from ros2_mos.ros.processor import ScanProcessor

    values = load_params(params, model, sensor)
    settings = node_settings(values)
    processor = ScanProcessor(MosPipeline(mos_config(values)), settings, MessageTypes.rosbags())
    in_topic = pointcloud_topic(bag_in, topic)
    topics = {**settings.topics, "tf": "/tf"}
    totals: list[float] = []
    if bag_out.exists():
        fail(f"bag output {bag_out} already exists; remove it or choose another path")
    # Written beside the target and renamed at the end: an interrupted, failed or empty run leaves no
    # half-written bag behind (and a rerun is not refused because of one).
    partial = bag_out.with_name(f".{bag_out.name}.partial-{os.getpid()}")
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with BagWriter(partial, storage=storage) as bag:
            done, skipped, moving, points = _process_into(bag, processor, bag_in, in_topic, topics, copy_input, totals)
        if done == 0:
            fail(f"no scan of {in_topic} could be processed ({skipped} skipped); no bag written")
        try:
            partial.rename(bag_out)
        except OSError as exc:
            fail(f"cannot write {bag_out}: {exc.strerror or exc}; nothing was written")
    except OutputError as exc:  # named after the bag, not the partial folder it was written in
        fail(f"cannot write {bag_out}: {exc.reason}; the partial output was removed")
    except KeyboardInterrupt:
        fail(f"interrupted: the partial output was removed, nothing was written to {bag_out}", 130)
    finally:
        signal.signal(signal.SIGTERM, previous)
        shutil.rmtree(partial, ignore_errors=True)
    typer.echo(f"{done} scans processed, {skipped} skipped; median {statistics.median(totals):.1f} ms/scan; "
               f"{100.0 * moving / max(points, 1):.1f}% of points moving; wrote {bag_out}")


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def _process_into(bag: Any, processor: Any, bag_in: Path, in_topic: str, topics: dict[str, str], copy_input: bool,
                  totals: list[float]) -> tuple[int, int, int, int]:
    """Label every cloud of ``in_topic`` into ``bag``; (processed, skipped, moving points, points)."""
    from tqdm import tqdm

    from ros2_mos.core.errors import ScanError
    from ros2_mos.io.bags import iter_pointclouds

    done = skipped = moving = points = 0
    problem = ""
    for stamp, msg in tqdm(iter_pointclouds(bag_in, in_topic), desc="process", unit="scan"):
        if copy_input:
            bag.write(in_topic, stamp, msg)
        try:
            out = processor.process(msg)
        except ScanError as exc:
            skipped += 1
            tqdm.write(f"warning: scan at {stamp * 1e-9:.3f} s skipped: {exc}")
            continue
        finally:
            if processor.stream_problem and processor.stream_problem != problem:  # once, as the node logs it
                tqdm.write(f"warning: {processor.stream_problem}")
            problem = processor.stream_problem
        if out.result.sensor_mismatch:  # every label would be wrong: stop before writing any
            fail(f"{bag_in} {in_topic}, scan at {stamp * 1e-9:.3f} s: {out.result.sensor_mismatch}")
        for note in out.notes:
            tqdm.write(f"warning: {note}")
        for key, message in out.messages.items():
            bag.write(topics[key], stamp, message)
        done += 1
        moving += out.n_moving
        points += len(out.valid_index)
        totals.append(out.timings["total"])
    return done, skipped, moving, points


@app.command()
def replay(
    bag: Path = typer.Argument(..., help="rosbag2 folder (mcap or sqlite3)"),
    topic: Optional[str] = typer.Option(None, help="PointCloud2 topic in the bag (default: its only one)"),
    publish_topic: Optional[str] = typer.Option(None, help="Publish on this topic (default: the bag's topic)"),
    rate: float = typer.Option(1.0, help="Speed factor over the recorded timing; 0 = as fast as possible"),
    loop: bool = typer.Option(False, help="Start over at the end (stamps go back: the node resets its buffer)"),
    reliable: bool = typer.Option(True, help="Reliable QoS (needed for large clouds across processes)"),
    wait: float = typer.Option(10.0, help="Seconds to wait for a subscriber before publishing"),
    sync: Optional[str] = typer.Option(None, help="Lock-step: after each cloud wait for a message on this "
                                       "topic (e.g. /mos/labels), so clouds go as fast as the node consumes them"),
    sync_timeout: float = typer.Option(5.0, help="Seconds to wait for the --sync topic per cloud"),
    max_messages: int = typer.Option(0, help="Stop after this many clouds (0 = all)"),
) -> None:
    """Publish a bag's PointCloud2 messages with rclpy at the recorded rate (stands in for `ros2 bag play`)."""
    from ros2_mos.io.bags import pointcloud_topic

    for option, value in (("--rate", rate), ("--wait", wait), ("--sync-timeout", sync_timeout)):
        if not (math.isfinite(value) and value >= 0):  # NaN fails every comparison: `< 0` let it through
            fail(f"{option} must be a finite number >= 0, got {value}")
    in_topic = pointcloud_topic(bag, topic)
    import rclpy

    from ros2_mos.ros.replayer import Replayer

    rclpy.init()
    replayer: Replayer | None = None
    try:
        replayer = Replayer(publish_topic or in_topic, reliable=reliable, sync_topic=sync)
        if not replayer.wait_for_subscriber(wait):
            fail(f"no subscriber on {replayer.topic} after {wait:.0f} s (is mos_node running, same ROS_DOMAIN_ID?)")
        t0 = time.monotonic()
        sent = replayer.play(bag, in_topic, rate=rate, loop=loop, sync_timeout=sync_timeout,
                             max_messages=max_messages)
        elapsed = time.monotonic() - t0
        typer.echo(f"published {sent} clouds on {replayer.topic} in {elapsed:.1f} s "
                   f"({sent / elapsed if elapsed > 0 else 0.0:.1f} Hz)"
                   + (f"; {replayer.synced} outputs received on {sync}" if sync else ""))
        if replayer.last_diagnostics:
            typer.echo(f"node: {replayer.last_diagnostics}")
    except KeyboardInterrupt:
        pass
    finally:
        if replayer is not None:
            replayer.close()
        rclpy.try_shutdown()


@app.command()
def params(
    markdown: bool = typer.Option(False, "--markdown",
                                  help="The parameter table in Markdown (docs/parameters.md), not the params file"),
) -> None:
    """Print the node's params file with every parameter at its default (config/mos.yaml), or its table."""
    from ros2_mos.ros.params import describe, params_file_text

    typer.echo(describe() if markdown else params_file_text(), nl=markdown)
