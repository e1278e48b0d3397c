"""Issues 29 and 30: the online model against `ros2-mos autolabel` on real drives without human labels.

    ros2-mos autolabel DRIVE... --out data/al_real --png                        # SemanticKITTI's convention
    ros2-mos autolabel DRIVE... --out data/al_real_instant --convention instant
    ros2-mos infer DRIVE --out data/online_real                                 # per drive, the model to judge
    python benchmarks/real_agreement.py DRIVE... --auto data/al_real_instant --auto-sk data/al_real \\
        --online data/online_real [--online data/adapted_real ...]

Per drive and per online prediction folder: movers per scan (autolabel's, from its objects.csv), the share of
points labelled moving by each, the share of points where the online labels and autolabel's disagree, and the
online model's precision, recall and IoU against autolabel's instant labels (what physically moves now), its
false-positive points per scan (median, p90, max) and the largest share of a scan it labels moving. Scans before
``--warmup`` are left out (no history yet).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label


def moving(root: Path, drive: str, stem: str, n: int) -> np.ndarray:
    return to_moving_classes(read_label(root / "sequences" / drive / "predictions" / f"{stem}.label", n)) == MOVING


def movers_per_scan(root: Path, drive: str, scans: int) -> float:
    rows = list(csv.DictReader(open(root / "sequences" / drive / "objects.csv")))
    covered = sum(int(r["last_scan"]) - int(r["first_scan"]) + 1 for r in rows)
    return covered / scans


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("drives", nargs="+", type=Path)
    parser.add_argument("--auto", type=Path, required=True, help="autolabel --convention instant root")
    parser.add_argument("--auto-sk", type=Path, help="autolabel (SemanticKITTI's convention) root")
    parser.add_argument("--online", type=Path, action="append", required=True)
    parser.add_argument("--warmup", type=int, default=8)
    args = parser.parse_args()
    print("| drive | scans | movers / scan | auto % moving (instant / sk) | online | online % moving | "
          "disagree % | precision | recall | IoU | FP / scan median / p90 / max | max % of a scan |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for folder in args.drives:
        seq = SemanticKittiSequence(folder)
        name = seq.name
        stems = [f.stem for f in seq.scan_files][args.warmup:]
        sizes = [f.stat().st_size // 16 for f in seq.scan_files][args.warmup:]
        auto = [moving(args.auto, name, s, n) for s, n in zip(stems, sizes)]
        sk = [moving(args.auto_sk, name, s, n) for s, n in zip(stems, sizes)] if args.auto_sk else None
        total = sum(sizes)
        auto_share = f"{100 * sum(a.sum() for a in auto) / total:.2f}"
        if sk is not None:
            auto_share += f" / {100 * sum(a.sum() for a in sk) / total:.2f}"
        per_scan = movers_per_scan(args.auto_sk or args.auto, name, len(seq))
        for online_root in args.online:
            online = [moving(online_root, name, s, n) for s, n in zip(stems, sizes)]
            tp = sum(int((o & a).sum()) for o, a in zip(online, auto))
            fp_scan = np.array([int((o & ~a).sum()) for o, a in zip(online, auto)])
            fn = sum(int((~o & a).sum()) for o, a in zip(online, auto))
            fp = int(fp_scan.sum())
            reference = sk if sk is not None else auto
            disagree = sum(int((o != a).sum()) for o, a in zip(online, reference)) / total
            precision = tp / max(tp + fp, 1)
            recall = tp / max(tp + fn, 1)
            iou = tp / max(tp + fp + fn, 1)
            top = max(float(o.mean()) for o in online)
            print(f"| {name} | {len(stems)} | {per_scan:.1f} | {auto_share} | {online_root.name} | "
                  f"{100 * sum(o.sum() for o in online) / total:.2f} | {100 * disagree:.2f} | {100 * precision:.1f} | "
                  f"{100 * recall:.1f} | {100 * iou:.1f} | {np.median(fp_scan):.0f} / {np.percentile(fp_scan, 90):.0f}"
                  f" / {fp_scan.max()} | {100 * top:.1f} |")


if __name__ == "__main__":
    try:
        main()
    except DatasetError as error:  # a drive missing from one of the roots: say which, no traceback
        raise SystemExit(f"real_agreement: {error}") from None
