"""A reference pipeline built the way the original LiDAR-MOS code does it, for speed-up ratios.

Residual images as ``utils/gen_residual_images.py`` computes them (homogeneous
float64 transforms, ``range_projection`` with an argsort per past scan), SalsaNext
in PyTorch eager mode, and RangeNet++'s ``KNN`` post-processing in PyTorch — all
on the CPU.  Only for timing on the same machine as our pipeline; the weights are
random (speed does not depend on them).
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
import torch.nn.functional as F

from ros2_mos.core.config import SensorConfig


def range_projection(vertex: np.ndarray, sensor: SensorConfig, max_range: float) -> np.ndarray:
    """LiDAR-MOS ``utils.range_projection``: (H, W) range, -1 where empty, closest point by argsort."""
    fov_up, fov_down = sensor.fov_up, sensor.fov_down
    fov = abs(fov_down) + abs(fov_up)
    depth = np.linalg.norm(vertex[:, :3], 2, axis=1)
    keep = (depth > 0) & (depth < max_range)
    vertex, depth = vertex[keep], depth[keep]
    scan_x, scan_y, scan_z = vertex[:, 0], vertex[:, 1], vertex[:, 2]
    yaw = -np.arctan2(scan_y, scan_x)
    pitch = np.arcsin(scan_z / depth)
    proj_x = 0.5 * (yaw / np.pi + 1.0) * sensor.width
    proj_y = (1.0 - (pitch + abs(fov_down)) / fov) * sensor.height
    proj_x = np.maximum(0, np.minimum(sensor.width - 1, np.floor(proj_x))).astype(np.int32)
    proj_y = np.maximum(0, np.minimum(sensor.height - 1, np.floor(proj_y))).astype(np.int32)
    order = np.argsort(depth)[::-1]
    proj_range = np.full((sensor.height, sensor.width), -1, dtype=np.float32)
    proj_range[proj_y[order], proj_x[order]] = depth[order]
    return proj_range


def residual_images(current: np.ndarray, current_pose: np.ndarray, past: list[tuple[np.ndarray, np.ndarray]],
                    sensor: SensorConfig, range_min: float = 2.0, range_max: float = 50.0) -> np.ndarray:
    """``gen_residual_images.py`` per scan: one re-projection and comparison per past scan."""
    current_range = range_projection(current, sensor, range_max)
    out = np.zeros((len(past), sensor.height, sensor.width), np.float32)
    for j, (scan, pose) in enumerate(past):
        hom = np.hstack([scan[:, :3], np.ones((len(scan), 1))])
        transformed = np.linalg.inv(current_pose).dot(pose).dot(hom.T).T
        last_range = range_projection(transformed, sensor, range_max)
        valid = ((current_range > range_min) & (current_range < range_max)
                 & (last_range > range_min) & (last_range < range_max))
        diff = np.abs(current_range[valid] - last_range[valid]) / current_range[valid]
        out[j][valid] = diff
    return out


def _gaussian_kernel(size: int, sigma: float) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32) - (size - 1) / 2
    g = torch.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / (2 * sigma ** 2))
    return g / g.sum()


def knn_postprocess(proj_range: torch.Tensor, unproj_range: torch.Tensor, proj_argmax: torch.Tensor,
                    px: torch.Tensor, py: torch.Tensor, knn: int = 5, search: int = 5, sigma: float = 1.0,
                    cutoff: float = 1.0, nclasses: int = 3) -> torch.Tensor:
    """RangeNet++ ``postproc/KNN.py`` forward pass (LiDAR-MOS uses it with 3 classes)."""
    h, w = proj_range.shape
    pad = (search - 1) // 2
    unfold_rang = F.unfold(proj_range[None, None], kernel_size=(search, search), padding=(pad, pad))
    idx_list = py * w + px
    unproj_unfold_rang = unfold_rang[:, :, idx_list]
    unproj_unfold_rang[unproj_unfold_rang < 0] = float("inf")
    center = (search * search - 1) // 2
    unproj_unfold_rang[:, center, :] = unproj_range
    k2_distances = torch.abs(unproj_unfold_rang - unproj_range)
    k2_distances = k2_distances * (1 - _gaussian_kernel(search, sigma)).view(1, -1, 1)
    _, knn_idx = k2_distances.topk(knn, dim=1, largest=False, sorted=False)
    unfold_argmax = F.unfold(proj_argmax[None, None].float(), kernel_size=(search, search), padding=(pad, pad)).long()
    knn_argmax = torch.gather(unfold_argmax[:, :, idx_list], 1, knn_idx)
    if cutoff > 0:
        knn_argmax[torch.gather(k2_distances, 1, knn_idx) > cutoff] = nclasses
    onehot = torch.zeros((1, nclasses + 1, len(idx_list))).scatter_add_(
        1, knn_argmax, torch.ones_like(knn_argmax).float()
    )
    return onehot[:, 1:-1].argmax(dim=1)[0] + 1


class ReferencePipeline:
    """LiDAR-MOS-style inference: numpy residuals, SalsaNext eager, torch kNN (poses given)."""

    def __init__(self, sensor: SensorConfig, n_past: int = 8, threads: int = 2) -> None:
        from ros2_mos.training.nets import build_network

        torch.set_num_threads(threads)
        self.sensor = sensor
        self.n_past = n_past
        self.net = build_network("salsanext", 5 + n_past, 3).eval()
        self.means = torch.tensor([12.12, 10.88, 0.23, -1.04, 0.21])[:, None, None]
        self.stds = torch.tensor([12.32, 11.47, 6.91, 0.86, 0.16])[:, None, None]
        self.past: list[tuple[np.ndarray, np.ndarray]] = []

    def process(
        self, points: np.ndarray, remission: np.ndarray, pose: np.ndarray
    ) -> tuple[np.ndarray, dict[str, float]]:
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        residuals = np.zeros((self.n_past, self.sensor.height, self.sensor.width), np.float32)
        if self.past:
            residuals[: len(self.past)] = residual_images(points, pose, self.past, self.sensor)
        t1 = time.perf_counter()
        timings["residuals"] = (t1 - t0) * 1e3
        # The LiDAR-MOS parser's projection of the current scan (range, xyz, remission, index).
        s = self.sensor
        depth = np.linalg.norm(points, axis=1)
        yaw, pitch = -np.arctan2(points[:, 1], points[:, 0]), np.arcsin(points[:, 2] / depth)
        px = np.clip(np.floor(0.5 * (yaw / math.pi + 1.0) * s.width), 0, s.width - 1).astype(np.int64)
        py = np.clip(np.floor((1.0 - (pitch + abs(s.fov_down)) / s.fov) * s.height), 0, s.height - 1).astype(np.int64)
        order = np.argsort(depth)[::-1]
        proj = np.full((5, s.height, s.width), -1, np.float32)
        proj[0, py[order], px[order]] = depth[order]
        proj[1:4, py[order], px[order]] = points[order].T
        proj[4, py[order], px[order]] = remission[order]
        mask = torch.from_numpy(proj[0] > 0)
        x = (torch.from_numpy(proj) - self.means) / self.stds
        x = torch.cat([x, torch.from_numpy(residuals)]) * mask
        t2 = time.perf_counter()
        timings["projection"] = (t2 - t1) * 1e3
        with torch.no_grad():
            argmax = self.net(x[None])[0].argmax(dim=0)
        t3 = time.perf_counter()
        timings["inference"] = (t3 - t2) * 1e3
        labels = knn_postprocess(torch.from_numpy(proj[0]), torch.from_numpy(depth.astype(np.float32)), argmax,
                                 torch.from_numpy(px), torch.from_numpy(py))
        t4 = time.perf_counter()
        timings["postprocess"] = (t4 - t3) * 1e3
        timings["total"] = (t4 - t0) * 1e3
        self.past = [(points, pose)] + self.past[: self.n_past - 1]
        return labels.numpy(), timings
