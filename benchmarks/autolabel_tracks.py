"""Issue 29: autolabel's mover tracks on simulated drives, one row each: how many of its moving points are right and
wrong (SemanticKITTI's convention) and the evidence that made it a mover. A survey to find the tracks a rule could
drop, on drives that rules may be chosen on (``data/validation``), then checked on the held-out ones.

    python benchmarks/autolabel_tracks.py data/validation/vlp32c --sensor vlp32c --out tracks.csv

Columns: drive, track, true and false moving points, evidence, observations, the share of its points seen through by
a far scan (mean and max over its observations, and the share of observations at 0.3 or more), by a near scan (mean,
max), the online model's moving share (mean), median distance from the sensor, box height and box top (world z),
and the semantic class most of its false points have (-1: none). Points labelled moving on no mover's track
(``AutolabelConfig.cue_attach``) are one row with track -1.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ros2_mos.core.config import sensor_preset
from ros2_mos.io.labels import MOVING_IDS
from ros2_mos.io.semantic_kitti import read_label
from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, scan_labels, track_ids
from ros2_mos.offline.drives import open_drive

COLUMNS = ["drive", "track", "true_points", "false_points", "evidence", "observations", "far_mean", "far_max",
           "far_share_0.3", "near_mean", "near_max", "online_mean", "distance_median", "height_median",
           "top_median", "false_class"]


def track_rows(folder: Path, sensor: str) -> list[list]:
    """One row per mover track of the drive in ``folder`` (its ``labels/`` in SemanticKITTI's convention)."""
    drive = open_drive(folder)
    labeler = AutoLabeler(sensor_preset(sensor), AutolabelConfig())
    work = Path(tempfile.mkdtemp())
    try:
        result = labeler.label(drive, work)
        points: dict[int, list[int]] = {}
        false_classes: dict[int, list[np.ndarray]] = {}
        for k, scan in enumerate(drive):
            truth = read_label(folder / "labels" / f"{drive.scan_names[k]}.label", scan.stored)[scan.kept]
            moving = np.isin(truth & 0xFFFF, MOVING_IDS)
            labelled = scan_labels(labeler, result, work, k, "semantickitti")
            tracks = track_ids(result, work, k)
            for t in np.unique(tracks[labelled]):
                on = labelled & (tracks == t)
                count = points.setdefault(int(t), [0, 0])
                count[0] += int((on & moving).sum())
                count[1] += int((on & ~moving).sum())
                false_classes.setdefault(int(t), []).append(truth[on & ~moving] & 0xFFFF)
    finally:
        shutil.rmtree(work)
    rows = []
    for t, (right, wrong) in sorted(points.items()):
        classes = np.concatenate(false_classes[t])
        false_class = int(np.bincount(classes).argmax()) if len(classes) else -1
        if t < 0:
            rows.append([folder.name, t, right, wrong, "attached"] + [""] * 10 + [false_class])
            continue
        observations = result.tracker.tracks[t].observations
        far = np.array([o.far for o in observations])
        near = np.array([o.near for o in observations])
        rows.append([folder.name, t, right, wrong, result.movers[t], len(observations), f"{far.mean():.3f}",
                     f"{far.max():.3f}", f"{(far >= 0.3).mean():.3f}", f"{near.mean():.3f}", f"{near.max():.3f}",
                     f"{np.mean([o.online for o in observations]):.3f}",
                     f"{np.median([o.distance for o in observations]):.1f}",
                     f"{np.median([o.size[2] for o in observations]):.2f}",
                     f"{np.median([o.hi[2] for o in observations]):.2f}", false_class])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path, help="a folder of simulated drives (ROOT/sequences/*)")
    parser.add_argument("--sensor", required=True)
    parser.add_argument("--out", type=Path, required=True, help="the CSV to write")
    args = parser.parse_args()
    with open(args.out, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for folder in sorted((args.root / "sequences").iterdir()):
            writer.writerows(track_rows(folder, args.sensor))
            f.flush()
            print(folder.name, flush=True)


if __name__ == "__main__":
    main()
