"""``ros2-mos adapt``: fit a shipped model to a user's own unlabelled drives.

The steps (:func:`adapt`), each resumable from what the work folder already holds:

1. **Labels**: ``autolabel`` each drive (instant convention: the online network learns the motion it can see;
   :mod:`ros2_mos.offline.autolabel`), cached in the work folder.
2. **Data**: each drive becomes two training sequences, its first part to train on and its last ``holdout`` share
   to choose the epoch and the threshold on; the scans stay where they are (links), the labels and the drive's
   KISS-ICP poses are written beside them, so the trainer builds the network inputs with the node's own residual
   and free-space code. Simulated drives of the same sensor are mixed in, so what the simulator taught is kept.
3. **Fine-tuning** from BASE's checkpoint (the one its ``training_config`` names), with BASE's recipe and a short
   schedule; resumes from the work folder's ``last.pt`` after an interruption.
4. **Export** of the best epoch (by IoU on the held-out real scans against their automatic labels, and on held-out
   simulated drives, so that the automatic labels alone do not set it), the moving threshold recalibrated on the same
   scans, and the adaptation recorded in the model's metadata.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.deskew import check_deskew_mode
from ros2_mos.core.errors import ConfigError, DatasetError, ModelError
from ros2_mos.io.semantic_kitti import write_calib, write_label, write_poses, write_scan, write_times

if TYPE_CHECKING:
    from ros2_mos.offline.autolabel import AutolabelConfig
    from ros2_mos.training.trainer import TrainConfig

#: Fewer real scans than this are too few to adapt on.
MIN_REAL_SCANS = 30
#: Below this many real scans the plan warns: adapted on 54 real scans (08b, r1) the HDL-64E model labelled an unseen
#: drive (r2) worse, precision 45.7 -> 21.7 %; on 186 (08b, r2) it labelled the unseen r1 better
#: (benchmarks/adaptation.md, leave-one-drive-out).
RECOMMENDED_REAL_SCANS = 150
#: Wall seconds per training sample (one cropped scan, forward and backward) and per scan prepared (autolabelled,
#: simulated, cached) on the 2-core development machine, for the plan's minutes: the HDL-64E model, 256-column crops,
#: 208 real + 240 simulated scans, 6 epochs took 2.5 min (benchmarks/adaptation.md).
SECONDS_PER_SAMPLE = 0.035
SECONDS_PER_PREPARED_SCAN = 0.11


@dataclass(frozen=True)
class AdaptConfig:
    epochs: int = 6
    holdout: float = 0.25  # the last share of each drive's scans, never trained on
    sim_drives: int = 4  # simulated drives of the same sensor mixed in ...
    sim_scans: int = 60  # ... of this many scans each
    sim_holdout: int = 2  # and simulated drives held out beside the real scans (epoch and threshold)
    sim_seed: int = 700  # never used by the suite (9xxx) or the recipes (100)
    lr: float = 3e-4
    batch_size: int = 8
    crop_width: int = 256
    max_minutes: float = 50.0
    #: autolabel's ``--deskew`` for the drives' labels: 'auto' (where a drive says its sweeps are skewed), 'on'
    #: (sweeps no driver compensated: KITTI raw's), 'off' (``AutolabelConfig.deskew``)
    deskew: str = "auto"

    def __post_init__(self) -> None:
        check_deskew_mode(self.deskew, "adapt")
        for name in ("epochs", "sim_drives", "sim_scans", "sim_holdout", "batch_size", "crop_width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (
                    0 if name in ("sim_drives", "sim_holdout") else 1):
                raise ConfigError(f"adapt: {name} must be a positive integer, got {value!r}")
        for name in ("holdout", "lr", "max_minutes"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"adapt: {name} must be a positive finite number, got {value!r}")
        if not self.holdout < 0.9:
            raise ConfigError(f"adapt: holdout must be below 0.9, got {self.holdout}")


@dataclass
class DrivePlan:
    name: str
    scans: int
    train: int
    holdout: int


@dataclass
class AdaptPlan:
    base_model: Path
    base_checkpoint: Path
    base_config: Path
    sensor: SensorConfig
    drives: list[DrivePlan]
    config: AdaptConfig

    @property
    def real_train(self) -> int:
        return sum(d.train for d in self.drives)

    @property
    def sim_train(self) -> int:
        return self.config.sim_drives * self.config.sim_scans

    def expected_minutes(self) -> float:
        prepared = (sum(d.scans for d in self.drives) * 2  # autolabel + cache
                    + self.sim_train + self.config.sim_holdout * self.config.sim_scans)  # simulate + cache
        samples = (self.real_train + self.sim_train) * self.config.epochs
        return (prepared * SECONDS_PER_PREPARED_SCAN + samples * SECONDS_PER_SAMPLE) / 60.0

    @property
    def warnings(self) -> list[str]:
        """What makes the plan doubtful (the CLI prints them with the plan)."""
        total = sum(d.scans for d in self.drives)
        if total < RECOMMENDED_REAL_SCANS:
            return [f"only {total} real scans: adapted on this few, a model has labelled unseen drives worse than "
                    f"its base (benchmarks/adaptation.md); {RECOMMENDED_REAL_SCANS} or more are recommended, and "
                    "check the adapted model on a drive it was not adapted on before you use it"]
        return []

    def describe(self) -> str:
        lines = [f"base {self.base_model.name} ({self.sensor.name}), fine-tuned from {self.base_checkpoint} "
                 f"with {self.base_config}'s recipe"]
        for d in self.drives:
            lines.append(f"  {d.name}: {d.scans} scans: train on {d.train}, hold out the last {d.holdout}")
        lines.append(f"  + {self.config.sim_drives} simulated {self.sensor.name} drives x {self.config.sim_scans} "
                     f"scans (seed {self.config.sim_seed}) to train on, {self.config.sim_holdout} held out")
        lines.append(f"{self.config.epochs} epochs x {self.real_train + self.sim_train} scans (crops "
                     f"{self.config.crop_width} columns), about {self.expected_minutes():.0f} minutes on 2 cores "
                     f"(at most {self.config.max_minutes:g} of training)")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


#: The source checkout: ``configs/`` and ``checkpoints/`` of the shipped models.
REPO_ROOT = Path(__file__).resolve().parents[2]


def base_checkpoint(model: Path, root: Path = REPO_ROOT) -> tuple[Path, Path]:
    """(checkpoint, training config) BASE was exported from: the config its metadata names (relative to
    ``root``), the checkpoint of that config kept in ``root/checkpoints/`` (``<config stem>_best.pt`` or
    ``_last.pt``)."""
    from ros2_mos.core.metadata import read_training_config

    config = read_training_config(model)
    if not config:
        raise ModelError(f"{model}: its metadata names no training_config, so there is no checkpoint to fine-tune "
                         "(adapt starts from a shipped model or one exported by `ros2-mos train`)")
    config_path = root / config
    for name in (f"{Path(config).stem}_best.pt", f"{Path(config).stem}_last.pt"):
        if (root / "checkpoints" / name).is_file() and config_path.is_file():
            return root / "checkpoints" / name, config_path
    raise ModelError(f"{model}: no checkpoint for {config} in {root / 'checkpoints'} (needs a source checkout)")


def plan_adaptation(drives: list, model: Path, sensor: SensorConfig, config: AdaptConfig,
                    root: Path = REPO_ROOT) -> AdaptPlan:
    """Check the inputs and say what :func:`adapt` will do; raises on mixed sensors, too few scans, another
    sensor's BASE."""
    from ros2_mos.core.inference import MosModel

    names = [d.name for d in drives]
    if len(set(names)) != len(names):
        raise DatasetError(f"drive names repeat: {' '.join(names)}")
    base = MosModel(str(model))
    if base.metadata.sensor.name != sensor.name:
        raise ModelError(f"the base model {model.name} is for the {base.metadata.sensor.name}, the drives are "
                         f"{sensor.name} scans: give --model for {sensor.name} (or --sensor)")
    checkpoint, recipe = base_checkpoint(model, root)
    plans = []
    for d in drives:
        n = len(d)
        holdout = max(1, int(round(config.holdout * n)))
        plans.append(DrivePlan(d.name, n, n - holdout, holdout))
    total = sum(p.scans for p in plans)
    if total < MIN_REAL_SCANS:
        raise DatasetError(f"{total} real scans; adapt needs at least {MIN_REAL_SCANS}")
    return AdaptPlan(model, checkpoint, recipe, sensor, plans, config)


def _check_sensor(drive, sensor: SensorConfig) -> None:
    from ros2_mos.core.sensor_check import mismatch_message

    first = next(iter(drive))
    problem = mismatch_message(first.points, sensor)
    if problem:
        raise DatasetError(f"{drive.name}: {problem}")


def _write_part(folder: Path, scan_paths: list[Path], labels: list[Path], poses: np.ndarray,
                times: np.ndarray) -> None:
    """A SemanticKITTI folder of existing scans (links), autolabel's labels, poses and times."""
    (folder / "velodyne").mkdir(parents=True, exist_ok=True)
    for i, (scan, label) in enumerate(zip(scan_paths, labels)):
        link = folder / "velodyne" / f"{i:06d}.bin"
        if not link.exists():
            os.symlink(os.path.abspath(scan), link)
        write_label(folder / "labels" / f"{i:06d}.label", np.fromfile(label, np.uint32))
    write_calib(folder / "calib.txt")
    write_poses(folder / "poses.txt", poses)
    write_times(folder / "times.txt", times - times[0])


#: Beside each drive's cached labels: what they were made from (:func:`labels_made_from`).
LABELS_MADE_FROM = "labels_made_from.json"


def labels_made_from(drive, config: AutolabelConfig | None = None) -> dict:
    """What a drive's automatic labels depend on: the drive (where it is, how many scans), the autolabel rules
    (``config``, default ones where None) and the package version (the online cue's model ships with it). A resumed
    work folder must hold labels made from the same."""
    from ros2_mos import __version__
    from ros2_mos.offline.autolabel import AutolabelConfig

    where = drive.sequence.root if hasattr(drive, "sequence") else drive.path
    rules = config if config is not None else AutolabelConfig()
    made_from = {"drive": str(Path(where).resolve()), "scans": len(drive),
                 "autolabel": dataclasses.asdict(rules), "ros2_mos": __version__}
    return json.loads(json.dumps(made_from))  # tuples as lists, as they read back


def prepare_real(drive, sensor: SensorConfig, work: Path, plan: DrivePlan,
                 progress: Callable[[str, int], None], deskew: str = "auto") -> tuple[str, str]:
    """Autolabel a drive (cached; ``deskew``: :class:`AdaptConfig`'s) and split it into a train and a holdout
    sequence under ``work/data``."""
    from ros2_mos.io.semantic_kitti import read_poses
    from ros2_mos.offline.autolabel import AutolabelConfig, autolabel_drive

    labels_root = work / "autolabel"
    labelled = labels_root / "sequences" / drive.name
    rules = AutolabelConfig(deskew=deskew)
    made_from = labels_made_from(drive, rules)
    stamp = labelled / LABELS_MADE_FROM
    if not (labelled / "poses.txt").is_file():
        autolabel_drive(drive, labels_root, sensor, "instant", rules, progress=progress)
        stamp.write_text(json.dumps(made_from, indent=1) + "\n")
    elif not stamp.is_file() or json.loads(stamp.read_text()) != made_from:
        raise DatasetError(f"{work}: its labels for {drive.name} were made from another drive or by other autolabel "
                           f"rules ({stamp.name}); remove the work folder or choose another --work")
    scans_dir = work / "scans" / drive.name
    if hasattr(drive, "sequence"):
        scan_paths = list(drive.sequence.scan_files)
    else:  # a bag: its clouds as .bin files once
        scan_paths = [scans_dir / f"{i:06d}.bin" for i in range(len(drive))]
        if not all(p.is_file() for p in scan_paths):
            for scan in drive:
                write_scan(scan_paths[scan.index], scan.points, scan.intensity)
    from ros2_mos.io.semantic_kitti import KITTI_TR, read_times

    poses = read_poses(labelled / "poses.txt", KITTI_TR)
    times = read_times(labelled / "times.txt")
    labels = sorted((labelled / "predictions").glob("*.label"))
    names = (f"{drive.name}_train", f"{drive.name}_holdout")
    cut = plan.train
    data = work / "data" / "sequences"
    if not (data / names[1] / "times.txt").is_file():
        _write_part(data / names[0], scan_paths[:cut], labels[:cut], poses[:cut], times[:cut])
        _write_part(data / names[1], scan_paths[cut:], labels[cut:], poses[cut:], times[cut:])
    return names


def recipe_share_drives(recipe: TrainConfig, drawn: list[str], count: int) -> list[bool]:
    """Which of ``count`` simulated drives are drawn as the ``drawn`` sequences of the base recipe were (on narrow
    streets: ``sim_narrow_streets``; with parked vans: ``sim_parked_vans``): the share of its training drives that
    were, spread evenly (drive i is when ``floor((i + 1) * share)`` steps up)."""
    train = set(recipe.train_sequences)
    share = len(train & set(drawn)) / len(train) if train else 0.0
    return [int((i + 1) * share) > int(i * share) for i in range(count)]


def prepare_simulated(sensor: SensorConfig, work: Path, config: AdaptConfig, recipe: TrainConfig,
                      progress: Callable[[str, int], None]) -> tuple[list[str], list[str]]:
    """Simulated drives of the same sensor (instant labels, randomised sensor effects), drawn as the base's recipe
    drew its training drives (large trees, beam layout, the shares on narrow streets and with parked vans), written
    once: (to train on, held out). A drive there already that this simulator did not write with these settings to
    its end (its ``simulator.txt``: another ``sim_seed`` or ``sim_scans``, another version of the simulator, or cut
    short) is simulated anew."""
    from ros2_mos.sim import sim_preset, simulate_sequence
    from ros2_mos.sim.presets import randomized_for_sequence
    from ros2_mos.sim.writer import made_by_this_simulator

    presets = ("benchmark", "traffic_jam", "easy")
    names = [f"sim{i:02d}" for i in range(config.sim_drives)] + [f"simv{i}" for i in range(config.sim_holdout)]
    narrow = recipe_share_drives(recipe, recipe.sim_narrow_streets, len(names))
    vans = recipe_share_drives(recipe, recipe.sim_parked_vans, len(names))
    for i, name in enumerate(names):
        preset = randomized_for_sequence(sim_preset(presets[i % len(presets)]), config.sim_seed, name,
                                         large_trees=recipe.sim_large_trees, beam_layout=recipe.sim_beam_layout,
                                         narrow_street=narrow[i], parked_vans=vans[i])
        folder = work / "data" / "sequences" / name
        if made_by_this_simulator(folder, preset, sensor, config.sim_seed + i, config.sim_scans):
            continue
        if folder.exists():
            shutil.rmtree(folder)
        simulate_sequence(work / "data", name, config.sim_scans, preset, config.sim_seed + i, sensor,
                          progress=lambda n: progress("simulate", n), convention="instant")
    return names[: config.sim_drives], names[config.sim_drives:]


@dataclass
class AdaptResult:
    model: Path
    best_epoch: int
    best_valid_iou: float
    threshold: float
    minutes: float


def adapt(drives: list, out: Path, plan: AdaptPlan, work: Path,
          progress: Callable[[str, int], None] = lambda stage, n: None,
          log: Callable[[str], None] = lambda s: None, show_progress: bool = True) -> AdaptResult:
    """Run the plan (see the module's docstring); writes the adapted ONNX model to ``out``."""
    from ros2_mos.core.config import MosConfig
    from ros2_mos.core.metadata import write_recommended_threshold
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence
    from ros2_mos.scoring.calibration import threshold_curve
    from ros2_mos.training.trainer import TrainConfig, Trainer, export_checkpoint

    start = time.monotonic()
    cfg = plan.config
    for drive in drives:
        _check_sensor(drive, plan.sensor)
    train, holdout = [], []
    for drive, drive_plan in zip(drives, plan.drives):
        a, b = prepare_real(drive, plan.sensor, work, drive_plan, progress, cfg.deskew)
        train.append(a)
        holdout.append(b)
    recipe = TrainConfig.from_yaml(plan.base_config)
    sim, sim_holdout = prepare_simulated(plan.sensor, work, cfg, recipe, progress)
    holdout += sim_holdout
    train_config = dataclasses.replace(
        recipe, name=f"{recipe.name}-adapted", train_sequences=train + sim, valid_sequences=holdout,
        poses="dataset", cache_dir=str(work / "cache"), out_dir=str(work / "run"), init_from=str(plan.base_checkpoint),
        epochs=cfg.epochs, max_minutes=cfg.max_minutes, lr=cfg.lr, warmup_epochs=0.0, batch_size=cfg.batch_size,
        crop_width=cfg.crop_width, valid_stride=1, full_history_only=False, fit_statistics=False, threads=0)
    trainer = Trainer(train_config, work / "data", log=log, show_progress=show_progress)
    history = trainer.fit()
    best_path = work / "run" / "best.pt"
    if not best_path.is_file():
        raise DatasetError(f"training wrote no {best_path}")
    valid = [h for h in history if h.valid_iou == h.valid_iou]
    best = max(valid, key=lambda h: h.valid_iou) if valid else None
    record = {"drives": [d.name for d in plan.drives], "real_scans_trained": plan.real_train,
              "labels": "ros2-mos autolabel, instant convention", "base": plan.base_model.name,
              "simulated_drives": cfg.sim_drives, "epochs": cfg.epochs}
    recipe_path = plan.base_config.resolve().relative_to(plan.base_config.resolve().parents[1])
    tmp = out.with_name(out.name + ".partial")
    export_checkpoint(best_path, tmp, extra={"adaptation": json.dumps(record), "training_config": str(recipe_path)})
    pipeline = MosPipeline(MosConfig(model=str(tmp)))
    curve = threshold_curve(pipeline, [SemanticKittiSequence(work / "data" / "sequences" / h) for h in holdout],
                            use_dataset_poses=False)
    pipeline.close()
    threshold, _ = curve.best()
    threshold = float(min(max(threshold, 0.05), 0.95))
    write_recommended_threshold(tmp, threshold)
    os.replace(tmp, out)
    return AdaptResult(out, best.epoch if best else -1, best.valid_iou if best else float("nan"), threshold,
                       (time.monotonic() - start) / 60.0)
