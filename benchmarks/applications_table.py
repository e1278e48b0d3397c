"""Re-evaluate the poses that ``ros2-mos odometry --save-poses DIR`` wrote, with several segment sets.

    python benchmarks/applications_table.py POSES_DIR DATASET_ROOT

Prints, per sequence and mask, the KITTI errors over the standard 100..800 m segments (those
that fit the trajectory) and over short 10..80 m segments (not KITTI's definition: the
simulated traffic-jam drives are only a few hundred metres long), plus ATE (SE(3) Umeyama).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from ros2_mos.apps.kitti_metrics import SEGMENT_LENGTHS, evaluate_trajectory
from ros2_mos.apps.odometry import MASKS, ground_truth_camera_poses
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_poses, sequence_dirs

SHORT = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)


def fmt(v: float, d: int = 2) -> str:
    return "-" if math.isnan(v) else f"{v:.{d}f}"


def main(poses_dir: Path, dataset: Path) -> None:
    print("| sequence | mask | t_err % (100..800 m) | r_err deg/100m (100..800 m) | segments | "
          "t_err % (10..80 m) | r_err deg/100m (10..80 m) | ATE m |")
    print("|---|---|---|---|---|---|---|---|")
    for seq_dir in sequence_dirs(dataset):
        seq = SemanticKittiSequence(seq_dir)
        if not (poses_dir / seq.name).is_dir():
            continue
        gt, _ = ground_truth_camera_poses(seq)
        for mask in MASKS:
            path = poses_dir / seq.name / f"{mask}.txt"
            if not path.is_file():
                continue
            est = read_poses(path)  # camera frame, as written
            kitti = evaluate_trajectory(gt, est, SEGMENT_LENGTHS)
            short = evaluate_trajectory(gt, est, SHORT)
            print(f"| {seq.name} | {mask} | {fmt(kitti.translation_pct)} | {fmt(kitti.rotation_deg_per_100m)} | "
                  f"{kitti.n_segments} | {fmt(short.translation_pct)} | {fmt(short.rotation_deg_per_100m)} | "
                  f"{fmt(kitti.ate_rmse, 3)} |")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
