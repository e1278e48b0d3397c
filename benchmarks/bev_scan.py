"""A bird's-eye picture of one scan labelled by several prediction folders side by side (moving red, the rest grey
by height), to look at what a change does on real data.

    python benchmarks/bev_scan.py SEQUENCE_DIR SCAN OUT.png ROOT[=TITLE] ROOT[=TITLE] ... [--half-width 40]

Each ROOT is a predictions root (ROOT/sequences/<name>/predictions/*.label: `infer`, `autolabel`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ros2_mos.apps.mapping import side_by_side
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import read_label, read_scan


def panel(points: np.ndarray, moving: np.ndarray, half: float, res: float) -> np.ndarray:
    n = int(2 * half / res)
    img = np.full((n, n, 3), 255, np.uint8)
    col = ((points[:, 0] + half) / res).astype(int)
    row = ((half - points[:, 1]) / res).astype(int)
    ok = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    shade = (200 - 160 * np.clip((points[:, 2] + 2.0) / 4.0, 0, 1)).astype(np.uint8)
    order = np.argsort(points[:, 2])
    order = order[ok[order]]
    img[row[order], col[order]] = shade[order, None]
    hit = ok & moving
    img[row[hit], col[hit]] = (230, 20, 20)
    return img


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("scan", type=int)
    parser.add_argument("out", type=Path)
    parser.add_argument("roots", nargs="+")
    parser.add_argument("--half-width", type=float, default=40.0)
    parser.add_argument("--resolution", type=float, default=0.1)
    args = parser.parse_args()
    stem = sorted((args.sequence / "velodyne").glob("*.bin"))[args.scan].stem
    points = read_scan(args.sequence / "velodyne" / f"{stem}.bin")[:, :3]
    panels, titles = [], []
    for item in args.roots:
        root, _, title = item.partition("=")
        labels = read_label(Path(root) / "sequences" / args.sequence.name / "predictions" / f"{stem}.label",
                            len(points))
        moving = to_moving_classes(labels) == MOVING
        panels.append(panel(points, moving, args.half_width, args.resolution))
        titles.append(f"{title or root}: {100 * moving.mean():.2f} % moving")
    image = side_by_side(panels, [f"{args.sequence.name} scan {args.scan}, {t}" for t in titles])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    image.save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
