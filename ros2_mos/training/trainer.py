"""The training loop: config, optimiser with warm-up + per-epoch decay, validation, checkpoints, resume.

One process on the CPU by default; under ``torchrun`` (``WORLD_SIZE`` set) it runs
DistributedDataParallel, one process per GPU (NCCL) or per CPU worker (gloo), and
only rank 0 validates, logs and writes checkpoints.

Outputs in ``out_dir``: ``last.pt`` (every epoch, for resume), ``best.pt`` (best
valid IoU), ``metrics.csv`` (one row per epoch) and ``config.yaml`` (what ran).
A checkpoint holds the network name/kwargs, the input setup, sensor, means/stds,
class weights and the valid IoU — everything :func:`export_checkpoint` needs.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader

from ros2_mos.core.config import (
    DEFAULT_RESIDUAL_MAX_RANGE,
    ResidualConfig,
    SensorConfig,
    read_yaml_mapping,
    sensor_preset,
)
from ros2_mos.core.errors import ConfigError, DatasetError
from ros2_mos.core.metadata import ModelMetadata
from ros2_mos.core.network_input import InputSetup
from ros2_mos.io.semantic_kitti import sequence_dirs
from ros2_mos.scoring.metrics import MovingIoU
from ros2_mos.training.dataset import (
    AugmentConfig,
    CacheSpec,
    MosDataset,
    build_caches,
    channel_statistics,
    class_counts,
)
from ros2_mos.training.losses import MosLoss, inverse_frequency_weights
from ros2_mos.training.nets import build_network

CHECKPOINT_FORMAT = 1


@dataclass
class TrainConfig:
    """Everything one training run needs; loaded from YAML (see ``configs/``).

    Defaults follow LiDAR-MOS/SalsaNext where they apply to a CPU (SGD momentum 0.9,
    weight decay 1e-4, 1 warm-up epoch, x0.99 per epoch), with fewer epochs.
    """

    name: str = "mos"
    network: str = "fastmos"
    network_kwargs: dict[str, Any] = field(default_factory=dict)
    input_kind: str = "residual"
    n_past: int = 3
    past_offsets: list[int] = field(default_factory=list)  # empty: 1..n_past
    signed_residuals: bool = False
    free_space: bool = False  # + free-space images at the same offsets (ros2_mos.core.residuals.free_space_image)
    image_channels: list[str] = field(default_factory=lambda: ["range", "x", "y", "z", "remission"])
    pose_noise: list[float] = field(default_factory=lambda: [0.0, 0.0])  # training inputs: σ_t (m), σ_r (deg)
    sensor: str | dict[str, Any] = "hdl64"
    residual_min_range: float = 2.0
    residual_max_range: float = DEFAULT_RESIDUAL_MAX_RANGE
    train_sequences: list[str] = field(
        default_factory=lambda: ["00", "01", "02", "03", "04", "05", "06", "07", "09", "10"])
    valid_sequences: list[str] = field(default_factory=lambda: ["08"])
    poses: str = "dataset"
    cache_dir: str = "data/cache"
    cache_n_residual: int = 8
    # true: cache only the residual images the input uses (its offsets), not every one up to the oldest
    cache_used_offsets_only: bool = False
    cache_n_frames: int = 1
    out_dir: str = "runs/mos"
    epochs: int = 10
    batch_size: int = 4
    optimizer: str = "sgd"
    lr: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 1e-4
    warmup_epochs: float = 1.0
    lr_decay: float = 0.99
    lovasz_weight: float = 1.0
    weight_eps: float = 1e-3
    max_class_weight: float | None = None
    crop_width: int | None = None
    rotate: bool = True
    flip_y: float = 0.5
    drop_max: float = 0.1
    train_stride: int = 1
    # Train only on scans with every past scan the input asks for (scan index >= the largest offset). The first
    # scans of a drive read 0 where a past scan is missing, which is also what a static surface reads; moving
    # labels there teach "a car-shaped blob with zero residuals moves" (benchmarks/experiments.md, row 26).
    full_history_only: bool = False
    valid_stride: int = 1
    workers: int = 0
    cache_workers: int = 2
    threads: int = 0
    seed: int = 0
    max_minutes: float | None = None
    fit_statistics: bool = True
    # Fine-tuning: start from this checkpoint's weights and normalisation (same network and input, or the same
    # input without free_space: the new input channels then start with zero weights; a new schedule from
    # epoch 0). Ignored once out_dir/last.pt exists (the run then resumes as usual).
    init_from: str | None = None
    # Read by tools/train_models.py when it simulates the sequences (ros2_mos.sim.presets.randomized:
    # large, lumpy trees; beams off the nominal grid; the sequences named here on narrow streets, or with parked
    # vans); not by training.
    sim_large_trees: bool = False
    sim_beam_layout: bool = True
    sim_narrow_streets: list[str] = field(default_factory=list)
    sim_parked_vans: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ("sim_narrow_streets", "sim_parked_vans"):
            value = getattr(self, name)
            if not isinstance(value, list) or not all(isinstance(n, str) for n in value):
                raise ConfigError(f"{name} must be a list of sequence names, got {value!r}")
        if self.optimizer not in ("sgd", "adamw"):
            raise ConfigError(f"optimizer must be 'sgd' or 'adamw', got {self.optimizer!r}")
        if self.epochs < 1 or self.batch_size < 1:
            raise ConfigError("epochs and batch_size must be >= 1")
        for name in ("lr", "lr_decay", "momentum", "weight_decay", "warmup_epochs", "lovasz_weight", "weight_eps",
                     "flip_y", "drop_max", "max_class_weight", "max_minutes", "residual_min_range",
                     "residual_max_range"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not math.isfinite(value)):
                raise ConfigError(f"training config: {name} must be a finite number, got {value!r}")
        if self.lr <= 0 or not 0 < self.lr_decay <= 1:
            raise ConfigError("need lr > 0 and 0 < lr_decay <= 1")
        if self.lovasz_weight < 0 or self.weight_decay < 0 or self.warmup_epochs < 0 or self.weight_eps <= 0:
            raise ConfigError("lovasz_weight, weight_decay and warmup_epochs must be >= 0, weight_eps > 0")
        if not 0 <= self.momentum < 1 or not 0 <= self.flip_y <= 1 or not 0 <= self.drop_max < 1:
            raise ConfigError("momentum and drop_max must be in [0, 1), flip_y in [0, 1]")
        if self.max_minutes is not None and self.max_minutes <= 0:
            raise ConfigError(f"max_minutes must be > 0, got {self.max_minutes}")
        if self.max_class_weight is not None and self.max_class_weight <= 0:
            raise ConfigError(f"max_class_weight must be > 0, got {self.max_class_weight}")
        if self.crop_width is not None and self.crop_width < 16:
            raise ConfigError(f"crop_width must be >= 16, got {self.crop_width}")
        if not 0 <= self.residual_min_range < self.residual_max_range:
            raise ConfigError("need 0 <= residual_min_range < residual_max_range")
        if not isinstance(self.full_history_only, bool):
            raise ConfigError(f"full_history_only must be true or false, got {self.full_history_only!r}")
        if self.init_from is not None and (not isinstance(self.init_from, str) or not self.init_from):
            raise ConfigError(f"init_from must be a checkpoint path, got {self.init_from!r}")
        self.setup  # validates kind / n_past / offsets / channels
        self.sensor_config  # validates the sensor
        self.cache_spec  # validates pose_noise

    @property
    def setup(self) -> InputSetup:
        return InputSetup(self.input_kind, self.n_past, tuple(self.past_offsets), self.signed_residuals,
                          tuple(self.image_channels), self.free_space)

    @property
    def sensor_config(self) -> SensorConfig:
        if isinstance(self.sensor, str):
            return sensor_preset(self.sensor)
        return SensorConfig.from_dict(self.sensor)

    @property
    def cache_spec(self) -> CacheSpec:
        return CacheSpec(
            sensor=self.sensor_config,
            residual=ResidualConfig(self.residual_min_range, self.residual_max_range),
            n_residual=max(self.cache_n_residual, self.setup.history if self.input_kind == "residual" else 0),
            n_frames=max(self.cache_n_frames, self.n_past if self.input_kind == "frames" else 0),
            poses=self.poses,
            pose_noise=((float(self.pose_noise[0]), float(self.pose_noise[1])) if len(self.pose_noise) == 2
                        else (-1.0, -1.0)),
            free_space_offsets=self.setup.offsets if self.free_space else (),
            residual_offsets=(self.setup.offsets if self.cache_used_offsets_only and self.input_kind == "residual"
                              else ()),
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "TrainConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ConfigError(f"training config: unknown keys {sorted(unknown)}; allowed: {sorted(names)}")
        data = dict(data)
        for key in ("train_sequences", "valid_sequences"):
            if key in data:
                data[key] = [str(s).zfill(2) if str(s).isdigit() else str(s) for s in data[key]]
        try:
            return cls(**data)
        except TypeError as exc:
            raise ConfigError(f"training config: {exc}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> "TrainConfig":
        return cls.from_dict(read_yaml_mapping(path, "training config"))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class EpochResult:
    epoch: int
    train_loss: float
    train_ce: float
    train_lovasz: float
    lr: float
    valid_iou: float
    valid_loss: float
    seconds: float


class _Dist:
    """torch.distributed state when launched by torchrun, a no-op otherwise."""

    def __init__(self) -> None:
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        self.enabled = self.world > 1
        self.device = torch.device("cpu")
        if self.enabled:
            import torch.distributed as dist

            if torch.cuda.is_available():
                torch.cuda.set_device(self.local_rank)
                self.device = torch.device("cuda", self.local_rank)
                backend = "nccl"
            else:
                backend = "gloo"
            if not dist.is_initialized():
                dist.init_process_group(backend)
        elif torch.cuda.is_available():
            self.device = torch.device("cuda")

    @property
    def main(self) -> bool:
        return self.rank == 0

    def barrier(self) -> None:
        if self.enabled:
            import torch.distributed as dist

            dist.barrier()


def lr_at(config: TrainConfig, epoch_float: float) -> float:
    """Linear warm-up over ``warmup_epochs``, then ``lr * lr_decay ** epoch`` (per-epoch steps)."""
    if config.warmup_epochs > 0 and epoch_float < config.warmup_epochs:
        return config.lr * max(epoch_float / config.warmup_epochs, 1e-3)
    return config.lr * config.lr_decay ** math.floor(epoch_float)


@torch.no_grad()
def evaluate_pixels(model: nn.Module, dataset: MosDataset, loss_fn: MosLoss | None, device: torch.device,
                    batch_size: int = 1, progress: Callable | None = None, workers: int = 0) -> tuple[float, float]:
    """Pixel-level moving IoU (and mean loss) of ``model`` on a dataset, full images, no augmentation."""
    model.eval()
    score = MovingIoU()
    losses: list[float] = []
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=workers)
    iterator = progress(loader) if progress else loader
    for x, y in iterator:
        x, y = x.to(device), y.to(device)
        logits = model(x)
        if loss_fn is not None:
            losses.append(float(loss_fn(logits, y)[0]))
        score.update((logits.argmax(1) == 1).cpu().numpy(), y.cpu().numpy())
    return score.iou, float(np.mean(losses)) if losses else float("nan")


def widen_input(weights: Mapping[str, torch.Tensor], target: Mapping[str, torch.Tensor],
                placement: Sequence[int]) -> dict[str, torch.Tensor]:
    """``weights`` fitted to ``target``'s shapes where a layer reads more input channels there.

    A weight of shape (out, c, ...) whose target is (out, c + k, ...) keeps its c channels' weights at the
    target channels ``placement`` lists (old channel i -> new channel ``placement[i]``) and gets zero weights
    for the k added ones, so the widened network computes exactly what the old one did until training moves
    them. Other shape differences are left for ``load_state_dict`` to report.
    """
    out = {}
    for name, value in weights.items():
        goal = target.get(name)
        if (goal is not None and value.ndim >= 2 and goal.ndim == value.ndim and goal.shape[1] > value.shape[1]
                and value.shape[1] == len(placement) and goal.shape[0] == value.shape[0]
                and goal.shape[2:] == value.shape[2:]):
            wide = torch.zeros(goal.shape, dtype=value.dtype)
            wide[:, list(placement)] = value
            value = wide
        out[name] = value
    return out


def input_placement(trained: InputSetup, setup: InputSetup) -> list[int] | None:
    """Where each input channel of a network trained on ``trained`` sits in ``setup``'s input, when ``setup``
    only adds channels to it (free-space images, more offsets); else None."""
    if (trained.kind, trained.signed) != (setup.kind, setup.signed):
        return None
    names = setup.channel_names
    if not set(trained.channel_names) <= set(names):
        return None
    return [names.index(n) for n in trained.channel_names]


class Trainer:
    """Trains one configuration; ``fit()`` resumes from ``out_dir/last.pt`` when it exists."""

    def __init__(self, config: TrainConfig, data_root: str | Path, log: Callable[[str], None] = lambda s: None,
                 show_progress: bool = True) -> None:
        self.config = config
        self.data_root = Path(data_root)
        self.log = log
        self.show_progress = show_progress
        self.out_dir = Path(config.out_dir)
        self.dist = _Dist()
        random.seed(config.seed)
        np.random.seed(config.seed)
        torch.manual_seed(config.seed)
        if config.threads > 0:
            torch.set_num_threads(config.threads)
        spec = config.cache_spec
        # Rank 0 builds the caches; the others wait and open them.
        train_dirs = sequence_dirs(self.data_root, config.train_sequences)
        valid_dirs = sequence_dirs(self.data_root, config.valid_sequences) if config.valid_sequences else []
        if self.dist.main:
            self.train_caches = build_caches(train_dirs, config.cache_dir, spec, config.cache_workers, log)
            self.valid_caches = build_caches(valid_dirs, config.cache_dir, spec, config.cache_workers, log)
        self.dist.barrier()
        if not self.dist.main:
            self.train_caches = build_caches(train_dirs, config.cache_dir, spec, 1)
            self.valid_caches = build_caches(valid_dirs, config.cache_dir, spec, 1)
        self._init_state = self._load_init() if not (self.out_dir / "last.pt").is_file() else None
        self.means, self.stds = self._statistics()
        counts = class_counts(self.train_caches)
        if counts[1] == 0:
            raise DatasetError("the training sequences contain no moving pixel: nothing to learn")
        weights = inverse_frequency_weights(counts, eps=config.weight_eps)
        if config.max_class_weight is not None:
            weights = np.minimum(weights, config.max_class_weight)
        self.class_counts = counts
        self.class_weights = weights
        setup = config.setup
        augment = AugmentConfig(config.rotate, config.flip_y, config.drop_max, config.crop_width)
        self.train_set = MosDataset(self.train_caches, setup, self.means, self.stds, augment, config.train_stride,
                                    config.seed, first_scan=setup.history if config.full_history_only else 0)
        self.valid_set = MosDataset(self.valid_caches, setup, self.means, self.stds, None, config.valid_stride)
        if len(self.train_set) == 0:
            raise DatasetError("no training scans")
        self.model = build_network(config.network, setup.channels, 2, **config.network_kwargs).to(self.dist.device)
        self.loss_fn = MosLoss(weights, config.lovasz_weight).to(self.dist.device)
        params = self.model.parameters()
        if config.optimizer == "sgd":
            self.optimizer: torch.optim.Optimizer = torch.optim.SGD(
                params, lr=config.lr, momentum=config.momentum, weight_decay=config.weight_decay
            )
        else:
            self.optimizer = torch.optim.AdamW(params, lr=config.lr, weight_decay=config.weight_decay)
        self.start_epoch = 0
        self.best_iou = -1.0
        self.history: list[EpochResult] = []
        if self._init_state is not None:
            weights = self._init_state["model"]
            if self._init_state["placement"] != list(range(self.config.setup.channels)):
                weights = widen_input(weights, self._raw_model().state_dict(), self._init_state["placement"])
            self._raw_model().load_state_dict(weights)
            self.log(f"fine-tuning from {self.config.init_from} (its epoch {int(self._init_state['epoch']) + 1})")
        self._maybe_resume()

    def _load_init(self) -> dict[str, Any] | None:
        """The ``init_from`` checkpoint, checked against this run's network and input."""
        if self.config.init_from is None:
            return None
        path = Path(self.config.init_from)
        state = load_checkpoint(path)
        setup = self.config.setup
        try:
            trained = InputSetup(**dict(state.get("input") or {}))
        except (ConfigError, TypeError):
            trained = None
        placement = None if trained is None else input_placement(trained, setup)
        if state.get("network") != self.config.network or placement is None:
            raise ConfigError(f"init_from {path}: trained as {state.get('network')} {state.get('input')}, not "
                              f"{self.config.network} {asdict(setup)} or a part of it")
        return dict(state, placement=placement)

    def _statistics(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        if self._init_state is not None:  # the weights expect their own normalisation
            return tuple(self._init_state["means"]), tuple(self._init_state["stds"])
        if self.config.fit_statistics:
            return channel_statistics(self.train_caches)
        from ros2_mos.core.network_input import DEFAULT_MEANS, DEFAULT_STDS

        return DEFAULT_MEANS, DEFAULT_STDS

    # -- checkpoints -------------------------------------------------------------------------
    def _raw_model(self) -> nn.Module:
        return self.model.module if hasattr(self.model, "module") else self.model

    def checkpoint_state(self, epoch: int, valid_iou: float) -> dict[str, Any]:
        return {
            "format": CHECKPOINT_FORMAT,
            "epoch": epoch,
            "model": self._raw_model().state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "config": self.config.to_dict(),
            "network": self.config.network,
            "network_kwargs": dict(self.config.network_kwargs),
            "input": asdict(self.config.setup),
            "sensor": self.config.sensor_config.to_dict(),
            "means": list(self.means),
            "stds": list(self.stds),
            "class_weights": self.class_weights.tolist(),
            "class_counts": self.class_counts.tolist(),
            "valid_iou": valid_iou,
            "best_iou": self.best_iou,
            "trained_on": f"{self.data_root.name}: train {','.join(self.config.train_sequences)}; "
            f"valid {','.join(self.config.valid_sequences)}",
            "history": [asdict(h) for h in self.history],
        }

    def _save(self, name: str, state: dict[str, Any]) -> None:
        from ros2_mos.core.atomic import atomic_path

        with atomic_path(self.out_dir / name) as tmp:  # a full disk: OutputError, the last checkpoint kept whole
            torch.save(state, tmp)

    def _maybe_resume(self) -> None:
        last = self.out_dir / "last.pt"
        if not last.is_file():
            return
        state = load_checkpoint(last)
        if state.get("network") != self.config.network or state.get("input") != asdict(self.config.setup):
            raise ConfigError(
                f"{last} was trained as {state.get('network')} {state.get('input')}, not "
                f"{self.config.network} {asdict(self.config.setup)}; use another out_dir"
            )
        self._raw_model().load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.start_epoch = int(state["epoch"]) + 1
        self.best_iou = float(state.get("best_iou", -1.0))
        self.history = [EpochResult(**h) for h in state.get("history", [])]
        self.log(f"resumed from {last} at epoch {self.start_epoch}")

    # -- training ----------------------------------------------------------------------------
    def fit(self) -> list[EpochResult]:
        config = self.config
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel
            from torch.utils.data.distributed import DistributedSampler

            ids = [self.dist.local_rank] if self.dist.device.type == "cuda" else None
            self.model = DistributedDataParallel(self.model, device_ids=ids)
            sampler = DistributedSampler(self.train_set, shuffle=True, seed=config.seed)
        else:
            sampler = None
        if self.dist.main:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            import yaml

            from ros2_mos.core.atomic import write_text_atomically

            write_text_atomically(self.out_dir / "config.yaml", yaml.safe_dump(config.to_dict(), sort_keys=False))
        started = time.monotonic()
        generator = torch.Generator().manual_seed(config.seed)
        for epoch in range(self.start_epoch, config.epochs):
            self.train_set.set_epoch(epoch)
            if sampler is not None:
                sampler.set_epoch(epoch)
            loader = DataLoader(
                self.train_set,
                batch_size=config.batch_size,
                shuffle=sampler is None,
                sampler=sampler,
                num_workers=config.workers,
                drop_last=len(self.train_set) > config.batch_size,
                generator=generator,
                persistent_workers=False,
            )
            t0 = time.monotonic()
            result = self._train_epoch(epoch, loader)
            if self.dist.main:
                valid_iou, valid_loss = (float("nan"), float("nan"))
                if len(self.valid_set):
                    valid_iou, valid_loss = evaluate_pixels(self._raw_model(), self.valid_set, self.loss_fn,
                                                            self.dist.device, workers=config.workers)
                result = dataclasses.replace(result, valid_iou=valid_iou, valid_loss=valid_loss,
                                             seconds=time.monotonic() - t0)
                self.history.append(result)
                self._write_csv(result)
                score = valid_iou if not math.isnan(valid_iou) else -result.train_loss
                improved = score > self.best_iou
                if improved:
                    self.best_iou = score
                state = self.checkpoint_state(epoch, valid_iou)
                self._save("last.pt", state)
                if improved:
                    self._save("best.pt", state)
                self.log(
                    f"epoch {epoch + 1}/{config.epochs}: loss {result.train_loss:.4f} (ce {result.train_ce:.4f}, "
                    f"lovasz {result.train_lovasz:.4f}) lr {result.lr:.2e} valid IoU {valid_iou:.4f} "
                    f"[{result.seconds:.0f} s]"
                )
            self.dist.barrier()
            if config.max_minutes is not None and (time.monotonic() - started) / 60 > config.max_minutes:
                self.log(f"stopping after epoch {epoch + 1}: max_minutes={config.max_minutes} reached")
                break
        return self.history

    def _train_epoch(self, epoch: int, loader: DataLoader) -> EpochResult:
        self.model.train()
        n_iter = max(1, len(loader))
        sums = np.zeros(3)
        count = 0
        iterator: Any = loader
        bar = None
        if self.dist.main and self.show_progress:
            from tqdm import tqdm

            bar = tqdm(loader, desc=f"epoch {epoch + 1}/{self.config.epochs}", leave=False, dynamic_ncols=True)
            iterator = bar
        lr = self.config.lr
        for it, (x, y) in enumerate(iterator):
            lr = lr_at(self.config, epoch + it / n_iter)
            for group in self.optimizer.param_groups:
                group["lr"] = lr
            x, y = x.to(self.dist.device, non_blocking=True), y.to(self.dist.device, non_blocking=True)
            logits = self.model(x)
            loss, ce, lov = self.loss_fn(logits, y)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            sums += (loss.item(), ce.item(), lov.item())
            count += 1
            if bar is not None:
                bar.set_postfix(loss=f"{sums[0] / count:.4f}", lr=f"{lr:.1e}",
                                best_iou=f"{max(self.best_iou, 0):.3f}")
        if bar is not None:
            bar.close()
        mean = sums / max(count, 1)
        return EpochResult(epoch + 1, float(mean[0]), float(mean[1]), float(mean[2]), lr, float("nan"), float("nan"),
                           0.0)

    def _write_csv(self, result: EpochResult) -> None:
        path = self.out_dir / "metrics.csv"
        new = not path.is_file()
        with path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(asdict(result)))
            if new:
                writer.writeheader()
            writer.writerow(asdict(result))

    def metadata(self, valid_iou: float | None) -> ModelMetadata:
        return metadata_from_checkpoint(self.checkpoint_state(max(self.start_epoch - 1, 0), valid_iou or float("nan")))


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # truncated zip, zeroed or random bytes: torch raises many types
        first_line = (str(exc).splitlines() or [""])[0][:120]
        raise ConfigError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {first_line})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ConfigError(f"{path} is not a ros2_mos training checkpoint")
    return state


def model_from_checkpoint(state: Mapping[str, Any]) -> nn.Module:
    setup = InputSetup(**state["input"])
    model = build_network(state["network"], setup.channels, 2, **state.get("network_kwargs", {}))
    model.load_state_dict(state["model"])
    return model.eval()


def metadata_from_checkpoint(state: Mapping[str, Any]) -> ModelMetadata:
    iou = state.get("valid_iou")
    return ModelMetadata(
        network=state["network"],
        input=InputSetup(**state["input"]),
        sensor=SensorConfig.from_dict(state["sensor"]),
        means=tuple(float(v) for v in state["means"]),
        stds=tuple(float(v) for v in state["stds"]),
        trained_on=state.get("trained_on", ""),
        valid_iou=None if iou is None or (isinstance(iou, float) and math.isnan(iou)) else float(iou),
        extra={
            "epoch": int(state["epoch"]) + 1,
            "network_kwargs": dict(state.get("network_kwargs", {})),
            "class_weights": list(state.get("class_weights", [])),
            "valid_iou_kind": "pixel IoU on the validation sequences (range image, no kNN)",
            # The residual window's far end it was trained with: the pipeline computes its residuals out to it.
            "residual_max_range": float(state.get("config", {}).get("residual_max_range", DEFAULT_RESIDUAL_MAX_RANGE)),
        },
    )


def export_checkpoint(checkpoint: str | Path, out: str | Path, sensor: SensorConfig | None = None,
                      extra: Mapping[str, Any] | None = None):
    """Export a training checkpoint to ONNX with its metadata (optionally for another image size).

    ``extra`` entries are added to the metadata's ``extra`` (e.g. a validation-tuned
    ``recommended_threshold``).
    """
    from ros2_mos.training.export import export_onnx

    state = load_checkpoint(checkpoint)
    model = model_from_checkpoint(state)
    meta = metadata_from_checkpoint(state)
    if sensor is not None:
        meta = dataclasses.replace(meta, sensor=sensor)
    if extra:
        meta.extra.update(extra)
    return export_onnx(model, meta, out)
