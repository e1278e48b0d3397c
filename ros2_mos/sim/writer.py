"""Write simulated sequences exactly as SemanticKITTI lays them out (and optionally as a rosbag2 bag).

``OUT/sequences/XX/{velodyne,labels}/NNNNNN.{bin,label}``, ``poses.txt`` (camera
poses through KITTI's ``Tr``, as the real dataset), ``calib.txt`` and
``times.txt``; ``labels/`` carries the chosen label convention and ``labels_<other>/``
the other one, ``label_convention.txt`` says which is which
(:mod:`ros2_mos.io.conventions`), all through :mod:`ros2_mos.io.semantic_kitti`, so that the
project's own reader (and any SemanticKITTI tool) reads them back unchanged. ``simulator.txt``, written
last, says what made the sequence (:func:`simulator_fingerprint`): a folder simulated by other code, or not
to its end, can be told from one this code would write.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import DatasetError
from ros2_mos.io.conventions import DEFAULT_CONVENTION, INSTANT, SEMANTICKITTI, other_convention, write_convention_file
from ros2_mos.io.semantic_kitti import (
    SemanticKittiSequence,
    write_calib,
    write_label,
    write_poses,
    write_scan,
    write_times,
)
from ros2_mos.io.sweep import write_sweep_file
from ros2_mos.sim.presets import SimPreset
from ros2_mos.sim.stats import SequenceStats
from ros2_mos.sim.traffic import relabel_movers
from ros2_mos.sim.world import SequenceSimulator, resolve_settings

#: Bag stamps start here (2023-11-14T22:13:20Z): a plausible wall-clock time rather than 0.
BAG_EPOCH_NS = 1_700_000_000 * 1_000_000_000


#: The file in a simulated sequence's folder that holds :func:`simulator_fingerprint`.
SIMULATOR_FILE = "simulator.txt"


def simulator_fingerprint(preset: SimPreset, sensor: SensorConfig, seed: int, name: str, n_scans: int) -> str:
    """A short hash of what a simulated sequence is made of: the simulator's sources (this package's modules), its
    preset (effects included), the sensor and the sequence's seed, name and length. Another version of the
    simulator, a preset or sensor changed, gives another."""
    digest = hashlib.sha1()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    digest.update(repr((preset, sensor, seed, name, n_scans)).encode())
    return digest.hexdigest()[:16]


def made_by_this_simulator(root: Path, preset: str | SimPreset, sensor: str | SensorConfig, seed: int,
                           n_scans: int) -> bool:
    """Whether the sequence folder ``root`` was simulated to its end by this simulator with these settings (its
    ``simulator.txt`` holds their :func:`simulator_fingerprint`)."""
    stamp = root / SIMULATOR_FILE
    if not stamp.is_file():
        return False
    resolved, config = resolve_settings(preset, sensor)
    return stamp.read_text().strip() == simulator_fingerprint(resolved, config, seed, root.name, n_scans)


def sequence_dir(out_dir: str | Path, name: str) -> Path:
    """Where sequence ``name`` of a dataset rooted at ``out_dir`` lives."""
    return Path(out_dir) / "sequences" / name


def simulate_sequence(
    out_dir: str | Path,
    name: str = "00",
    n_scans: int = 100,
    preset: str | SimPreset = "benchmark",
    seed: int = 0,
    sensor: str | SensorConfig = "hdl64",
    progress: Callable[[int], None] | None = None,
    convention: str = DEFAULT_CONVENTION,
) -> SequenceStats:
    """Simulate one sequence and write it under ``out_dir/sequences/name``; returns its statistics.

    ``labels/`` holds ``convention``'s labels, ``labels_<other>/`` the other convention's.
    ``progress`` is called with 1 after each written scan (e.g. ``tqdm.update``).
    Deterministic for a given (seed, name, preset, sensor, n_scans); the statistics count the instant convention.
    """
    start = time.perf_counter()
    other = other_convention(convention)
    sim = SequenceSimulator(n_scans, preset, seed, sensor, name)
    root = sequence_dir(out_dir, name)
    folders = {convention: root / "labels", other: root / f"labels_{other}"}
    for folder in (root / "velodyne", *folders.values()):
        folder.mkdir(parents=True, exist_ok=True)
    (root / SIMULATOR_FILE).unlink(missing_ok=True)  # until the last scan is written, the folder is no such drive
    write_convention_file(root, convention)
    write_sweep_file(root, sim.preset.effects.intra_sweep_motion)
    movers = sim.traffic.observed_movers(sim.lidar.max_range)
    stats = SequenceStats(name)
    agents = {a.inst: a for a in sim.traffic.agents}
    parked = set(sim.static.parked_ids.tolist())
    period = sim.preset.scan_period
    poses, times = [], []
    ego_x, ego_y = sim.traffic.ego_x, sim.traffic.ego_y
    for item in sim:
        k = item.index
        if not np.isfinite(item.scan.points).all():  # never expected; a NaN must not reach a file
            raise DatasetError(f"sequence {name} scan {k}: non-finite point coordinates")
        write_scan(root / "velodyne" / f"{k:06d}.bin", item.scan.points, item.scan.remission)
        write_label(folders[INSTANT] / f"{k:06d}.label", item.scan.labels)
        write_label(folders[SEMANTICKITTI] / f"{k:06d}.label", relabel_movers(item.scan.labels, movers))
        poses.append(item.pose)
        times.append(item.time)
        ego_speed = float(np.hypot(ego_x[k + 1] - ego_x[k], ego_y[k + 1] - ego_y[k]) / period)
        stats.add_scan(item.scan, agents, parked, k, ego_speed, period)
        if progress is not None:
            progress(1)
    write_poses(root / "poses.txt", np.asarray(poses))
    write_calib(root / "calib.txt")
    write_times(root / "times.txt", np.asarray(times))
    (root / SIMULATOR_FILE).write_text(simulator_fingerprint(sim.preset, sim.sensor, seed, name, n_scans) + "\n")
    stats.seconds = time.perf_counter() - start
    return stats


def iter_sequence_scans(
    seq_dir: str | Path, epoch_ns: int = BAG_EPOCH_NS
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(stamp_ns, points, intensity) of every scan of a written sequence, for a bag writer."""
    seq = SemanticKittiSequence(seq_dir)
    for frame in seq:
        stamp = epoch_ns + int(round(frame.timestamp * 1e9))
        yield stamp, frame.points, frame.remission


def write_sequence_bag(seq_dir: str | Path, bag_path: str | Path, topic: str = "/points",
                       frame_id: str = "velodyne", storage: str = "mcap") -> int:
    """Write a simulated (or any SemanticKITTI) sequence as a rosbag2 bag of PointCloud2; returns the message count."""
    from ros2_mos.io.bags import write_scans_bag

    return write_scans_bag(bag_path, iter_sequence_scans(seq_dir), topic=topic, frame_id=frame_id, storage=storage)
