"""Timing the pipeline stage by stage, the way the node runs it (no ROS needed).

Each scan goes through :class:`~ros2_mos.ros.processor.ScanProcessor` with rosbags
message types: PointCloud2 decode, validation, odometry, projection, residuals,
CNN, back-projection, map update and message encode are exactly the node's code.
Every configuration runs in a fresh process so that its peak RSS is its own.
"""

from __future__ import annotations

import multiprocessing
import resource
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

STAGES = ("decode", "validate", "odometry", "projection", "registration", "residuals", "inference", "temporal",
          "postprocess", "mover_memory",
          "map_update", "encode")


@dataclass
class BenchResult:
    """Per-stage median / p95 in ms, end-to-end latency, rate and peak RSS of one configuration."""

    label: str
    scans: int
    stage_ms: dict[str, tuple[float, float]] = field(default_factory=dict)
    total_ms: tuple[float, float] = (0.0, 0.0)
    peak_rss_mb: float = 0.0
    notes: str = ""

    @property
    def hz(self) -> float:
        """Scans per second at the median end-to-end time (one scan at a time)."""
        return 1000.0 / self.total_ms[0] if self.total_ms[0] > 0 else 0.0


def summarise(label: str, timings: list[dict[str, float]], notes: str = "") -> BenchResult:
    """Median and p95 of each stage over the measured scans."""
    result = BenchResult(label, len(timings), notes=notes)
    for stage in [s for s in timings[0] if s != "total"]:
        values = np.array([t.get(stage, 0.0) for t in timings])
        result.stage_ms[stage] = (float(np.median(values)), float(np.percentile(values, 95)))
    totals = np.array([t["total"] for t in timings])
    result.total_ms = (float(np.median(totals)), float(np.percentile(totals, 95)))
    result.peak_rss_mb = peak_rss_mb()
    return result


def peak_rss_mb() -> float:
    """This process's peak resident size (MB).

    From ``VmHWM``, the high-water mark of the current address space: ``ru_maxrss`` survives
    ``exec`` on Linux, so a worker spawned by a big parent would report the parent's peak.
    """
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _bench_pipeline(bag: str, model: str | None, scans: int, warmup: int, threads: int,
                    geometry: str = "numpy", sensor: str | None = None, params: str | None = None) -> BenchResult:
    from ros2_mos.core import kernels
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.bags import iter_pointclouds
    from ros2_mos.ros.messages import MessageTypes
    from ros2_mos.ros.params import load_params, mos_config, node_settings
    from ros2_mos.ros.processor import ScanProcessor

    values = load_params(params, model, sensor)
    values["intra_op_threads"] = threads
    values["geometry_backend"] = geometry
    pipeline = MosPipeline(mos_config(values))
    processor = ScanProcessor(pipeline, node_settings(values), MessageTypes.rosbags())
    timings: list[dict[str, float]] = []
    for i, (_, msg) in enumerate(iter_pointclouds(bag)):
        if i >= scans + warmup:
            break
        out = processor.process(msg)
        if i >= warmup:
            timings.append(out.timings)
    if not timings:
        raise ValueError(f"{bag}: fewer than {warmup + 1} clouds")
    meta = pipeline.model.metadata
    label = f"{meta.network} {meta.input.label} ({Path(pipeline.model.path).name})"
    notes = (f"{pipeline.sensor.height}x{pipeline.sensor.width}, {pipeline.model.provider}, ORT threads "
             f"{threads or 'default'}, geometry {geometry}"
             + (f", {kernels.status()}" if geometry == "numpy" else ""))
    return summarise(label, timings, notes)


def bench_pipeline(bag: Path, model: Path | None, scans: int = 50, warmup: int = 5, threads: int = 0,
                   geometry: str = "numpy", sensor: str | None = None, params: Path | None = None) -> BenchResult:
    """Time the node's pipeline over the bag's first clouds, in a fresh process."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(_bench_pipeline, str(bag), None if model is None else str(model), scans, warmup,
                           threads, geometry, sensor, None if params is None else str(params)).result()


def format_table(results: list[BenchResult]) -> str:
    """A Markdown table: one column per configuration, one row per stage."""
    if not results:
        return ""
    stages = [s for s in STAGES if any(s in r.stage_ms for r in results)]
    head = "| stage (ms, median / p95) | " + " | ".join(r.label for r in results) + " |"
    rows = [head, "|---" * (len(results) + 1) + "|"]
    for s in stages:
        cells = [f"{r.stage_ms[s][0]:.1f} / {r.stage_ms[s][1]:.1f}" if s in r.stage_ms else "–" for r in results]
        rows.append(f"| {s} | " + " | ".join(cells) + " |")
    rows.append(
        "| **end to end** | " + " | ".join(f"**{r.total_ms[0]:.1f} / {r.total_ms[1]:.1f}**" for r in results) + " |"
    )
    rows.append("| rate (Hz, at the median) | " + " | ".join(f"{r.hz:.1f}" for r in results) + " |")
    rows.append("| peak RSS (MB) | " + " | ".join(f"{r.peak_rss_mb:.0f}" for r in results) + " |")
    rows.append("| scans timed | " + " | ".join(str(r.scans) for r in results) + " |")
    rows.append("| setup | " + " | ".join(r.notes for r in results) + " |")
    return "\n".join(rows)
