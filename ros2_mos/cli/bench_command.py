"""``bench``: where the time goes, per stage, for each shipped model, against a LiDAR-MOS-style reference."""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path
from typing import Optional

import typer

from ros2_mos.cli.app import PARAMS_OPTION, app

BENCH_SEQUENCE = "bench"
BENCH_SEED = 7


@app.command()
def bench(
    data: Path = typer.Option(Path("data/bench"),
                              help="Where the benchmark sequence and bag are (simulated if missing)"),
    scans: int = typer.Option(50, min=5, help="Scans timed per configuration (after 5 warm-up scans)"),
    model: Optional[list[Path]] = typer.Option(None, help="ONNX models to time (default: the model shipped for "
                                                          "--sensor)"),
    sensor: str = typer.Option("hdl64", help="Sensor preset whose simulated drive is timed (hdl64, vlp16, vlp32c, "
                                             "os1-64, os1-128)"),
    threads: int = typer.Option(0, help="ONNX Runtime intra-op threads (0 = runtime default)"),
    geometry: str = typer.Option("numpy",
                                 help="Residuals + kNN backend: numpy, or torch (GPU path, CUDA when present)"),
    reference: bool = typer.Option(True, help="Also time the LiDAR-MOS-style reference "
                                              "(numpy residuals, SalsaNext N=8 eager)"),
    reference_scans: int = typer.Option(5, min=1, help="Scans timed for the (slow) reference"),
    node: bool = typer.Option(True, help="Also run mos_node as a process with the bag replayed at 10 Hz and 20 Hz"),
    node_model: Optional[Path] = typer.Option(None, help="Model for the node runs (default: the shipped default)"),
    untrained: Optional[list[str]] = typer.Option(
        None, help="Also time NETWORK:N (e.g. salsanext:8) exported with random weights: speed does not depend "
                   "on the weights, so this times networks nobody trained here (needs torch)"),
    out: Optional[Path] = typer.Option(None, help="Also write the report (Markdown) to this file"),
    params: Optional[Path] = PARAMS_OPTION,
) -> None:
    """Median / p95 ms per stage, end-to-end latency, Hz and peak RSS; reference ratio; the node under replay."""
    from ros2_mos.cli.demo_command import ensure_sequence
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.core.inference import default_model_path
    from ros2_mos.tools.bench import bench_pipeline, format_table

    spec = sensor_preset(sensor)
    if params is not None:
        from ros2_mos.cli.core_commands import load_config

        load_config(params, None, spec.name)  # a bad file: one line here, not a traceback from the timing process
    seq_dir, bag = ensure_sequence(data, BENCH_SEQUENCE, scans + 5, BENCH_SEED, sensor=spec.name)
    models = list(model) if model else [default_model_path(spec.name)]
    if untrained:
        models += [_export_untrained(spec, data / "untrained") for spec in untrained]
    lines = [f"# ros2-mos bench, {datetime.date.today().isoformat()}",
             f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average "
             f"{os.getloadavg()[0]:.1f}; {scans} scans of {seq_dir} "
             f"({spec.height} x {spec.width} {spec.name}, simulated)",
             ""]
    results = []
    for m in models:
        typer.echo(f"timing {m.name} ...")
        results.append(bench_pipeline(bag, m, scans, threads=threads, geometry=geometry, sensor=spec.name,
                                      params=params))
    if reference and spec.name == "hdl64":
        typer.echo("timing the LiDAR-MOS-style reference (SalsaNext N=8, PyTorch eager) ...")
        results.append(_bench_reference(seq_dir, reference_scans))
    lines += ["## Pipeline, one scan at a time (the node's code, no DDS)", "", format_table(results), ""]
    ours = [r for r in results if not r.label.startswith("reference")]
    ref = [r for r in results if r.label.startswith("reference")]
    if ours and ref:
        for r in ours:
            lines.append(f"- speed-up of {r.label} over the reference: {ref[0].total_ms[0] / r.total_ms[0]:.1f}x "
                         "(median end-to-end; the reference excludes decode/encode/odometry)")
        lines.append("")
    typer.echo("\n".join(lines))
    if node:
        node_lines = _bench_node(bag, node_model, spec.name)
        typer.echo("\n".join(node_lines))
        lines += node_lines
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        from ros2_mos.core.atomic import write_text_atomically

        write_text_atomically(out, "\n".join(lines) + "\n")
        typer.echo(f"wrote {out}")


def _export_untrained(spec: str, folder: Path) -> Path:
    """An ONNX file of NETWORK with N residual images and random weights, for timing only."""
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.core.metadata import ModelMetadata
    from ros2_mos.core.network_input import InputSetup
    from ros2_mos.training.export import export_onnx
    from ros2_mos.training.nets import build_network, network_names

    name, _, n = spec.partition(":")
    if name not in network_names() or not n.isdigit():
        raise typer.BadParameter(f"{spec!r}: expected NETWORK:N with NETWORK one of {', '.join(network_names())}")
    setup = InputSetup("residual", int(n))
    meta = ModelMetadata(network=name, input=setup, sensor=sensor_preset("hdl64"),
                         trained_on="untrained (random weights): timing only")
    path = folder / f"{name}-residual{n}-untrained.onnx"
    if not path.is_file():
        typer.echo(f"exporting an untrained {name} {setup.label} to {path} ...")
        export_onnx(build_network(name, setup.channels), meta, path)
    return path


def _bench_reference(seq_dir: Path, scans: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(_reference_worker, str(seq_dir), scans).result()


def _reference_worker(seq_dir: str, scans: int):
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence
    from ros2_mos.tools.bench import summarise
    from ros2_mos.training.reference import ReferencePipeline

    seq = SemanticKittiSequence(seq_dir)
    pipe = ReferencePipeline(sensor_preset("hdl64"), n_past=8, threads=os.cpu_count() or 2)
    timings = []
    for i in range(min(len(seq), scans + 8)):
        frame = seq[i]
        _, t = pipe.process(frame.points, frame.remission, frame.pose)
        if i >= 8:  # all 8 residuals present
            timings.append(t)
    return summarise("reference: SalsaNext N=8 eager + numpy residuals", timings,
                     "LiDAR-MOS code path on this CPU, dataset poses")


def _bench_node(bag: Path, model: Optional[Path], sensor: str = "hdl64") -> list[str]:
    import numpy as np

    from ros2_mos.tools.harness import NodeProcess, isolate_ros_domain, replay_through_node

    isolate_ros_domain()
    lines = ["## mos_node as a process, the bag replayed by `ros2-mos replay` (stamps = publication time)", "",
             "| replay rate | published | labels received (per s of input) | node dropped (queue) | "
             "node lost on the way in | node capacity (Hz) | node processing mean (ms) | "
             "node receive -> publish mean (ms) | latency stamp -> /mos/labels median / p95 (ms) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for hz, rate in ((10, 1.0), (20, 2.0)):
        params = {"qos.reliability": "reliable", "qos.depth": "1", "sensor.preset": sensor}
        if model is not None:
            params["model"] = str(model.resolve())
        typer.echo(f"node run at {hz} Hz ...")
        with NodeProcess(params):
            report = replay_through_node(bag, rate, restamp=True, warmup=5)
        lat = np.array(report.latency_ms) if report.latency_ms else np.zeros(1)
        d = report.diagnostics
        lines.append(f"| {hz} Hz | {report.sent} | {len(report.labels)} ({report.processed_per_input_s:.1f}) | "
                     f"{d.get('dropped', '?')} | {d.get('lost_in_transport', '?')} | {d.get('capacity_hz', '?')} | "
                     f"{d.get('total_ms_mean', '?')} | {d.get('latency_ms_mean', '?')} | "
                     f"{np.median(lat):.0f} / {np.percentile(lat, 95):.0f} |")
    return lines + [
        "",
        "5 warm-up clouds go first in lock-step (not counted; the node's counters include them). "
        "The node shares the 2 cores with the replayer and the listener (one process, which also decodes every "
        "cloud it sends and receives); it builds only what is subscribed (here /mos/labels and odometry). "
        "Stamp -> /mos/labels = transport to the node + waiting for the worker + processing + transport back.",
        "",
    ]
