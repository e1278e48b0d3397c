"""Speed profiles: how far along its path an agent is at any time, with stops that stay exactly still.

An agent cruises, slows for corners, brakes to a stop, waits and pulls away
again.  While it waits its arc length is held *exactly* constant, so that its
pose does not change between scans and it is labelled static (a car at a red
light is not moving), which is the MOS ground-truth definition used here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class SpeedProfile:
    """Arc length ``s`` (non-decreasing) sampled at times ``t``; interpolated in between."""

    t: np.ndarray
    s: np.ndarray

    def at(self, t: np.ndarray | float) -> np.ndarray:
        """Arc length at times ``t`` (held constant outside the simulated interval)."""
        return np.interp(np.asarray(t, float), self.t, self.s)

    @classmethod
    def constant(cls, t0: float, t1: float, speed: float, s0: float = 0.0) -> "SpeedProfile":
        return cls(np.array([t0, t1]), np.array([s0, s0 + speed * (t1 - t0)]))


@dataclass(frozen=True)
class Stop:
    """Wait ``duration`` seconds once arc length ``s`` is reached."""

    s: float
    duration: float


def simulate_profile(
    t0: float,
    t1: float,
    cruise: float,
    stops: list[Stop] | None = None,
    speed_limit: Callable[[float], float] | None = None,
    accel: float = 1.5,
    decel: float = 2.5,
    v0: float | None = None,
    hold_until: float | None = None,
    dt: float = 0.05,
) -> SpeedProfile:
    """Integrate a simple longitudinal driver from ``t0`` to ``t1``, starting at s = 0.

    The driver tracks ``min(cruise, speed_limit(s), braking speed for the next stop)``
    within the acceleration limits, stands still until ``hold_until`` if given, and
    snaps onto each stop point so that the wait is exactly motionless.  A scalar
    loop: a few thousand steps per agent, cheap next to ray casting.
    """
    pending = sorted(stops or [], key=lambda st: st.s)
    n = int(math.ceil((t1 - t0) / dt)) + 1
    times = t0 + dt * np.arange(n)
    s_out = np.empty(n)
    s = 0.0
    v = cruise if v0 is None else v0
    wait_until = hold_until if hold_until is not None else -math.inf
    if hold_until is not None:
        v = 0.0
    k_stop = 0
    limit = speed_limit
    for k in range(n):
        t = times[k]
        s_out[k] = s
        if t < wait_until:
            continue
        target = cruise
        if limit is not None:
            target = min(target, limit(s))
        while k_stop < len(pending) and pending[k_stop].s < s - 1e-6:
            k_stop += 1  # stops behind us (e.g. started past them) are skipped
        if k_stop < len(pending):
            gap = pending[k_stop].s - s
            if gap <= 0.05 and v <= 0.5:
                s = pending[k_stop].s
                v = 0.0
                wait_until = t + pending[k_stop].duration
                k_stop += 1
                s_out[k] = s
                continue
            target = min(target, math.sqrt(2.0 * decel * max(gap - 0.02, 0.0)) + 0.2)
        v = min(max(target, v - decel * dt * 1.5), v + accel * dt)
        v = max(v, 0.0)
        step = v * dt
        if k_stop < len(pending):
            step = min(step, pending[k_stop].s - s)
        s += step
    return SpeedProfile(times, s_out)


def random_stops(rng: np.random.Generator, length: float, every: tuple[float, float],
                 duration: tuple[float, float], start: float = 0.0) -> list[Stop]:
    """Stop-and-go: stops spaced ``every`` metres apart (uniform), each ``duration`` seconds (uniform)."""
    stops: list[Stop] = []
    s = start + rng.uniform(*every)
    while s < length:
        stops.append(Stop(float(s), float(rng.uniform(*duration))))
        s += rng.uniform(*every)
    return stops
