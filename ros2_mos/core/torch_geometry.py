"""The GPU path of the per-scan geometry: residual images and kNN back-projection in torch.

On a GPU the CNN takes a few ms and the numpy stages (re-projecting N past scans, the
kNN vote over ~120k points) dominate; these are the same computations as
:mod:`ros2_mos.core.residuals` and :mod:`ros2_mos.core.postprocess` written for torch tensors, so
they run on CUDA.  Imported only when ``MosConfig.geometry_backend == 'torch'``: the
default runtime never imports torch.  They also run on the CPU (used by the tests to
check them against the numpy code).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ros2_mos.core.config import PostprocessConfig, ResidualConfig, SensorConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.projection import PixelIndex, RangeImage
from ros2_mos.core.residuals import relative_pose, scans_at_offsets

_EMPTY_RANGE = 1e9


def pick_device(name: str = "auto") -> torch.device:
    """'auto' takes CUDA when it is there, else the CPU; a device this torch cannot use is a ConfigError."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"device {name!r} is not a torch device (auto, cpu, cuda or cuda:N)") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {name!r}: this torch build or machine has no CUDA device (torch "
                          f"{torch.__version__}); use device auto or cpu")
    if device.type == "cuda" and device.index is not None and device.index >= torch.cuda.device_count():
        raise ConfigError(f"device {name!r}: only {torch.cuda.device_count()} CUDA device(s) here")
    return device


def pixels_of(points: torch.Tensor, sensor: SensorConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor,
                                                                       torch.Tensor]:
    """Row, column, range and inside-the-image flag of (N, 3) points, like ``projection.pixel_index``."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    r = torch.sqrt(x * x + y * y + z * z)
    pitch = torch.asin(torch.clamp(z / torch.clamp(r, min=1e-12), -1.0, 1.0))
    yaw = torch.atan2(y, x)
    u_f = 0.5 * (1.0 - yaw / math.pi) * sensor.width
    v_f = (1.0 - (pitch - sensor.fov_down) / sensor.fov) * sensor.height
    inside = (v_f >= 0) & (v_f < sensor.height) & (r > sensor.min_range) & (r < sensor.max_range)
    u = torch.clamp(torch.floor(u_f), 0, sensor.width - 1).long()
    v = torch.clamp(torch.floor(v_f), 0, sensor.height - 1).long()
    return v, u, r, inside


def range_image(points: torch.Tensor, sensor: SensorConfig) -> torch.Tensor:
    """(H, W) closest range per pixel (0 where empty) of (N, 3) points, like ``projection.project_range``."""
    v, u, r, inside = pixels_of(points, sensor)
    pix = (v * sensor.width + u)[inside]
    best = torch.full((sensor.height * sensor.width,), float("inf"), device=points.device, dtype=points.dtype)
    best.scatter_reduce_(0, pix, r[inside], reduce="amin")
    best[torch.isinf(best)] = 0.0
    return best.view(sensor.height, sensor.width)


def free_space_image(current_xyz: torch.Tensor, current_mask: torch.Tensor, past_range: torch.Tensor,
                     to_past: np.ndarray, sensor: SensorConfig, config: ResidualConfig) -> torch.Tensor:
    """Like :func:`ros2_mos.core.residuals.free_space_image`, on device tensors."""
    out = torch.zeros(current_mask.shape, device=current_xyz.device, dtype=torch.float32)
    points = current_xyz[current_mask]
    if len(points) == 0:
        return out
    t = torch.as_tensor(to_past, dtype=points.dtype, device=points.device)
    v, u, here, inside = pixels_of(points @ t[:3, :3].T + t[:3, 3], sensor)
    seen = past_range[v, u]
    lo, hi = config.min_range, config.upper
    valid = inside & (here > lo) & (here < hi) & (seen > lo) & (seen < hi)
    values = torch.where(valid, (seen - here) / torch.where(valid, here, torch.ones_like(here)),
                         torch.zeros_like(here))
    out[current_mask] = values
    return out


def residual_images(current_range: torch.Tensor, current_pose: np.ndarray, past: list[tuple[torch.Tensor, np.ndarray]],
                    n: int, sensor: SensorConfig, config: ResidualConfig, signed: bool = False) -> torch.Tensor:
    """(n, H, W) residuals against past scans (device tensors, own frame) and their world poses (signed or not)."""
    device = current_range.device
    out = torch.zeros((n, sensor.height, sensor.width), device=device, dtype=torch.float32)
    lo, hi = config.min_range, config.upper
    cur_ok = (current_range > lo) & (current_range < hi)
    inv_current = np.linalg.inv(current_pose)
    for j, (points, pose) in enumerate(past[:n]):
        t = torch.as_tensor(inv_current @ pose, dtype=torch.float32, device=device)
        moved = points @ t[:3, :3].T + t[:3, 3]
        past_range = range_image(moved, sensor)
        valid = cur_ok & (past_range > lo) & (past_range < hi)
        diff = (past_range - current_range) / torch.where(valid, current_range, torch.ones_like(current_range))
        if not signed:
            diff = torch.abs(diff)
        out[j] = torch.where(valid, diff, torch.zeros_like(diff))
    return out


def _inverse_gaussian(window: int, sigma: float, device: torch.device) -> torch.Tensor:
    offs = torch.arange(window, dtype=torch.float64) - window // 2
    g = torch.exp(-(offs[:, None] ** 2 + offs[None, :] ** 2) / (2 * sigma * sigma))
    return (1.0 - g / g.sum()).float().reshape(-1).to(device)


def _wrap_pad(image: torch.Tensor, half: int, fill: float) -> torch.Tensor:
    padded = torch.nn.functional.pad(image[None, None], (0, 0, half, half), value=fill)[0, 0]
    return torch.cat([padded[:, -half:], padded, padded[:, :half]], dim=1) if half else padded


def knn_backproject(prob_image: torch.Tensor, range_img: torch.Tensor, pixels: PixelIndex,
                    config: PostprocessConfig) -> torch.Tensor:
    """Per-point moving probability: the same vote as ``postprocess.knn_backproject`` (all points)."""
    device = prob_image.device
    h, w = range_img.shape
    half = config.window // 2
    rng = _wrap_pad(torch.where(range_img > 0, range_img, torch.full_like(range_img, _EMPTY_RANGE)), half, _EMPTY_RANGE)
    prob = _wrap_pad(prob_image, half, 0.0)
    pw = w + 2 * half
    offs = torch.arange(-half, half + 1, device=device)
    window_offsets = (offs.repeat_interleave(config.window) * pw + offs.repeat(config.window))[None, :]
    v = torch.as_tensor(pixels.v, device=device).long()
    u = torch.as_tensor(pixels.u, device=device).long()
    point_range = torch.as_tensor(pixels.range, device=device)
    flat = ((v + half) * pw + u + half)[:, None] + window_offsets
    dist = torch.abs(rng.reshape(-1)[flat] - point_range[:, None]) * _inverse_gaussian(
        config.window, config.sigma, device
    )
    dist[:, (config.window * config.window) // 2] = -1.0
    kth = torch.kthvalue(dist, config.k, dim=1, keepdim=True).values if config.k < dist.shape[1] else None
    keep = dist <= config.cutoff
    if kth is not None:
        keep &= dist <= kth
    probs = prob.reshape(-1)[flat]
    return (probs * keep).sum(dim=1) / keep.sum(dim=1)


class TorchGeometry:
    """Residuals and kNN on a torch device for :class:`~ros2_mos.core.pipeline.MosPipeline` (numpy in, numpy out).

    Past scans are moved to the device once and kept there while they are in the buffer.
    """

    def __init__(self, sensor: SensorConfig, device: str = "auto") -> None:
        self.sensor = sensor
        self.device = pick_device(device)
        self._cache: dict[int, torch.Tensor] = {}

    def _on_device(self, points: np.ndarray) -> torch.Tensor:
        key = id(points)
        if key not in self._cache:
            self._cache[key] = torch.from_numpy(points).to(self.device)
        return self._cache[key]

    def residuals(self, current_range: np.ndarray, pose: np.ndarray, past: list[tuple[np.ndarray, np.ndarray]],
                  n: int, config: ResidualConfig, offsets: tuple[int, ...] | None = None,
                  signed: bool = False) -> np.ndarray:
        """Like :func:`ros2_mos.core.residuals.residual_images`: residual k against ``past[offsets[k] - 1]``."""
        offsets = tuple(offsets) if offsets is not None else tuple(range(1, n + 1))
        chosen = scans_at_offsets(past, offsets)
        live = {id(p) for p, _ in past}
        self._cache = {k: v for k, v in self._cache.items() if k in live}
        cur = torch.from_numpy(current_range).to(self.device)
        on_device = [(self._on_device(p), q) for p, q in chosen]
        return residual_images(cur, pose, on_device, n, self.sensor, config, signed).cpu().numpy()

    def free_space(self, image: RangeImage, pose: np.ndarray, past: list[tuple[np.ndarray, np.ndarray]],
                   offsets: tuple[int, ...], config: ResidualConfig) -> np.ndarray:
        """Like :func:`ros2_mos.core.residuals.free_space_images`: against ``past`` (own range image, pose)."""
        out = np.zeros((len(offsets),) + image.range.shape, np.float32)
        chosen = scans_at_offsets(past, offsets)
        if not chosen:
            return out
        xyz = torch.from_numpy(np.ascontiguousarray(image.xyz)).to(self.device)
        mask = torch.from_numpy(image.mask).to(self.device)
        for j, (past_range, past_pose) in enumerate(chosen):
            own = torch.from_numpy(past_range).to(self.device)
            out[j] = free_space_image(xyz, mask, own, relative_pose(past_pose, pose), self.sensor,
                                      config).cpu().numpy()
        return out

    def knn(self, prob_image: np.ndarray, range_img: np.ndarray, pixels: PixelIndex,
            config: PostprocessConfig, threshold: float = 0.5) -> np.ndarray:
        """Per-point probability by the kNN vote (``mode: nearest`` goes to numpy, as it is a plain gather)."""
        if config.mode != "knn":
            from ros2_mos.core.postprocess import backproject

            return backproject(prob_image, range_img, pixels, config, threshold)
        prob = torch.from_numpy(prob_image).to(self.device)
        rng = torch.from_numpy(range_img).to(self.device)
        return knn_backproject(prob, rng, pixels, config).cpu().numpy().astype(np.float32)

    def close(self) -> None:
        """Nothing to stop (the same interface as the numpy backend)."""
