"""The rotating multi-beam LiDAR: beam layout, ray casting, and the imperfections of a real sensor.

Rays leave from the sensor at the row/column centres of the sensor's range
image (the HDL-64E's real two-block layout for ``hdl64``, evenly spaced beams
otherwise), so a projected scan fills the image without collisions.  Range
noise, dropouts (random, at grazing incidence, at long range on dark
surfaces) and incidence-dependent remission make the scan look measured.
Points are written in the sensor frame at the firing time, as sensors deliver them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.sim.objects import VEGETATION
from ros2_mos.sim.presets import SensorEffects
from ros2_mos.sim.raycast import SoupScene, cast_nearest


def beam_elevations(sensor: SensorConfig) -> np.ndarray:
    """Elevation (rad) of each beam, top first.

    ``hdl64``: the HDL-64E's upper block (+2 to -8.33 deg, 1/3 deg apart) and lower
    block (-8.83 to -24.8 deg); other sensors: evenly spaced row centres of the fov.
    """
    if sensor.name == "hdl64" and sensor.height == 64:
        deg = np.concatenate([2.0 - np.arange(32) / 3.0, np.linspace(-8.83, -24.8, 32)])
        return np.radians(deg)
    rows = np.arange(sensor.height) + 0.5
    return sensor.fov_up - rows * (sensor.fov / sensor.height)


def column_azimuths(sensor: SensorConfig) -> np.ndarray:
    """Azimuth (rad) of each column centre: +pi at column 0, decreasing (clockwise) as KITTI's range images."""
    cols = np.arange(sensor.width) + 0.5
    return np.pi - cols * (2.0 * np.pi / sensor.width)


@dataclass
class LidarScan:
    """One simulated sweep: points in the sensor frame and, per point, remission and labels."""

    points: np.ndarray  # (N, 3) float32
    remission: np.ndarray  # (N,) float32
    sem: np.ndarray  # (N,) uint16
    inst: np.ndarray  # (N,) uint32

    @property
    def labels(self) -> np.ndarray:
        """SemanticKITTI raw labels: semantic id | instance id << 16."""
        return self.sem.astype(np.uint32) | (self.inst.astype(np.uint32) << np.uint32(16))


class Lidar:
    """A rotating LiDAR of the given sensor geometry with the given imperfections."""

    def __init__(self, sensor: SensorConfig, effects: SensorEffects) -> None:
        self.sensor = sensor
        self.effects = effects
        self.max_range = min(sensor.max_range, effects.max_range)
        self.min_range = max(sensor.min_range, effects.ego_clearance)
        el = beam_elevations(sensor) + np.radians(effects.beam_elevation_offset_deg)
        if effects.beam_elevation_jitter_deg > 0:
            deviation = np.random.default_rng(effects.beam_seed).normal(0.0, effects.beam_elevation_jitter_deg, len(el))
            el = el + np.radians(deviation)
        az = column_azimuths(sensor)
        cos_el, sin_el = np.repeat(np.cos(el), sensor.width), np.repeat(np.sin(el), sensor.width)
        az_all = np.tile(az, sensor.height)
        self._col = np.tile(np.arange(sensor.width), sensor.height)
        self.dirs_sensor = np.column_stack([cos_el * np.cos(az_all), cos_el * np.sin(az_all), sin_el])
        # Firing time of each column relative to the scan's stamp (mid-sweep), in sweeps.
        self.column_phase = (np.arange(sensor.width) + 0.5) / sensor.width - 0.5

    @property
    def n_rays(self) -> int:
        return len(self.dirs_sensor)

    def scan(self, scenes: list[SoupScene], poses: np.ndarray, rng: np.random.Generator) -> LidarScan:
        """Cast one sweep from the sensor pose (4, 4), or one pose per column (W, 4, 4) for intra-sweep motion."""
        eff = self.effects
        poses = np.asarray(poses, float)
        if poses.ndim == 3:
            rot, origins = poses[self._col, :3, :3], poses[self._col, :3, 3]
            dirs = np.einsum("nij,nj->ni", rot, self.dirs_sensor)
        else:
            origins = poses[:3, 3]
            dirs = self.dirs_sensor @ poses[:3, :3].T
        hits = cast_nearest(scenes, origins, dirs)

        soups = [s.soup for s in scenes]
        base = np.zeros(self.n_rays, np.float32)
        sem = np.zeros(self.n_rays, np.uint16)
        inst = np.zeros(self.n_rays, np.uint32)
        for k, soup in enumerate(soups):
            sel = hits.soup == k
            tri = hits.triangle[sel]
            base[sel], sem[sel], inst[sel] = soup.remission[tri], soup.sem[tri], soup.inst[tri]

        dist = hits.distance
        cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal, dirs))
        r = dist + rng.normal(0.0, eff.range_sigma, self.n_rays) * (1.0 + np.minimum(dist, 1e3) / 100.0)
        if eff.vegetation_penetration > 0 and eff.vegetation_depth > 0:
            foliage = np.flatnonzero(sem == VEGETATION)
            into = foliage[rng.random(len(foliage)) < eff.vegetation_penetration]
            r[into] += rng.exponential(eff.vegetation_depth, len(into))
        if eff.edge_mixing > 0:
            r = _mix_edges(r, dist, self.sensor.width, eff.edge_mixing, rng)
        p_drop = (
            eff.dropout
            + eff.grazing_dropout * np.clip(1.0 - cos_inc / 0.1, 0.0, 1.0)
            + eff.far_dropout * (np.minimum(dist, self.max_range) / self.max_range) ** 2 * (1.0 - base)
        )
        keep = (
            np.isfinite(dist)
            & (r >= self.min_range)
            & (r <= self.max_range)
            & (rng.random(self.n_rays) >= p_drop)
        )
        remission = base * (0.35 + 0.65 * cos_inc) + rng.normal(0.0, eff.remission_sigma, self.n_rays)
        remission = np.clip(remission, 0.0, 1.0)
        points = (self.dirs_sensor[keep] * r[keep, None]).astype(np.float32)
        return LidarScan(points, remission[keep].astype(np.float32), sem[keep], inst[keep])


def _mix_edges(r: np.ndarray, dist: np.ndarray, width: int, probability: float, rng: np.random.Generator) -> np.ndarray:
    """Ranges of rays at a depth edge (the next ray of the beam lands > max(0.5 m, 5 %) away), with the given
    probability replaced by a range uniformly between the two surfaces (a mixed pixel)."""
    d = np.where(np.isfinite(dist), dist, np.inf).reshape(-1, width)
    nxt = np.roll(d, -1, axis=1)
    near, far = np.minimum(d, nxt), np.maximum(d, nxt)
    with np.errstate(invalid="ignore"):  # inf - inf where neither ray returns: no edge
        edge = np.isfinite(far) & (far - near > np.maximum(0.5, 0.05 * near))
    edge |= np.roll(edge, 1, axis=1)  # both rays of the pair straddle the edge
    lo = np.minimum(near, np.roll(near, 1, axis=1))
    hi = np.where(np.isfinite(far), far, 0.0)
    hi = np.maximum(hi, np.roll(hi, 1, axis=1))
    idx = np.flatnonzero(edge.ravel() & (rng.random(edge.size) < probability))
    out = r.copy()
    out[idx] = lo.ravel()[idx] + rng.random(len(idx)) * (hi.ravel()[idx] - lo.ravel()[idx])
    return out
