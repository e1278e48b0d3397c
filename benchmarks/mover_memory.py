"""The memory of movers (ros2_mos/core/mover_memory.py), off against on: moving IoU under both label conventions.

The pipeline (shipped model, KISS-ICP poses, memory off) runs once over each drive; every memory setting is then
applied to the same network output, scan by scan, as the pipeline applies it (the memory changes no other stage's
state at the default ``odometry.map_update: all``). Drives: the suite's held-out ones (``--suite``,
ros2_mos/scoring/suite.py SIM_SEEDS) plus a stop-and-go traffic_jam drive of a seed used nowhere else (9401), or
validation drives (``--validation``: seeds 9501-9502 traffic_jam, 9501 benchmark and easy) for tuning.

    nice -n 5 .venv/bin/python benchmarks/mover_memory.py --suite [--setting 10,0.5,0.5,2 ...]
    nice -n 5 .venv/bin/python benchmarks/mover_memory.py --validation --grid

Prints Markdown tables: per drive and per preset, IoU (precision / recall) under each convention with the memory
off and with each setting, the share of SemanticKITTI-moving points that are static under the instant convention
(movers standing: what the memory is for), and the memory's cost per scan (ms, median).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from pathlib import Path

import numpy as np

from ros2_mos.core.config import MosConfig, MoverMemoryConfig
from ros2_mos.core.mover_memory import MoverMemory
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.core.projection import project
from ros2_mos.io.conventions import INSTANT, SEMANTICKITTI, label_dirs
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
from ros2_mos.scoring.metrics import MovingIoU
from ros2_mos.scoring.suite import SIM_SEEDS, ensure_sim_sequences

STOP_AND_GO = {"traffic_jam": (9401,)}
VALIDATION = {"traffic_jam": (9501, 9502), "benchmark": (9501,), "easy": (9501,)}
SCANS = 100
CONVENTIONS = (SEMANTICKITTI, INSTANT)


def parse_setting(text: str) -> MoverMemoryConfig:
    """'max_age,share,voxel_size,min_scans' -> an enabled configuration."""
    max_age, share, voxel, min_scans = text.split(",")
    return MoverMemoryConfig(enabled=True, max_age=float(max_age), share=float(share), voxel_size=float(voxel),
                             min_scans=int(min_scans))


def label(setting: MoverMemoryConfig | None) -> str:
    if setting is None:
        return "off"
    return f"{setting.max_age:g} s / {setting.share:g} / {setting.voxel_size:g} m / {setting.min_scans}"


@dataclasses.dataclass
class DriveScore:
    name: str
    preset: str
    scores: dict[tuple[str, str], MovingIoU]  # (setting label, convention) -> counts
    standing: int = 0  # points moving under SemanticKITTI's convention, static under the instant one
    sk_moving: int = 0
    ms: dict[str, list[float]] = dataclasses.field(default_factory=dict)


def score_drive(pipeline: MosPipeline, folder: Path, preset: str, settings: list[MoverMemoryConfig | None]
                ) -> DriveScore:
    sequence = SemanticKittiSequence(folder)
    folders = label_dirs(folder)
    labels = [label(s) for s in settings]
    out = DriveScore(folder.name, preset, {(lab, c): MovingIoU() for lab in labels for c in CONVENTIONS},
                     ms={lab: [] for lab in labels})
    memories = [None if s is None else MoverMemory(s) for s in settings]
    pipeline.reset()
    for frame in sequence:
        result = pipeline.process(frame.points, frame.remission, frame.timestamp)
        stem = sequence.scan_files[frame.index].stem
        gts = {c: to_moving_classes(frame.labels if folders[c].name == "labels"
                                    else read_label(folders[c] / f"{stem}.label", len(frame.points)))
               for c in CONVENTIONS}
        out.standing += int(np.count_nonzero((gts[SEMANTICKITTI] == MOVING) & (gts[INSTANT] != MOVING)))
        out.sk_moving += int(np.count_nonzero(gts[SEMANTICKITTI] == MOVING))
        # The pipeline's own image of the scan (the same projection it made).
        valid = result.valid
        image = project(np.ascontiguousarray(frame.points[valid], np.float32),
                        np.nan_to_num(frame.remission[valid]).astype(np.float32), pipeline.sensor)
        point_prob = result.probability[valid]
        for lab, memory in zip(labels, memories):
            if memory is None:
                predicted = result.labels
            else:
                start = time.perf_counter()
                _, prob = memory.apply(result.probability_image, point_prob, image, result.pose, frame.timestamp,
                                       pipeline.threshold)
                out.ms[lab].append((time.perf_counter() - start) * 1e3)
                predicted = np.zeros(len(valid), np.uint8)
                predicted[valid] = prob >= pipeline.threshold
            for c in CONVENTIONS:
                out.scores[(lab, c)].update(predicted, gts[c])
    return out


def pct(v: float) -> str:
    return "–" if v != v else f"{100 * v:.1f}"


def cell(s: MovingIoU) -> str:
    precision = s.tp / (s.tp + s.fp) if s.tp + s.fp else float("nan")
    recall = s.tp / (s.tp + s.fn) if s.tp + s.fn else float("nan")
    return f"{pct(s.iou)} ({pct(precision)} / {pct(recall)})"


def table(drives: list[DriveScore], labels: list[str]) -> str:
    """One row per drive and per preset (sums), one column pair per setting."""
    groups: dict[str, list[DriveScore]] = {}
    for d in drives:
        groups.setdefault(d.preset, []).append(d)
    rows: list[tuple[str, DriveScore]] = []
    for preset, group in groups.items():
        rows += [(f"  {d.name}", d) for d in group]
        total = DriveScore(f"{preset}", preset, {k: sum((d.scores[k] for d in group), MovingIoU())
                                                  for k in group[0].scores},
                           sum(d.standing for d in group), sum(d.sk_moving for d in group))
        rows.append((f"**{preset}**", total))
    head = "| drive | standing movers % |" + "".join(f" {c} IoU (P / R), {lab} |" for lab in labels
                                                     for c in CONVENTIONS)
    head += "".join(f" Δ {c}, {lab} |" for lab in labels[1:] for c in CONVENTIONS)
    lines = [head, "|---|---:|" + "---:|" * (2 * len(labels) + 2 * (len(labels) - 1))]
    for name, d in rows:
        line = f"| {name.strip()} | {pct(d.standing / max(d.sk_moving, 1))} |"
        line += "".join(f" {cell(d.scores[(lab, c)])} |" for lab in labels for c in CONVENTIONS)
        line += "".join(f" {100 * (d.scores[(lab, c)].iou - d.scores[(labels[0], c)].iou):+.1f} |"
                        for lab in labels[1:] for c in CONVENTIONS)
        lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--suite", action="store_true", help="the suite's held-out drives + stop-and-go seed 9401")
    which.add_argument("--validation", action="store_true", help="the validation drives (seeds 9501-9502)")
    parser.add_argument("--data", type=Path, default=Path("data/suite"), help="suite drives (simulated on first use)")
    parser.add_argument("--extra-data", type=Path, default=Path("data/mover_memory"),
                        help="the stop-and-go and validation drives (simulated on first use)")
    parser.add_argument("--setting", action="append", default=[],
                        help="max_age,share,voxel_size,min_scans (repeatable); default: the defaults, enabled")
    parser.add_argument("--grid", action="store_true", help="max_age 5/10/20 s x share 0.5/0.7 x min_scans 2/3/5 "
                        "(voxel 0.5 m)")
    args = parser.parse_args(argv)

    settings: list[MoverMemoryConfig | None] = [None]
    if args.grid:
        settings += [MoverMemoryConfig(enabled=True, max_age=a, share=s, min_scans=n)
                     for a, s, n in itertools.product((5.0, 10.0, 20.0), (0.5, 0.7), (2, 3, 5))]
    settings += [parse_setting(s) for s in args.setting]
    if len(settings) == 1:
        settings.append(dataclasses.replace(MoverMemoryConfig(), enabled=True))
    drives = []
    if args.suite:
        drives += ensure_sim_sequences(args.data, SCANS, SIM_SEEDS, log=print)
        drives += [("stop_and_go", name, folder)
                   for _, name, folder in ensure_sim_sequences(args.extra_data, SCANS, STOP_AND_GO, log=print)]
    else:
        drives += ensure_sim_sequences(args.extra_data, SCANS, VALIDATION, log=print)
    pipeline = MosPipeline(MosConfig())  # memory off: the network's labels, the memory applied beside
    scored = []
    for preset, name, folder in drives:
        start = time.perf_counter()
        scored.append(score_drive(pipeline, folder, preset, settings))
        print(f"{name}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    labels = [label(s) for s in settings]
    print(f"Memory of movers, model `{pipeline.model.path.name}`, KISS-ICP poses, {SCANS} scans a drive; "
          "settings max_age / share / voxel_size / min_scans\n")
    if len(labels) <= 4:
        print(table(scored, labels))
    else:  # a grid: one summary line per setting over all drives, then per preset
        presets = sorted({d.preset for d in scored})
        print("| setting | " + " | ".join(f"{p} Δ {c}" for p in presets for c in CONVENTIONS) +
              " | min Δ semantickitti | min Δ instant |")
        print("|---|" + "---:|" * (2 * len(presets) + 2))
        base = labels[0]
        for lab in labels[1:]:
            deltas = {}
            for p in presets:
                group = [d for d in scored if d.preset == p]
                for c in CONVENTIONS:
                    s = sum((d.scores[(lab, c)] for d in group), MovingIoU())
                    b = sum((d.scores[(base, c)] for d in group), MovingIoU())
                    deltas[(p, c)] = 100 * (s.iou - b.iou)
            print(f"| {lab} | " + " | ".join(f"{deltas[(p, c)]:+.1f}" for p in presets for c in CONVENTIONS) +
                  f" | {min(deltas[(p, SEMANTICKITTI)] for p in presets):+.1f} | "
                  f"{min(deltas[(p, INSTANT)] for p in presets):+.1f} |")
    costs = [ms for d in scored for lab in labels[1:] for ms in d.ms[lab]]
    if costs:
        print(f"\nmemory cost per scan (all settings, {len(costs)} applications): median "
              f"{np.median(costs):.1f} ms, p95 {np.percentile(costs, 95):.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
