"""Training data: per-scan network components computed by the core code, cached on disk.

Cache
-----
Computing N = 8 residual images costs ~8 re-projections per scan; doing that every
epoch would dominate training on a CPU.  So each sequence is processed once, with
exactly the functions the node runs (:func:`~ros2_mos.core.projection.project`,
:func:`~ros2_mos.core.residuals.residual_images`, and for the ``frames`` setups
``project(transform_points(past))``), and these *components* are stored as
``.npy`` memory maps under ``<cache_root>/<sequence>-<key>/``:

* ``frame.npy``     (S, 5, H, W) float16: raw r, x, y, z, e of the current scan (0 = empty)
* ``residual.npy``  (S, N_max, H, W) float16: *signed* residuals (r_j - r_0) / r_0 against
  the last N_max scans (a setup without ``signed`` takes their absolute value)
* ``past.npy``      (S, 5 * F_max, H, W) float16: the last F_max scans re-projected into this one
* ``label.npy``     (S, H, W) int8: -1 ignore/empty, 0 static, 1 moving (label of the pixel's point)
* ``points_*.npy``  per-point pixel, range and class, concatenated (only for evaluation sequences)

A setup takes the residual channels of its ``offsets`` (the first n_past by default),
so one cache serves the whole ablation.  The key hashes the sensor, the residual
window, N_max, F_max, the pose source and pose noise, and every file the cache is
computed from (names, sizes and modification times of the scans, labels and
poses), so relabelling or new poses rebuild it.

Pose noise
----------
The simulator's poses are exact; the node's come from KISS-ICP, whose scan-to-scan
error is centimetres and hundredths of a degree.  With ``pose_noise`` = (σ_t in m,
σ_r in degrees) each past scan is moved into the current frame with a relative pose
perturbed by a random translation and rotation of those standard deviations (one
draw per scan pair, seeded by the pair), so the network learns that small
misregistration is not motion.
The network input is then assembled at load time by the core's
:func:`~ros2_mos.core.network_input.assemble_input` (normalisation with the model's means/stds).

Augmentation in image space (why it is equivalent to augmenting the points)
---------------------------------------------------------------------------
The projection is ``u = ½ (1 − yaw/π) W``; everything below is applied to the
current scan, its past scans (already in the current frame) and the labels alike:

* rotation about z by θ = 2π k / W: yaw → yaw + θ shifts every column by −k, exactly
  (a column roll), and x, y are rotated by θ.  Range, z, remission and the residuals
  (a function of ranges only) are unchanged.  The rotation is limited to whole
  columns, i.e. multiples of 0.18° at W = 2048.
* flip y → −y: yaw → −yaw maps column u to W − 1 − u (a column reversal, exact up to
  the floor of a pixel edge) and negates y.  A flip x → −x is the y-flip followed by a
  rotation by π, so random rotations and y-flips together cover both flips.
* point dropping: a random fraction of the current scan's pixels is emptied (all
  channels 0, residual 0, label ignored), as if their points had not been measured.
  Unlike dropping points before projection, a second point behind a dropped one does
  not take over the pixel; with ~120k points over 131k pixels those are few.
* width crops (for speed, not augmentation): after the random roll the first
  ``crop_width`` columns are used; a fully convolutional network trains on a
  2048/crop_width smaller image per step and runs on the full 360° at inference.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from ros2_mos.core.config import ResidualConfig, SensorConfig
from ros2_mos.core.errors import ConfigError, DatasetError
from ros2_mos.core.network_input import InputSetup, assemble_input
from ros2_mos.core.projection import (
    PixelIndex,
    RangeImage,
    finite_mask,
    project,
    project_range,
    project_range_columns,
)
from ros2_mos.core.residuals import (
    free_space_image,
    relative_pose,
    residual_image,
    transform_columns,
    transform_points,
)
from ros2_mos.io.labels import IGNORE, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence

CACHE_VERSION = 3
_EMPTY_PIXELS = PixelIndex(
    u=np.empty(0, np.int32), v=np.empty(0, np.int32), range=np.empty(0, np.float32), in_image=np.empty(0, bool)
)


@dataclass(frozen=True)
class CacheSpec:
    """What a sequence cache holds: the largest residual count and past-frame count it serves."""

    sensor: SensorConfig
    residual: ResidualConfig = ResidualConfig()
    n_residual: int = 8
    n_frames: int = 1
    poses: str = "dataset"  # 'dataset' (poses.txt) or 'kiss_icp'
    with_points: bool = False
    pose_noise: tuple[float, float] = (0.0, 0.0)  # σ of the relative pose: translation (m), rotation (deg)
    # Free-space images (ros2_mos.core.residuals.free_space_image) against the scans this many back.
    free_space_offsets: tuple[int, ...] = ()
    # Only the residual images against the scans this many back are cached (default: 1..n_residual, every one).
    residual_offsets: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.poses not in ("dataset", "kiss_icp"):
            raise ConfigError(f"poses must be 'dataset' or 'kiss_icp', got {self.poses!r}")
        if self.n_residual < 0 or self.n_frames < 0:
            raise ConfigError("n_residual and n_frames must be >= 0")
        noise = tuple(float(v) for v in self.pose_noise)
        if len(noise) != 2 or not all(math.isfinite(v) and 0.0 <= v <= 10.0 for v in noise):
            raise ConfigError(f"pose_noise must be two finite values in [0, 10] (m, deg), got {self.pose_noise}")
        object.__setattr__(self, "pose_noise", noise)
        offsets = tuple(int(o) for o in self.free_space_offsets)
        if any(not 1 <= o <= self.n_residual for o in offsets) or len(set(offsets)) != len(offsets):
            raise ConfigError(f"free_space_offsets must be distinct values in 1..n_residual={self.n_residual}, "
                              f"got {list(self.free_space_offsets)}")
        object.__setattr__(self, "free_space_offsets", offsets)
        kept = tuple(int(o) for o in self.residual_offsets)
        if any(not 1 <= o <= self.n_residual for o in kept) or list(kept) != sorted(set(kept)):
            raise ConfigError(f"residual_offsets must be increasing values in 1..n_residual={self.n_residual}, "
                              f"got {list(self.residual_offsets)}")
        object.__setattr__(self, "residual_offsets", kept)

    @property
    def stored_offsets(self) -> tuple[int, ...]:
        """The offsets of the cached residual images, in their order in ``residual.npy``."""
        return self.residual_offsets or tuple(range(1, self.n_residual + 1))

    def serves(self, setup: InputSetup) -> bool:
        if setup.free_space and not set(setup.offsets) <= set(self.free_space_offsets):
            return False
        if setup.kind == "residual":
            return set(setup.offsets) <= set(self.stored_offsets)
        return setup.history <= self.n_frames


def _file_stamps(paths: Iterable[Path]) -> list[tuple[str, int, int]]:
    out = []
    for p in paths:
        st = p.stat()
        out.append((p.name, st.st_size, st.st_mtime_ns))
    return out


def _cache_key(spec: CacheSpec, sequence: SemanticKittiSequence) -> str:
    """A hash of what the cache is computed from: spec, path, and every input file's name, size and mtime."""
    root = Path(sequence.root).resolve()
    described = asdict(spec)
    for optional in ("free_space_offsets", "residual_offsets"):  # caches built before these existed keep their key
        if not described[optional]:
            del described[optional]
    inputs = list(sequence.scan_files)
    for sub in ("labels",):
        if (root / sub).is_dir():
            inputs += sorted((root / sub).glob("*.label"))
    inputs += [root / name for name in ("poses.txt", "calib.txt", "times.txt") if (root / name).is_file()]
    blob = json.dumps([CACHE_VERSION, described, str(root), _file_stamps(inputs)], sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:12]


def perturb_pose(transform: np.ndarray, sigma_t: float, sigma_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``transform`` composed with a random rigid motion (translation σ_t m per axis, rotation σ_deg
    about a random axis)."""
    if sigma_t == 0.0 and sigma_deg == 0.0:
        return transform
    axis = rng.normal(size=3)
    axis /= max(float(np.linalg.norm(axis)), 1e-12)
    angle = np.radians(rng.normal(0.0, sigma_deg))
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    noise = np.eye(4)
    noise[:3, :3] = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)  # Rodrigues
    noise[:3, 3] = rng.normal(0.0, sigma_t, 3)
    return noise @ transform


@dataclass
class _Scan:
    points: np.ndarray
    remission: np.ndarray
    labels: np.ndarray | None
    pose: np.ndarray


def _read(sequence: SemanticKittiSequence, index: int, poses: np.ndarray) -> _Scan:
    """A frame with the pipeline's input cleaning (finite, non-zero points only)."""
    frame = sequence[index]
    valid = finite_mask(frame.points)
    remission = np.nan_to_num(frame.remission[valid], nan=0.0, posinf=0.0, neginf=0.0)
    labels = None if frame.labels is None else frame.labels[valid]
    return _Scan(np.ascontiguousarray(frame.points[valid], np.float32), remission.astype(np.float32), labels,
                 poses[index])


def _raw_frame(image: RangeImage) -> np.ndarray:
    out = np.empty((5,) + image.range.shape, np.float32)
    out[0] = image.range
    out[1:4] = np.moveaxis(image.xyz, -1, 0)
    out[4] = image.remission
    out *= image.mask[None]
    return out


def _process_chunk(args: tuple[str, CacheSpec, np.ndarray, int, int, str]) -> int:
    """Fill cache rows [start, stop) of one sequence (runs in a worker process)."""
    root, spec, poses, start, stop, out_dir = args
    sequence = SemanticKittiSequence(root)
    out = Path(out_dir)
    frame_mm = np.load(out / "frame.npy", mmap_mode="r+")
    label_mm = np.load(out / "label.npy", mmap_mode="r+")
    res_mm = np.load(out / "residual.npy", mmap_mode="r+") if spec.n_residual else None
    past_mm = np.load(out / "past.npy", mmap_mode="r+") if spec.n_frames else None
    free_mm = np.load(out / "free_space.npy", mmap_mode="r+") if spec.free_space_offsets else None
    sensor = spec.sensor
    history = max(spec.n_residual, spec.n_frames)
    buffer: list[_Scan] = [_read(sequence, j, poses) for j in range(max(0, start - history), start)][::-1]
    own_range: dict[int, np.ndarray] = {}  # scan index -> its own range image (free-space inputs)
    for i in range(start, stop):
        scan = _read(sequence, i, poses)
        image = project(scan.points, scan.remission, sensor)
        own_range[i] = image.range
        frame_mm[i] = _raw_frame(image).astype(np.float16)
        if scan.labels is not None:
            classes = to_moving_classes(scan.labels)
            lab = np.full(image.point_index.shape, IGNORE, np.int8)
            lab[image.mask] = classes[image.point_index[image.mask]]
        else:
            lab = np.full(image.point_index.shape, IGNORE, np.int8)
        label_mm[i] = lab
        if res_mm is not None:
            # residual_images() of the core, unrolled for the per-pair pose noise.
            stored = spec.stored_offsets
            res = np.zeros((len(stored), sensor.height, sensor.width), np.float32)
            free = np.zeros((len(spec.free_space_offsets), sensor.height, sensor.width), np.float32)
            for j, s in enumerate(buffer[: spec.n_residual]):
                if j + 1 not in stored and j + 1 not in spec.free_space_offsets:
                    continue
                rng = np.random.default_rng((i, j + 1, spec.n_residual))
                moved = perturb_pose(relative_pose(scan.pose, s.pose), *spec.pose_noise, rng)
                if j + 1 in stored:
                    x, y, z = transform_columns(s.points, moved)
                    past_range = project_range_columns(x, y, z, sensor)
                    res[stored.index(j + 1)] = residual_image(image.range, past_range, spec.residual, signed=True)
                if j + 1 in spec.free_space_offsets:  # the same noisy pose, the other way round
                    if i - j - 1 not in own_range:
                        own_range[i - j - 1] = project_range(s.points, sensor)
                    free[spec.free_space_offsets.index(j + 1)] = free_space_image(
                        image.xyz, image.mask, own_range[i - j - 1], np.linalg.inv(moved), sensor, spec.residual)
            res_mm[i] = res.astype(np.float16)
            if free_mm is not None:
                free_mm[i] = free.astype(np.float16)
            for k in [k for k in own_range if k <= i - spec.n_residual]:
                del own_range[k]
        if past_mm is not None:
            stack = np.zeros((5 * spec.n_frames, sensor.height, sensor.width), np.float32)
            for j, s in enumerate(buffer[: spec.n_frames]):
                moved = transform_points(s.points, relative_pose(scan.pose, s.pose))
                stack[5 * j : 5 * (j + 1)] = _raw_frame(project(moved, s.remission, sensor))
            past_mm[i] = stack.astype(np.float16)
        if spec.with_points:
            pix = image.pixels
            np.savez(
                out / "points" / f"{i:06d}.npz",
                u=pix.u.astype(np.int16),
                v=pix.v.astype(np.int16),
                range=pix.range,
                in_image=pix.in_image,
                classes=(
                    to_moving_classes(scan.labels) if scan.labels is not None else np.full(len(pix.u), IGNORE, np.int8)
                ),
            )
        buffer.insert(0, scan)
        del buffer[history:]
    for mm in (frame_mm, label_mm, res_mm, past_mm, free_mm):
        if mm is not None:
            mm.flush()
    return stop - start


def _sequence_poses(sequence: SemanticKittiSequence, source: str, sensor: SensorConfig) -> np.ndarray:
    if source == "dataset":
        return sequence.require_poses("training with 'poses: dataset' (else use poses: kiss_icp)")
    from ros2_mos.core.config import OdometryConfig
    from ros2_mos.core.odometry import KissIcpOdometry

    odometry = KissIcpOdometry(OdometryConfig(max_range=min(100.0, sensor.max_range)))
    poses = []
    for i in range(len(sequence)):
        frame = sequence[i]
        pts = frame.points[finite_mask(frame.points)].astype(np.float64)
        poses.append(odometry.estimate(pts))
        odometry.update_map()
    return np.asarray(poses)


class SequenceCache:
    """The cached components of one sequence (memory-mapped, read-only)."""

    def __init__(self, directory: Path, spec: CacheSpec) -> None:
        self.directory = directory
        self.spec = spec
        self.frame = np.load(directory / "frame.npy", mmap_mode="r")
        self.label = np.load(directory / "label.npy", mmap_mode="r")
        self.residual = np.load(directory / "residual.npy", mmap_mode="r") if spec.n_residual else None
        self.past = np.load(directory / "past.npy", mmap_mode="r") if spec.n_frames else None
        self.free_space = (np.load(directory / "free_space.npy", mmap_mode="r") if spec.free_space_offsets
                           else None)
        self.name = json.loads((directory / "info.json").read_text())["sequence"]

    def __len__(self) -> int:
        return len(self.frame)

    def points(self, index: int) -> dict[str, np.ndarray]:
        """Per-point pixel (u, v), range and class of scan ``index`` (evaluation caches only)."""
        path = self.directory / "points" / f"{index:06d}.npz"
        if not path.is_file():
            raise DatasetError(f"{self.directory}: built without per-point data (with_points=False)")
        with np.load(path) as data:
            return {k: data[k] for k in data.files}

    @classmethod
    def build(
        cls,
        sequence_dir: str | Path,
        cache_root: str | Path,
        spec: CacheSpec,
        workers: int = 2,
        progress: Callable[[str], None] | None = None,
    ) -> "SequenceCache":
        """Open the cache of a sequence, computing it first if missing or stale."""
        sequence = SemanticKittiSequence(sequence_dir)
        if spec.sensor is None:
            raise ConfigError("CacheSpec needs a sensor")
        key = _cache_key(spec, sequence)
        directory = Path(cache_root) / f"{sequence.name}-{key}"
        if (directory / "done").is_file():
            return cls(directory, spec)
        if not sequence.has_labels:
            raise DatasetError(f"{sequence.root}: no labels/ folder; training needs labelled scans")
        directory.mkdir(parents=True, exist_ok=True)
        (directory / "points").mkdir(exist_ok=True)
        s, h, w = len(sequence), spec.sensor.height, spec.sensor.width
        np.lib.format.open_memmap(directory / "frame.npy", "w+", np.float16, (s, 5, h, w)).flush()
        np.lib.format.open_memmap(directory / "label.npy", "w+", np.int8, (s, h, w)).flush()
        if spec.n_residual:
            np.lib.format.open_memmap(directory / "residual.npy", "w+", np.float16,
                                      (s, len(spec.stored_offsets), h, w)).flush()
        if spec.n_frames:
            np.lib.format.open_memmap(directory / "past.npy", "w+", np.float16, (s, 5 * spec.n_frames, h, w)).flush()
        if spec.free_space_offsets:
            np.lib.format.open_memmap(directory / "free_space.npy", "w+", np.float16,
                                      (s, len(spec.free_space_offsets), h, w)).flush()
        if progress:
            progress(f"caching sequence {sequence.name} ({s} scans) into {directory}")
        poses = _sequence_poses(sequence, spec.poses, spec.sensor)
        workers = max(1, min(workers, s))
        bounds = np.linspace(0, s, workers + 1).astype(int)
        jobs = [
            (str(sequence.root), spec, poses, int(a), int(b), str(directory))
            for a, b in zip(bounds[:-1], bounds[1:])
            if b > a
        ]
        if workers == 1:
            for job in jobs:
                _process_chunk(job)
        else:
            with ProcessPoolExecutor(workers) as pool:
                list(pool.map(_process_chunk, jobs))
        (directory / "info.json").write_text(json.dumps({"sequence": sequence.name, "scans": s, "spec": asdict(spec)}))
        (directory / "done").write_text("ok\n")
        return cls(directory, spec)


@dataclass(frozen=True)
class AugmentConfig:
    """Image-space augmentations (see the module docstring for their point-space meaning)."""

    rotate: bool = True
    flip_y: float = 0.5
    drop_max: float = 0.1
    crop_width: int | None = None


def as_range_image(raw: np.ndarray) -> RangeImage:
    """A RangeImage view of raw (5, H, W) r, x, y, z, e channels, for the core's assemble_input."""
    mask = raw[0] > 0
    return RangeImage(
        range=raw[0],
        xyz=np.moveaxis(raw[1:4], 0, -1),
        remission=raw[4],
        point_index=np.where(mask, 0, -1).astype(np.int32),
        pixels=_EMPTY_PIXELS,
    )


def _rotate_xy(raw: np.ndarray, cos: float, sin: float) -> None:
    """Rotate the x, y channels of raw (5k, H, W) frames in place (empty pixels stay 0)."""
    for base in range(0, len(raw), 5):
        x, y = raw[base + 1].copy(), raw[base + 2].copy()
        raw[base + 1] = cos * x - sin * y
        raw[base + 2] = sin * x + cos * y


class MosDataset(Dataset):
    """(input (C, H, W) float32, label (H, W) int64) samples over cached sequences."""

    def __init__(
        self,
        caches: Sequence[SequenceCache],
        setup: InputSetup,
        means: Sequence[float],
        stds: Sequence[float],
        augment: AugmentConfig | None = None,
        stride: int = 1,
        seed: int = 0,
        first_scan: int = 0,
    ) -> None:
        """``first_scan``: samples start at this scan of each sequence (every ``stride``-th from there)."""
        if isinstance(first_scan, bool) or not isinstance(first_scan, int) or first_scan < 0:
            raise ConfigError(f"first_scan must be an integer >= 0, got {first_scan!r}")
        for cache in caches:
            if not cache.spec.serves(setup):
                raise ConfigError(f"cache {cache.directory} (residual offsets {list(cache.spec.stored_offsets)}, free "
                                  f"space {list(cache.spec.free_space_offsets)}) cannot serve {setup}")
        self.caches = list(caches)
        self.setup = setup
        self.means = np.asarray(means, np.float32)
        self.stds = np.asarray(stds, np.float32)
        self.augment = augment
        self.index = [(c, i) for c, cache in enumerate(self.caches)
                      for i in range(first_scan, len(cache), max(1, stride))]
        self.seed = seed
        self.epoch = 0
        if augment and augment.crop_width is not None and self.caches:
            width = self.caches[0].frame.shape[-1]
            if not 0 < augment.crop_width <= width:
                raise ConfigError(f"crop_width must be in 1..{width}, got {augment.crop_width}")

    def __len__(self) -> int:
        return len(self.index)

    def set_epoch(self, epoch: int) -> None:
        """Different augmentations each epoch, yet reproducible for a seed."""
        self.epoch = epoch

    def components(self, item: int, columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw (current 5xHxW, past_channels (n, H, W) residuals or (5n, H, W) frames, label) of a sample.

        ``columns`` gathers only those image columns (in that order), as a crop would.
        """
        c, i = self.index[item]
        cache = self.caches[c]

        def read(array: np.ndarray, dtype: type) -> np.ndarray:
            return np.asarray(array if columns is None else np.take(array, columns, axis=-1), dtype)

        current = read(cache.frame[i], np.float32)
        n = self.setup.n_past
        if self.setup.kind == "residual":
            channels = [cache.spec.stored_offsets.index(o) for o in self.setup.offsets]
            past_channels = (
                read(cache.residual[i, channels], np.float32) if n else np.zeros((0,) + current.shape[1:], np.float32)
            )
            if self.setup.free_space:
                if cache.free_space is None:
                    raise DatasetError(f"{cache.directory}: cached without free-space images")
                free = [cache.spec.free_space_offsets.index(o) for o in self.setup.offsets]
                past_channels = np.concatenate([past_channels, read(cache.free_space[i, free], np.float32)])
        else:
            past_channels = (read(cache.past[i, : 5 * n], np.float32) if n
                             else np.zeros((0,) + current.shape[1:], np.float32))
        return current, past_channels, read(cache.label[i], np.int64)

    def __getitem__(self, item: int) -> tuple[torch.Tensor, torch.Tensor]:
        if self.augment is not None:
            rng = np.random.default_rng((self.seed, self.epoch, item))
            current, past_channels, label = self._augmented(item, rng)
        else:
            current, past_channels, label = self.components(item)
        if self.setup.kind == "residual":
            x = assemble_input(as_range_image(current), past_channels, self.setup, self.means, self.stds)
        else:
            frames = [as_range_image(past_channels[5 * j : 5 * (j + 1)]) for j in range(len(past_channels) // 5)]
            x = assemble_input(as_range_image(current), frames, self.setup, self.means, self.stds)
        return torch.from_numpy(x), torch.from_numpy(label)

    def _augmented(self, item: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flip, rotate, crop as one column gather, then drop points.

        Equal to :func:`flip_y` followed by :func:`rotate_columns` by k and taking the first
        ``crop_width`` columns (the column of crop position c is ``(c + k) mod W``, mirrored
        to ``W - 1 - that`` when flipped), but only the cropped columns are read and converted.
        """
        aug = self.augment
        assert aug is not None
        frames_kind = self.setup.kind == "frames"
        c, _ = self.index[item]
        w = self.caches[c].frame.shape[-1]
        flip = bool(aug.flip_y) and rng.random() < aug.flip_y
        k = int(rng.integers(w)) if aug.rotate else 0
        width = aug.crop_width if aug.crop_width is not None else w
        columns = (k + np.arange(width)) % w
        if flip:
            columns = w - 1 - columns
        current, past_channels, label = self.components(item, columns)
        if flip:
            current[2] *= -1.0
            if frames_kind:
                past_channels[2::5] *= -1.0
        if k:
            theta = 2.0 * np.pi * k / w
            cos, sin = float(np.cos(theta)), float(np.sin(theta))
            _rotate_xy(current, cos, sin)
            if frames_kind:
                _rotate_xy(past_channels, cos, sin)
        if aug.drop_max > 0:
            fraction = rng.random() * aug.drop_max
            drop = rng.random(label.shape) < fraction
            current[:, drop] = 0.0
            if not frames_kind:
                past_channels[:, drop] = 0.0
            label[drop] = IGNORE
        return current, past_channels, label


def flip_y(
    current: np.ndarray, past_channels: np.ndarray, label: np.ndarray, frames_kind: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The image-space form of mirroring the points y -> -y: reverse the columns, negate y."""
    current, past_channels, label = current[..., ::-1].copy(), past_channels[..., ::-1].copy(), label[..., ::-1].copy()
    current[2] *= -1.0
    if frames_kind:
        past_channels[2::5] *= -1.0
    return current, past_channels, label


def rotate_columns(
    current: np.ndarray, past_channels: np.ndarray, label: np.ndarray, k: int, frames_kind: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The image-space form of rotating the points by 2πk/W about z: roll by -k columns, rotate x, y."""
    w = current.shape[-1]
    theta = 2.0 * np.pi * k / w
    current, past_channels, label = (np.roll(a, -k, axis=-1) for a in (current, past_channels, label))
    cos, sin = float(np.cos(theta)), float(np.sin(theta))
    _rotate_xy(current, cos, sin)
    if frames_kind:
        _rotate_xy(past_channels, cos, sin)
    return current, past_channels, label


def build_caches(
    sequence_dirs: Iterable[Path], cache_root: str | Path, spec: CacheSpec, workers: int = 2,
    progress: Callable[[str], None] | None = None,
) -> list[SequenceCache]:
    """Open (building where needed) the caches of several sequences."""
    return [SequenceCache.build(d, cache_root, spec, workers=workers, progress=progress) for d in sequence_dirs]


def channel_statistics(
    caches: Sequence[SequenceCache], max_scans: int = 200
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Means and stds of r, x, y, z, e over occupied pixels of (a sample of) the training scans.

    The model's normalisation is fitted to its own training data (the simulator's
    remission, for one, is not KITTI's) and travels in its metadata.
    """
    total = sum(len(c) for c in caches)
    if total == 0:
        raise DatasetError("no scans to compute channel statistics from")
    step = max(1, total // max_scans)
    acc = np.zeros(5)
    acc2 = np.zeros(5)
    count = 0
    k = 0
    for cache in caches:
        for i in range(len(cache)):
            if k % step == 0:
                raw = np.asarray(cache.frame[i], np.float64)
                mask = raw[0] > 0
                vals = raw[:, mask]
                acc += vals.sum(axis=1)
                acc2 += (vals * vals).sum(axis=1)
                count += vals.shape[1]
            k += 1
    if count == 0:
        raise DatasetError("the training scans have no occupied pixel")
    mean = acc / count
    std = np.sqrt(np.maximum(acc2 / count - mean * mean, 1e-12))
    std = np.maximum(std, 1e-3)
    return tuple(float(v) for v in mean), tuple(float(v) for v in std)


def class_counts(caches: Sequence[SequenceCache], n_classes: int = 2) -> np.ndarray:
    """Pixel counts per class over the training labels (ignored pixels not counted)."""
    counts = np.zeros(n_classes, np.int64)
    for cache in caches:
        for i in range(0, len(cache), 64):
            block = np.asarray(cache.label[i : i + 64])
            counts += np.bincount(block[block >= 0].ravel().astype(np.int64), minlength=n_classes)[:n_classes]
    return counts


def default_workers() -> int:
    return max(1, min(2, os.cpu_count() or 1))
