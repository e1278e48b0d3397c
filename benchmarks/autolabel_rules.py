"""Issue 29: autolabel's decision rules compared on simulated drives, each drive tracked once.

Labelling a drive is two parts: its poses, objects, evidence and tracks (``AutoLabeler.track``, nearly all the time),
then which tracks are movers and where they move (``AutoLabeler.decide``, under a second a drive). A rule of the
second part is tried on a sensor's validation drives in seconds once their tracks are kept (timings:
``benchmarks/autolabel.md``, round 47): each drive's tracks are built once and kept in ``--cache`` (under a key of the
code that builds them: a change there builds them again), then decided under the default settings and under each
``--variant``, and both conventions are scored.

    python benchmarks/autolabel_rules.py --data data/autolabel --sensors vlp16 --seeds validation \\
        --variant tracks.cue_veto_near=0.1 --variant "tracks.leave_travel=0.5 instant_speed=0.5"

A variant changes settings that only the decision reads: ``tracks.NAME`` for any track setting but those read while
tracks are built (``ros2_mos.offline.tracks.TRACKING_FIELDS``), and the labeller's :data:`DECISION_SETTINGS`. Others
(objects, evidence, the online cue) need ``benchmarks/autolabel.py --set``, which labels every drive again. Prints
per drive the moving IoU under SemanticKITTI's convention and the instant one and the movers, per variant, then
each preset's mean and the mean of all of a sensor's drives.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from ros2_mos.core.config import sensor_preset
from ros2_mos.io.conventions import CONVENTIONS, label_dirs
from ros2_mos.io.labels import to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult, scan_labels
from ros2_mos.offline.drives import FolderDrive
from ros2_mos.offline.tracks import TRACKING_FIELDS
from ros2_mos.scoring.metrics import MovingIoU
from ros2_mos.scoring.suite import ensure_sim_sequences
from ros2_mos.sim.writer import SIMULATOR_FILE

sys.path.insert(0, str(Path(__file__).parent))
from autolabel import SEED_SETS, config_with, preset_means, seeds_of  # noqa: E402  (seed sets, --set, means: defined once)

#: The labeller's settings that only :meth:`AutoLabeler.decide` reads (where movers move under each convention).
DECISION_SETTINGS = ("support_margin", "ever_from_motion", "shadow_edges", "instant_seen_through", "instant_speed",
                     "instant_span", "instant_motion", "instant_context", "instant_cue_reshape", "instant_cue_centroid",
                     "instant_cue_motion")
#: The code that builds the tracks: the cache is kept per hash of it.
TRACKING_CODE = ("core", "offline", "io")


def code_key() -> str:
    """A short hash of the package's code that tracking runs (sources and compiled kernels)."""
    root = Path(__file__).resolve().parent.parent / "ros2_mos"
    digest = hashlib.sha1()
    for part in TRACKING_CODE:
        for path in sorted((root / part).rglob("*")):
            if path.suffix in (".py", ".c", ".so") and path.is_file():
                digest.update(path.relative_to(root).as_posix().encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def parse_variant(text: str) -> AutolabelConfig:
    """``"tracks.NAME=VALUE NAME=VALUE ..."`` -> the default settings with those changed; raises ValueError."""
    settings = text.split()
    for item in settings:
        if "=" not in item:
            raise ValueError(f"{item!r}: NAME=VALUE")
    config = config_with(settings)[0]  # unknown names and values the settings refuse first
    for item in settings:
        name = item.partition("=")[0]
        part, dot, field_name = name.rpartition(".")
        if dot and part == "tracks" and field_name in TRACKING_FIELDS:
            raise ValueError(f"{name} is read while tracks are built: use benchmarks/autolabel.py --set")
        if (dot and part != "tracks") or (not dot and field_name not in DECISION_SETTINGS):
            raise ValueError(f"{name} is not read by the decision alone ({', '.join(DECISION_SETTINGS)}, tracks.*): "
                             "use benchmarks/autolabel.py --set")
    return config


def tracked_drive(folder: Path, labeler: AutoLabeler, cache: Path) -> tuple[AutolabelResult, Path]:
    """The drive's tracks (from ``cache``, else built by ``labeler`` and kept there) and the folder of its per-scan
    object ids. Kept per drive as simulated (its ``simulator.txt``): a drive simulated anew is tracked anew."""
    stamp = folder / SIMULATOR_FILE
    made = stamp.read_text().strip() if stamp.is_file() else "unstamped"
    where = cache / labeler.sensor.name / f"{folder.name}-{made}"
    state = where / "tracked.pkl"
    if not state.exists():
        work = where / "objects"
        work.mkdir(parents=True, exist_ok=True)
        tracked = labeler.track(FolderDrive(folder), work)
        partial = state.with_suffix(".partial")
        with open(partial, "wb") as f:
            pickle.dump(tracked, f)
        partial.rename(state)
    with open(state, "rb") as f:
        return pickle.load(f), where / "objects"


def score(labeler: AutoLabeler, tracked: AutolabelResult, objects: Path,
          truth: dict[str, list[np.ndarray]]) -> tuple[list[float], int]:
    """Moving IoU (%) per convention of ``tracked`` decided by ``labeler``, and its movers."""
    result = labeler.decide(copy.deepcopy(tracked))
    ious = []
    for convention in CONVENTIONS:
        iou = MovingIoU()
        for k in range(result.scans):
            iou.update(scan_labels(labeler, result, objects, k, convention), truth[convention][k])
        ious.append(100 * iou.iou)
    return ious, len(result.movers)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=Path("data/autolabel"))
    parser.add_argument("--sensors", nargs="+", default=["hdl64"])
    parser.add_argument("--seeds", choices=tuple(SEED_SETS), default="validation")
    parser.add_argument("--presets", nargs="+", metavar="PRESET",
                        help="only the seed set's drives of these presets (default: all of them)")
    parser.add_argument("--scans", type=int, default=100)
    parser.add_argument("--cache", type=Path, default=Path("data/autolabel_tracked"),
                        help="where each drive's tracks are kept (a folder per code version)")
    parser.add_argument("--variant", action="append", default=[], metavar='"NAME=VALUE ..."',
                        help="decision settings other than the defaults (repeat for more variants)")
    args = parser.parse_args()
    try:
        variants = {"default": AutolabelConfig(), **{text: parse_variant(text) for text in args.variant}}
    except (ValueError, TypeError) as error:
        parser.error(f"--variant: {error}")
    try:
        seeds = seeds_of(args.seeds, args.presets)
    except ValueError as error:
        parser.error(str(error))
    cache = args.cache / code_key()
    print(f"autolabel decision rules, {time.strftime('%Y-%m-%d')}: {args.seeds} drives, {args.scans} scans, tracks "
          f"kept in {cache}; semantickitti / instant moving IoU (movers)\n")
    print("| sensor | drive | " + " | ".join(variants) + " |")
    print("|---|---|" + "---:|" * len(variants))
    for sensor in args.sensors:
        root = args.data if sensor == "hdl64" else args.data / sensor
        labelers = {name: AutoLabeler(sensor_preset(sensor), config) for name, config in variants.items()}
        rows: dict[str, list[list[float]]] = {name: [] for name in variants}
        presets = []
        for preset, name, folder in ensure_sim_sequences(root, args.scans, seeds, print, sensor):
            seq = SemanticKittiSequence(folder)
            dirs = label_dirs(folder)
            truth = {c: [to_moving_classes(read_label(dirs[c] / f"{f.stem}.label")) for f in seq.scan_files]
                     for c in CONVENTIONS}
            tracked, objects = tracked_drive(folder, labelers["default"], cache)
            presets.append(preset)
            cells = []
            for variant, labeler in labelers.items():
                ious, movers = score(labeler, tracked, objects, truth)
                rows[variant].append(ious)
                cells.append(f"{ious[0]:.2f} / {ious[1]:.2f} ({movers})")
            print(f"| {sensor} | {name} | " + " | ".join(cells) + " |", flush=True)
        for label, chosen in preset_means(presets):
            means = [np.mean([rows[v][i] for i in chosen], axis=0) for v in variants]
            print(f"| {sensor} | {label} | " + " | ".join(f"**{m[0]:.2f} / {m[1]:.2f}**" for m in means) + " |",
                  flush=True)


if __name__ == "__main__":
    main()
