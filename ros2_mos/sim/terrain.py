"""Gently uneven ground, and vehicle poses that follow it.

A perfectly flat ground plane is not only unrealistic, it misleads odometry: the
rings a rotating LiDAR draws on a plane move with the sensor, so point-to-point
ICP is pulled towards zero motion.  Real roads undulate by centimetres over tens
of metres and the vehicle pitches and rolls with them; a smooth world-fixed
height field (a few random plane waves) gives both, cheaply and deterministically.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.sim.motion import SpeedProfile

_WHEELBASE, _TRACK = 2.7, 1.6


@dataclass(frozen=True)
class Terrain:
    """Ground height h(x, y) = sum_k a_k sin(w_k . (x, y) + phase_k)."""

    amplitude: np.ndarray  # (K,)
    wave: np.ndarray  # (K, 2) angular wave vectors, rad/m
    phase: np.ndarray  # (K,)

    @classmethod
    def flat(cls) -> "Terrain":
        return cls(np.zeros(0), np.zeros((0, 2)), np.zeros(0))

    @classmethod
    def random(cls, rng: np.random.Generator, rms: float = 0.12, wavelength: tuple[float, float] = (25.0, 120.0),
               components: int = 6) -> "Terrain":
        """A field of ``components`` waves with the given total RMS height and wavelengths."""
        if rms <= 0:
            return cls.flat()
        lam = rng.uniform(*wavelength, components)
        ang = rng.uniform(0.0, 2.0 * np.pi, components)
        wave = (2.0 * np.pi / lam)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        amp = rng.uniform(0.5, 1.0, components)
        amp *= rms / np.sqrt(0.5 * np.sum(amp**2))
        return cls(amp, wave, rng.uniform(0.0, 2.0 * np.pi, components))

    def height(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        x, y = np.asarray(x, float), np.asarray(y, float)
        arg = x[..., None] * self.wave[:, 0] + y[..., None] * self.wave[:, 1] + self.phase
        return np.sum(self.amplitude * np.sin(arg), axis=-1)

    def vehicle_pose(self, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, mount_height: float,
                     body_pitch: np.ndarray | float = 0.0, body_roll: np.ndarray | float = 0.0) -> np.ndarray:
        """(N, 4, 4) poses of a sensor ``mount_height`` above a car standing on the ground at (x, y, yaw).

        Pitch and roll come from the ground height under the axles and the wheels,
        which smooths the field as a real suspension does, plus the body's own
        ``body_pitch``/``body_roll`` (rad) on its springs.
        """
        x, y, yaw = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, yaw))
        c, s = np.cos(yaw), np.sin(yaw)
        h = lambda dx, dy: self.height(x + c * dx - s * dy, y + s * dx + c * dy)  # noqa: E731
        pitch = -np.arctan((h(_WHEELBASE / 2, 0) - h(-_WHEELBASE / 2, 0)) / _WHEELBASE)
        roll = np.arctan((h(0, _TRACK / 2) - h(0, -_TRACK / 2)) / _TRACK)
        rot = rotation_zyx(yaw, pitch + body_pitch, roll + body_roll)
        poses = np.tile(np.eye(4), (len(x), 1, 1))
        poses[:, :3, :3] = rot
        poses[:, :3, 3] = np.column_stack([x, y, self.height(x, y)]) + rot[:, :, 2] * mount_height
        return poses


@dataclass(frozen=True)
class BodyMotion:
    """The car body's pitch and roll on its springs: a few slow oscillations while driving, a dip when braking.

    At standstill the body is still, so a standing ego vehicle sees a static world
    exactly static.

    Real LiDAR poses are never perfectly level, and the ground rings move with
    every pitch change, which keeps them from pinning ICP to the previous pose.
    """

    amplitude: np.ndarray  # (2, K) rad, pitch and roll
    freq: np.ndarray  # (2, K) Hz
    phase: np.ndarray  # (2, K)
    pitch_per_accel: float = np.radians(0.3)  # rad per m/s^2: nose up when accelerating

    @classmethod
    def random(cls, rng: np.random.Generator, rms_deg: float, components: int = 3) -> "BodyMotion":
        amp = rng.uniform(0.5, 1.0, (2, components))
        amp *= np.radians(rms_deg) / np.sqrt(0.5 * np.sum(amp**2, axis=1, keepdims=True))
        return cls(amp, rng.uniform(0.5, 2.5, (2, components)), rng.uniform(0, 2 * np.pi, (2, components)))

    def at(self, t: np.ndarray, profile: SpeedProfile) -> tuple[np.ndarray, np.ndarray]:
        """(pitch, roll) in rad at times ``t`` for a vehicle driving ``profile``."""
        t = np.asarray(t, float)
        osc = np.sum(self.amplitude[:, :, None] * np.sin(2 * np.pi * self.freq[:, :, None] * t.reshape(1, 1, -1)
                                                         + self.phase[:, :, None]), axis=1)
        dt = 0.2
        accel = (profile.at(t + dt) - 2.0 * profile.at(t) + profile.at(t - dt)) / dt**2
        speed = (profile.at(t + dt) - profile.at(t - dt)) / (2.0 * dt)
        # The road excites the vibration: none at standstill, full from a walking pace on.
        excite = np.clip(speed / 3.0, 0.0, 1.0) * (profile.at(t + 0.06) != profile.at(t - 0.06))
        pitch = excite * osc[0].reshape(t.shape) - self.pitch_per_accel * accel
        return pitch, excite * osc[1].reshape(t.shape)


def rotation_zyx(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def height_grid(terrain: Terrain, x0: float, y0: float, x1: float, y1: float, spacing: float,
                dz: float = 0.0) -> np.ndarray:
    """Triangles of the ground over a rectangle, vertices every ~``spacing`` m at height h + dz."""
    nx = max(int(np.ceil((x1 - x0) / spacing)), 1)
    ny = max(int(np.ceil((y1 - y0) / spacing)), 1)
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1), indexing="ij")
    v = np.stack([gx, gy, terrain.height(gx, gy) + dz], axis=-1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])


def curb_strip(terrain: Terrain, p0: np.ndarray, p1: np.ndarray, spacing: float, z_low: float,
               z_high: float) -> np.ndarray:
    """A vertical face from p0 to p1 between h + z_low and h + z_high (a curb)."""
    n = max(int(np.ceil(np.linalg.norm(p1 - p0) / spacing)), 1)
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    xy = p0 + t * (p1 - p0)
    h = terrain.height(xy[:, 0], xy[:, 1])
    lo = np.column_stack([xy, h + z_low])
    hi = np.column_stack([xy, h + z_high])
    return np.concatenate([np.stack([lo[:-1], lo[1:], hi[1:]], 1), np.stack([lo[:-1], hi[1:], hi[:-1]], 1)])
