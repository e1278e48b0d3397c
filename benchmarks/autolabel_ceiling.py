"""Issue 29: how much of SemanticKITTI's moving a labeller that must *see* motion can reach on simulated drives.

Under SemanticKITTI's convention (``ros2-mos simulate --convention semantickitti``) an agent is moving in every scan
of a drive when it moved at any time within the sensor's reach, also when it moved only as a few returns 50 m
away. Autolabel, like any labeller of whole drives, knows an object moved only from scans in which it is an object:
``ObjectConfig.min_points`` returns or more within ``ObjectConfig.max_range``, in at least
``TrackConfig.min_moving_observations`` scans. Per drive this prints the share of the SemanticKITTI moving points
on agents never seen moving that way (from the instant labels), and the moving IoU a labeller that is perfect
otherwise would reach: a ceiling, not a target, and a lower one for a sparse sensor.

    python benchmarks/autolabel_ceiling.py data/autolabel/vlp16/sequences/* [--min-points 8] [--max-range 60]
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from ros2_mos.io.conventions import INSTANT, SEMANTICKITTI, label_dirs
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
from ros2_mos.offline.objects import ObjectConfig
from ros2_mos.offline.tracks import TrackConfig


def unseen_motion(folder: Path, min_points: int, max_range: float, min_scans: int) -> tuple[int, int]:
    """(SemanticKITTI moving points, those on agents seen moving with ``min_points`` returns within ``max_range``
    in fewer than ``min_scans`` scans) of one simulated drive."""
    seq = SemanticKittiSequence(folder)
    dirs = label_dirs(folder)
    moving_points: Counter[int] = Counter()
    seen_moving: Counter[int] = Counter()
    for k, scan_file in enumerate(seq.scan_files):
        ever = read_label(dirs[SEMANTICKITTI] / f"{scan_file.stem}.label")
        now = read_label(dirs[INSTANT] / f"{scan_file.stem}.label")
        points = seq[k].points
        instance = ever >> 16
        moving_points.update(dict(zip(*np.unique(instance[to_moving_classes(ever) == MOVING], return_counts=True))))
        close = np.einsum("ij,ij->i", points, points) < max_range**2
        ids, counts = np.unique(instance[(to_moving_classes(now) == MOVING) & close], return_counts=True)
        seen_moving.update(int(i) for i, c in zip(ids, counts) if c >= min_points)
    total = sum(moving_points.values())
    return total, sum(c for i, c in moving_points.items() if seen_moving[int(i)] < min_scans)


def main() -> None:
    objects, tracks = ObjectConfig(), TrackConfig()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("drives", nargs="+", type=Path, help="simulated sequence folders (both label conventions)")
    parser.add_argument("--min-points", type=int, default=objects.min_points)
    parser.add_argument("--max-range", type=float, default=objects.max_range)
    parser.add_argument("--min-scans", type=int, default=tracks.min_moving_observations)
    args = parser.parse_args()
    print("| drive | SemanticKITTI moving points | on agents never seen moving | ceiling IoU |")
    print("|---|---:|---:|---:|")
    ceilings = []
    for folder in args.drives:
        if not label_dirs(folder).keys() >= {SEMANTICKITTI, INSTANT}:
            raise SystemExit(f"{folder}: needs both label conventions (a drive of `ros2-mos simulate`)")
        total, unseen = unseen_motion(folder, args.min_points, args.max_range, args.min_scans)
        ceilings.append(1.0 - unseen / max(total, 1))
        print(f"| {folder.name} | {total} | {unseen} ({100 * unseen / max(total, 1):.1f} %) | "
              f"{100 * ceilings[-1]:.1f} |", flush=True)
    print(f"| mean of {len(ceilings)} | | | {100 * float(np.mean(ceilings)):.2f} |")


if __name__ == "__main__":
    main()
