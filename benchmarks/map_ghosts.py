"""Maps cleaned by the online model against maps cleaned by autolabel's labels (issue 29, item 4).

    python benchmarks/map_ghosts.py --data data/autolabel [--sensor hdl64] [--drives easy-9301 ...]

For each of the suite's held-out drives (simulated into --data where missing; the same seeds as the suite): the
raw map, the map cleaned by the shipped online model (``ros2-mos map DRIVE``: the pipeline's own KISS-ICP poses) and
the map cleaned by ``ros2-mos autolabel``'s labels in each convention (``ros2-mos map DRIVE --labels OUT``:
autolabel's poses over the whole drive). Prints per drive and map its ghost share (map points of objects the
simulator labels moving under SemanticKITTI's convention, so a car that waited and left is a ghost) and the share of
the raw map's static voxels the cleaned map keeps; the means over the drives last. 0.1 m voxels, 50 m, as ``map``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ros2_mos.apps.mapping import MappingConfig, MappingResult, build_maps, build_maps_from_labels, ghost_share
from ros2_mos.core.config import MosConfig, sensor_preset
from ros2_mos.core.inference import default_model_path
from ros2_mos.io.conventions import CONVENTIONS
from ros2_mos.offline.autolabel import AutolabelConfig, autolabel_drive
from ros2_mos.offline.drives import FolderDrive
from ros2_mos.scoring.suite import SIM_SEEDS, ensure_sim_sequences


def figures(result: MappingResult) -> tuple[float, float, float]:
    """Raw ghost %, cleaned ghost %, static voxels kept %."""
    return (100 * ghost_share(result.raw), 100 * ghost_share(result.cleaned), 100 * result.builder.static_kept())


def cells(row: list[float]) -> str:
    """A table row's figures: raw ghost %, then ghost % / static kept % for the online model and each convention."""
    pairs = [f"{row[1 + 2 * i]:.2f} / {row[2 + 2 * i]:.1f}" for i in range(1 + len(CONVENTIONS))]
    return f"{row[0]:.2f} | " + " | ".join(pairs) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=Path("data/autolabel"), help="root of the suite's drives")
    parser.add_argument("--sensor", default="hdl64")
    parser.add_argument("--drives", nargs="*", default=None, help="preset-seed (default: the suite's eight)")
    parser.add_argument("--scans", type=int, default=100)
    args = parser.parse_args()
    sensor = sensor_preset(args.sensor)
    root = args.data if args.sensor == "hdl64" else args.data / args.sensor
    drives = ensure_sim_sequences(root, args.scans, SIM_SEEDS, print, args.sensor)
    folders = [folder for _, name, folder in drives if not args.drives or name.rsplit("-", 1)[0] in args.drives]
    if not folders:
        names = ", ".join(name for _, name, _ in drives)
        parser.error(f"--drives {' '.join(args.drives)}: none of the suite's drives ({names}); give preset-seed")
    config = MosConfig(model=str(default_model_path(args.sensor)))
    mapping = MappingConfig()
    print(f"maps cleaned online and by autolabel, {args.sensor}, {args.scans} scans a drive, "
          f"{time.strftime('%Y-%m-%d')}; ghost % raw -> cleaned / static voxels kept %\n")
    print("| drive | raw ghost % | online: ghost % / static kept % | " +
          " | ".join(f"autolabel {c}: ghost % / static kept %" for c in CONVENTIONS) + " |")
    print("|---|---:|---:|" + "---:|" * len(CONVENTIONS))
    rows = []
    for folder in folders:
        drive = FolderDrive(folder)
        labelled = []
        # autolabel first: KISS-ICP takes its threads from the first registration a process builds, and autolabel's
        # one thread makes its labels repeat (the online map after it runs on one thread too)
        for convention in CONVENTIONS:
            with tempfile.TemporaryDirectory() as out:
                autolabel_drive(drive, out, sensor, convention, AutolabelConfig())
                _, ghost, kept = figures(build_maps_from_labels(drive, out, mapping))
            labelled += [ghost, kept]
        raw, online_ghost, online_kept = figures(build_maps(drive, config, mapping))
        row = [raw, online_ghost, online_kept, *labelled]
        rows.append(row)
        print(f"| {folder.name} | {cells(row)}", flush=True)
    print(f"| mean of {len(rows)} | {cells(list(np.mean(rows, axis=0)))}")


if __name__ == "__main__":
    main()
