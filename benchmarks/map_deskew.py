"""Maps of skewed drives, deskewed or not, against the same drives simulated without skew (round 40).

    python benchmarks/map_deskew.py --data data/autolabel --skewed-data data/skewed
    python benchmarks/map_deskew.py --sensors hdl64 vlp32c vlp16 --drives easy-9301 narrow_street-9502

The suite's drives are simulated into --data (not skewed) and --skewed-data (``--intra-sweep-motion``; a root of its
own), reused where they exist; the same seed gives the same world, traffic and path. Each map is built with the
drive's true poses (``MappingConfig``, 5 cm voxels, 2.5-50 m), so that only the sweeps differ. Prints per drive and
sweep treatment the map's points and the share of them in a voxel (0.1 / 0.2 / 0.4 m) that the unskewed twin's map
fills: a sharp map lies on the twin's surfaces.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ros2_mos.apps.mapping import MappingConfig, fill_maps
from ros2_mos.offline.drives import FolderDrive
from ros2_mos.scoring.suite import SIM_SEEDS, ensure_sim_sequences

VOXELS = (0.1, 0.2, 0.4)


def voxel_keys(points: np.ndarray, size: float) -> np.ndarray:
    cells = np.floor(points / size).astype(np.int64) + (1 << 20)
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


def raw_map(folder: Path, deskewed: bool) -> np.ndarray:
    """The drive's map of every point (nothing removed) at its true poses."""
    drive = FolderDrive(folder)
    return fill_maps(drive, drive.poses, lambda k, scan: np.zeros(len(scan.points), bool),
                     MappingConfig(voxel_size=0.05), deskewed, drive.sequence.times[: len(drive)]).raw.points


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=Path("data/autolabel"), help="root of the unskewed drives")
    parser.add_argument("--skewed-data", type=Path, default=Path("data/skewed"), help="root of the skewed drives")
    parser.add_argument("--sensors", nargs="+", default=["hdl64", "vlp32c", "vlp16"])
    parser.add_argument("--drives", nargs="+", default=["easy-9301", "narrow_street-9502", "benchmark-9101",
                                                        "easy-9302"], help="preset-seed of the suite's drives")
    parser.add_argument("--scans", type=int, default=100)
    args = parser.parse_args()
    seeds: dict[str, tuple[int, ...]] = {}
    for drive in args.drives:
        preset, seed = drive.rsplit("-", 1)
        if int(seed) not in SIM_SEEDS.get(preset, ()):
            parser.error(f"{drive} is not one of the suite's drives")
        seeds[preset] = (*seeds.get(preset, ()), int(seed))
    print("| sensor | drive | map | points | in the twin's 0.1 m voxels | 0.2 m | 0.4 m |")
    print("|---|---|---|---:|---:|---:|---:|")
    for sensor in args.sensors:
        roots = [root if sensor == "hdl64" else root / sensor for root in (args.data, args.skewed_data)]
        plain = ensure_sim_sequences(roots[0], args.scans, seeds, sensor=sensor)
        skewed = ensure_sim_sequences(roots[1], args.scans, seeds, sensor=sensor, skewed=True)
        for (_, name, twin), (_, _, folder) in zip(plain, skewed):
            reference = raw_map(twin, False)
            filled = {size: np.unique(voxel_keys(reference, size)) for size in VOXELS}
            for label, points in (("twin (not skewed)", reference), ("skewed", raw_map(folder, False)),
                                  ("skewed, deskewed", raw_map(folder, True))):
                shares = " | ".join(f"{np.isin(voxel_keys(points, s), filled[s]).mean():.3f}" for s in VOXELS)
                print(f"| {sensor} | {name} | {label} | {len(points)} | {shares} |", flush=True)


if __name__ == "__main__":
    main()
