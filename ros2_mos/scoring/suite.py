"""The fixed evaluation suite: one table that says how good a model is, beside the heuristics.

Rows
----
* **Simulated, held out**: the presets easy, benchmark, traffic_jam and narrow_street, each with the
  seeds in :data:`SIM_SEEDS` (slow_traffic is a training preset, not scored here); no
  training recipe of this project uses them (training data is simulated with seed 100,
  the demo with its own).  The sequences are
  simulated on first use into the suite's data folder and reused afterwards.  Every
  scan is scored, with KISS-ICP poses (the node's odometry), as the node would label
  them.
* **Real**: the KITTI seq-08 development scans of ``../shared/real`` (unpacked with its
  ``unpack.sh``), scored as *agreement* IoU with another model's predictions after
  :data:`REAL_WARMUP` warm-up scans (no history before them).  Skipped, with a line
  saying so, where they are absent.

One table per label convention (:mod:`ros2_mos.io.conventions`): the simulated rows under SemanticKITTI's and
under the instant one, the real rows under SemanticKITTI's (the reference's).

Columns: moving IoU, precision, recall, false-positive points per scan, the largest
share of a scan's points labelled moving, and the **Residual** and **Residual + RG**
baselines (:mod:`ros2_mos.scoring.baselines`) run on the very same scans with the same
poses and the same kNN back-projection.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.core.postprocess import backproject
from ros2_mos.core.projection import finite_mask, project
from ros2_mos.core.residuals import residual_images
from ros2_mos.io.conventions import CONVENTIONS, label_dirs
from ros2_mos.io.labels import to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
from ros2_mos.io.sweep import read_sweep_file
from ros2_mos.scoring.baselines import (
    RegionGrowingParams,
    region_growing,
    residual_threshold,
)
from ros2_mos.scoring.breakdown import ErrorBreakdown
from ros2_mos.scoring.metrics import MovingIoU

#: Held-out simulation seeds per preset (never used for training data).
SIM_SEEDS: dict[str, tuple[int, ...]] = {
    "easy": (9301, 9302),
    "benchmark": (9101, 9102),
    "traffic_jam": (9201, 9202),
    "narrow_street": (9501, 9502),
}
#: Residual baseline threshold, tuned on the simulator's validation sequence (benchmarks/ablation.md).
RESIDUAL_TAU = 0.05
#: Real scans scored after this many scans of history.
REAL_WARMUP = 8


@dataclass
class RowScore:
    """One row of the suite: the model's counts and the baselines' on the same scans."""

    name: str
    scans: int = 0
    model: MovingIoU = field(default_factory=MovingIoU)
    residual: MovingIoU = field(default_factory=MovingIoU)
    region_growing: MovingIoU = field(default_factory=MovingIoU)
    max_moving_fraction: float = 0.0
    seconds: float = 0.0

    def add(self, other: "RowScore") -> None:
        self.scans += other.scans
        self.model = self.model + other.model
        self.residual = self.residual + other.residual
        self.region_growing = self.region_growing + other.region_growing
        self.max_moving_fraction = max(self.max_moving_fraction, other.max_moving_fraction)
        self.seconds += other.seconds


def _precision(s: MovingIoU) -> float:
    return s.tp / (s.tp + s.fp) if s.tp + s.fp else float("nan")


def _recall(s: MovingIoU) -> float:
    return s.tp / (s.tp + s.fn) if s.tp + s.fn else float("nan")


def score_sequence(pipeline: MosPipeline, sequence: SemanticKittiSequence, name: str, warmup: int = 0,
                   rg_params: RegionGrowingParams = RegionGrowingParams(),
                   progress: Callable[[], None] | None = None,
                   breakdown: ErrorBreakdown | None = None) -> dict[str, RowScore]:
    """Run the pipeline (KISS-ICP poses) over a labelled sequence; score scans from ``warmup`` on.

    Returns one row per label convention the sequence has (:mod:`ros2_mos.io.conventions`), main one first: the
    same labels of the model and the baselines scored against each. With ``breakdown`` the model's labels of every
    scored scan are also added to it (against the main convention), under the sequence's name.
    """
    if not sequence.has_labels:
        raise DatasetError(f"{sequence.root}: no labels/ to score against")
    folders = label_dirs(sequence.root)
    rows = {convention: RowScore(name) for convention in folders}
    sensor, post = pipeline.sensor, pipeline.config.postprocess
    pipeline.reset()
    start = time.perf_counter()
    for frame in sequence:
        past = [(s.points, s.pose) for s in pipeline.buffer.newest_first()]
        result = pipeline.process(frame.points, frame.remission, frame.timestamp)
        if progress is not None:
            progress()
        if frame.index < warmup:
            continue
        stem = sequence.scan_files[frame.index].stem
        gts = {convention: to_moving_classes(frame.labels if folder.name == "labels"
                                             else read_label(folder / f"{stem}.label", len(frame.points)))
               for convention, folder in folders.items()}
        if breakdown is not None:
            breakdown.update(sequence.name, frame.points, frame.labels, result.labels, frame.pose, frame.timestamp)
        # The baselines on the same scan, poses and back-projection.
        valid = finite_mask(frame.points)
        xyz = np.ascontiguousarray(frame.points[valid], np.float32)
        image = project(xyz, np.zeros(len(xyz), np.float32), sensor)
        signed = residual_images(image.range, result.pose, past, 2, sensor, pipeline.config.residuals, signed=True)
        z_image = np.where(image.mask, image.xyz[..., 2], 0.0)
        baselines = []
        for mask in (residual_threshold(signed[0], RESIDUAL_TAU), region_growing(image.range, z_image, signed,
                                                                                   rg_params)):
            moving = np.zeros(len(frame.points), bool)
            moving[valid] = backproject(mask.astype(np.float32), image.range, image.pixels, post, 0.5) >= 0.5
            baselines.append(moving)
        for convention, row in rows.items():
            gt = gts[convention]
            row.scans += 1
            row.model.update(result.labels, gt)
            row.max_moving_fraction = max(row.max_moving_fraction, float(result.labels[result.valid].mean()))
            row.residual.update(baselines[0], gt)
            row.region_growing.update(baselines[1], gt)
    seconds = time.perf_counter() - start
    for row in rows.values():
        row.seconds = seconds
    return rows


def ensure_sim_sequences(root: Path, scans: int, seeds: dict[str, tuple[int, ...]] = SIM_SEEDS,
                         log: Callable[[str], None] = lambda s: None,
                         sensor: str = "hdl64", skewed: bool = False) -> list[tuple[str, str, Path]]:
    """(preset, row name, sequence folder) of the suite's simulated sequences, simulating missing ones (``skewed``:
    each column cast from the pose of its firing time, ``--intra-sweep-motion``). A folder there already whose
    ``sweep.txt`` says otherwise (none: not skewed) is refused: keep skewed drives in a root of their own. One that
    another version of the simulator wrote, or that was not written to its end (its ``simulator.txt``:
    :func:`~ros2_mos.sim.writer.made_by_this_simulator`), is simulated anew: its figures would be another drive's."""
    import shutil

    from ros2_mos.sim import sim_preset, simulate_sequence, with_effects
    from ros2_mos.sim.writer import made_by_this_simulator

    out = []
    for preset, preset_seeds in seeds.items():
        for seed in preset_seeds:
            name = f"{preset}-{seed}-{scans}"
            folder = root / "sequences" / name
            if folder.is_dir() and bool(read_sweep_file(folder)) != skewed:
                raise DatasetError(f"{folder} was simulated {'with' if not skewed else 'without'} intra-sweep motion; "
                                   f"keep skewed and other drives in roots of their own")
            sim = sim_preset(preset)
            sim = with_effects(sim, intra_sweep_motion=True) if skewed else sim
            if not made_by_this_simulator(folder, sim, sensor, seed, scans):
                if folder.exists():
                    log(f"simulating {name} anew: {folder} was written by another version of the simulator, or not "
                        "to its end")
                    shutil.rmtree(folder)
                log(f"simulating {name} ({scans} scans) into {folder}")
                simulate_sequence(root, name, scans, sim, seed, sensor)
            out.append((preset, name, folder))
    return out


def real_sequences(real_root: Path | None) -> list[Path]:
    """The real development sequences under ``real_root`` (``sequences/08a``, ``08b``), or none."""
    if real_root is None or not (real_root / "sequences").is_dir():
        return []
    return sorted(p for p in (real_root / "sequences").iterdir()
                  if (p / "velodyne").is_dir() and (p / "labels").is_dir())


def run_suite(pipeline: MosPipeline, sim_root: Path, real_root: Path | None, scans: int = 100,
              seeds: dict[str, tuple[int, ...]] = SIM_SEEDS, log: Callable[[str], None] = lambda s: None,
              progress: Callable[[], None] | None = None, sensor: str = "hdl64",
              breakdown: ErrorBreakdown | None = None) -> dict[str, list[RowScore]]:
    """Every row of the suite, per label convention: per sequence, per preset, the real scans (SemanticKITTI's
    convention only); absent real scans are skipped.

    With ``breakdown`` every scored scan of the model is also added to it (see :func:`score_sequence`).
    """
    tables: dict[str, list[RowScore]] = {c: [] for c in CONVENTIONS}

    def add_group(title: str, scored: list[dict[str, RowScore]]) -> None:
        for convention, rows in tables.items():
            group = [s[convention] for s in scored if convention in s]
            if not group:
                continue
            total = RowScore(title)
            for row in group:
                total.add(row)
            rows.extend([*group, total])

    for preset, group in _grouped(ensure_sim_sequences(sim_root, scans, seeds, log, sensor)):
        add_group(f"sim {preset}", [score_sequence(pipeline, SemanticKittiSequence(folder), f"  {name}",
                                                   progress=progress, breakdown=breakdown)
                                    for name, folder in group])
    real = real_sequences(real_root)
    if real:
        add_group("real KITTI 08 (agreement)",
                  [score_sequence(pipeline, SemanticKittiSequence(folder), f"  real {folder.name}", REAL_WARMUP,
                                  progress=progress, breakdown=breakdown) for folder in real])
    elif real_root is None:
        log("real scans skipped: the development scans are HDL-64E scans")
    else:
        log(f"real scans skipped: no {real_root}/sequences/*/{{velodyne,labels}} "
            "(unpack them with ../shared/real/unpack.sh data/real-kitti08-dev)")
    return {c: rows for c, rows in tables.items() if rows}


def _grouped(items: Iterable[tuple[str, str, Path]]) -> list[tuple[str, list[tuple[str, Path]]]]:
    groups: dict[str, list[tuple[str, Path]]] = {}
    for preset, name, folder in items:
        groups.setdefault(preset, []).append((name, folder))
    return list(groups.items())


def format_table(rows: list[RowScore], title: str = "") -> str:
    """A Markdown table: IoU, precision, recall, FP per scan, max moving share, and the baselines' IoU."""

    def pct(v: float) -> str:
        return "–" if v != v else f"{100 * v:.1f}"

    lines = [title] if title else []
    lines += [
        "| data | scans | moving IoU | precision | recall | FP points / scan | max % of a scan moving | "
        "Residual IoU | Residual + RG IoU | model − RG |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        bold = not r.name.startswith(" ")
        iou = pct(r.model.iou)
        margin = 100 * (r.model.iou - r.region_growing.iou)
        lines.append(
            f"| {r.name.strip()} | {r.scans} | {f'**{iou}**' if bold else iou} | {pct(_precision(r.model))} | "
            f"{pct(_recall(r.model))} | {r.model.fp / max(r.scans, 1):.0f} | {100 * r.max_moving_fraction:.1f} | "
            f"{pct(r.residual.iou)} | {pct(r.region_growing.iou)} | {'–' if margin != margin else f'{margin:+.1f}'} |"
        )
    return "\n".join(lines)
