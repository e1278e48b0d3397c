"""The paper's ablation on held-out sequences: baselines, input setups and networks, as one table.

Every row is scored the way the MOS benchmark scores a submission: per *point*
moving IoU (:class:`~ros2_mos.scoring.metrics.MovingIoU`, counts accumulated over all test
scans) after the node's own kNN back-projection (:func:`~ros2_mos.core.postprocess.backproject`),
on test sequences no model or threshold was fitted on.  CNN rows are trained by
:class:`~ros2_mos.training.trainer.Trainer` from one base config with only the input
setup / network changed (and resumed if their run folder already holds the run);
baseline thresholds are tuned on the validation sequences.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ros2_mos.core.config import PostprocessConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.network_input import IMAGE_CHANNELS, InputSetup
from ros2_mos.core.postprocess import backproject
from ros2_mos.core.projection import PixelIndex
from ros2_mos.io.semantic_kitti import sequence_dirs
from ros2_mos.scoring.metrics import MovingIoU
from ros2_mos.training.baselines import tune_region_growing, tune_residual_threshold
from ros2_mos.training.dataset import MosDataset, SequenceCache, build_caches
from ros2_mos.training.trainer import TrainConfig, Trainer, load_checkpoint, model_from_checkpoint


@dataclass(frozen=True)
class Variant:
    """One CNN row: a network and an input setup (e.g. 'fastmos', residual N=8).

    ``past_offsets`` picks which past scans the residuals use (empty: 1..n_past).
    """

    network: str
    kind: str
    n_past: int
    past_offsets: tuple[int, ...] = ()

    @property
    def slug(self) -> str:
        if self.past_offsets:
            return f"{self.network}-{self.kind}" + "-".join(str(o) for o in self.past_offsets)
        return f"{self.network}-{self.kind}{self.n_past}"

    def training_config(self, base: TrainConfig, runs_dir: str | Path) -> TrainConfig:
        """``base`` with this row's network and input.

        Residual rows keep the base's residual sign and image channels (the recipe under test); frame rows
        (and one frame, residual N=0) take all five image channels, as in the paper.
        """
        residual = self.kind == "residual" and self.n_past > 0
        return dataclasses.replace(
            base,
            name=self.slug,
            network=self.network,
            network_kwargs=base.network_kwargs if self.network == base.network else {},
            input_kind=self.kind,
            n_past=self.n_past,
            past_offsets=list(self.past_offsets),
            signed_residuals=base.signed_residuals and residual,
            image_channels=list(base.image_channels) if residual else list(IMAGE_CHANNELS),
            out_dir=str(Path(runs_dir) / self.slug),
            init_from=None,
        )

    @classmethod
    def parse(cls, text: str) -> "Variant":
        """'fastmos:residual:8', 'fastmos:frames:1', 'salsanext:residual:1' or 'fastmos:residual:1,2,4,8'."""
        parts = text.split(":")
        offsets = parts[2].split(",") if len(parts) == 3 else []
        if len(parts) != 3 or not all(o.isdigit() for o in offsets) or parts[1] not in ("residual", "frames"):
            raise ConfigError(f"variant {text!r} must look like NETWORK:residual|frames:N or "
                              "NETWORK:residual:O1,O2,... (offsets of the past scans)")
        if len(offsets) == 1:
            return cls(parts[0], parts[1], int(offsets[0]))
        past_offsets = tuple(int(o) for o in offsets)
        InputSetup(parts[1], len(past_offsets), past_offsets)  # validates the offsets
        return cls(parts[0], parts[1], len(past_offsets), past_offsets)


@dataclass
class Row:
    method: str
    input: str
    iou: float
    detail: str = ""
    train_minutes: float | None = None


def evaluate_point_iou(
    caches: Sequence[SequenceCache],
    predict: Callable[[SequenceCache, int], np.ndarray],
    postprocess: PostprocessConfig = PostprocessConfig(),
    threshold: float = 0.5,
    stride: int = 1,
) -> MovingIoU:
    """Point moving IoU over test caches (built ``with_points``) of a per-pixel probability predictor.

    ``stride`` > 1 scores every stride-th scan only (the residuals still use every past scan).
    """
    score = MovingIoU()
    for cache in caches:
        for i in range(0, len(cache), max(1, stride)):
            prob = np.asarray(predict(cache, i), np.float32)
            pts = cache.points(i)
            pixels = PixelIndex(pts["u"].astype(np.int32), pts["v"].astype(np.int32), pts["range"], pts["in_image"])
            rng = np.asarray(cache.frame[i, 0], np.float32)
            point_prob = backproject(prob, rng, pixels, postprocess)
            score.update(point_prob >= threshold, pts["classes"])
    return score


def network_predictor(model: torch.nn.Module, caches: Sequence[SequenceCache], setup: InputSetup,
                      means: Sequence[float], stds: Sequence[float]) -> Callable[[SequenceCache, int], np.ndarray]:
    """Moving probability image of a trained network on a cached scan (no augmentation)."""
    datasets = {id(c): MosDataset([c], setup, means, stds) for c in caches}
    model.eval()

    @torch.no_grad()
    def predict(cache: SequenceCache, index: int) -> np.ndarray:
        x, _ = datasets[id(cache)][index]
        return torch.softmax(model(x[None]), dim=1)[0, 1].numpy()

    return predict


def run_ablation(
    base: TrainConfig,
    data_root: str | Path,
    test_sequences: list[str],
    variants: Sequence[Variant],
    runs_dir: str | Path,
    baselines: bool = True,
    log: Callable[[str], None] = lambda s: None,
    show_progress: bool = False,
    test_stride: int = 1,
    test_root: str | Path | None = None,
) -> list[Row]:
    """Train (or resume) each variant, tune the baselines, and score everything on the test sequences.

    The test sequences are read from ``test_root`` (default: ``data_root``).
    """
    spec = dataclasses.replace(base.cache_spec, with_points=True)
    test_dirs = sequence_dirs(data_root if test_root is None else test_root, test_sequences)
    test_caches = build_caches(test_dirs, base.cache_dir, spec, base.cache_workers, log)
    rows: list[Row] = []
    if baselines:
        valid_spec = base.cache_spec
        valid_caches = build_caches(sequence_dirs(data_root, base.valid_sequences), base.cache_dir, valid_spec,
                                    base.cache_workers, log)
        t0 = time.monotonic()
        thr, _ = tune_residual_threshold(valid_caches, [0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.2])
        score = evaluate_point_iou(test_caches, lambda c, i: thr.predict(c, i).astype(np.float32), stride=test_stride)
        rows.append(Row("Residual (threshold d_1)", "residual N=1", score.iou, f"tau={thr.tau} (tuned on valid)"))
        log(f"Residual baseline: IoU {100 * score.iou:.1f} ({time.monotonic() - t0:.0f} s)")
        t0 = time.monotonic()
        rg, _ = tune_region_growing(valid_caches, [0.1, 0.2, 0.4], [0.03, 0.06], [0.1, 0.3, 0.5])
        score = evaluate_point_iou(test_caches, lambda c, i: rg.predict(c, i).astype(np.float32), stride=test_stride)
        rows.append(Row("Residual + RG (free space + region growing)", "residual N=2", score.iou,
                        f"tau={rg.tau_seed}, jump={rg.rel_jump}, frac={rg.seed_fraction} (tuned on valid)"))
        log(f"Residual + RG baseline: IoU {100 * score.iou:.1f} ({time.monotonic() - t0:.0f} s)")
    for variant in variants:
        config = variant.training_config(base, runs_dir)
        t0 = time.monotonic()
        trainer = Trainer(config, data_root, log=log, show_progress=show_progress)
        history = trainer.fit()
        minutes = sum(h.seconds for h in history) / 60.0
        state = load_checkpoint(Path(config.out_dir) / "best.pt")
        model = model_from_checkpoint(state)
        predict = network_predictor(model, test_caches, config.setup, state["means"], state["stds"])
        score = evaluate_point_iou(test_caches, predict, stride=test_stride)
        valid = state.get("valid_iou", float("nan"))
        rows.append(Row(variant.network, config.setup.label, score.iou,
                        f"epochs {state['epoch'] + 1}, valid pixel IoU {100 * valid:.1f}", minutes))
        log(f"{variant.slug}: test IoU {100 * score.iou:.1f} ({time.monotonic() - t0:.0f} s)")
    return rows


def format_table(rows: Sequence[Row]) -> str:
    """A Markdown table like the paper's Tables I/II (IoU in percent)."""
    lines = ["| Method | Input | Moving IoU (test) | Train min (wall) | Notes |", "|---|---|---:|---:|---|"]
    for r in rows:
        iou = "n/a" if math.isnan(r.iou) else f"{100 * r.iou:.1f}"
        minutes = "" if r.train_minutes is None else f"{r.train_minutes:.0f}"
        lines.append(f"| {r.method} | {r.input} | {iou} | {minutes} | {r.detail} |")
    return "\n".join(lines)
