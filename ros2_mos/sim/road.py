"""The street network and paths along it.

Streets form an irregular Manhattan grid: centre lines at x = ``xs[i]`` and
y = ``ys[j]`` with random block sizes, so that cross streets come at varied
distances.  Routes are random walks over its intersections with rounded
corners; a :class:`Path` gives the pose at any arc length, and at any lateral
offset, continuously, so lanes and sidewalks are just offsets of one route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ros2_mos.core.errors import ConfigError
from ros2_mos.sim.presets import StreetConfig

# Headings of the four grid directions (east, north, west, south) as (dx, dy) index steps.
_STEPS = ((1, 0), (0, 1), (-1, 0), (0, -1))


@dataclass(frozen=True)
class StreetGrid:
    """Street centre lines; node (i, j) is the intersection of x = xs[i] and y = ys[j]."""

    xs: np.ndarray
    ys: np.ndarray

    @classmethod
    def generate(cls, rng: np.random.Generator, street: StreetConfig, n_lines: int) -> "StreetGrid":
        """``n_lines`` streets in each direction, the middle one through the origin."""
        road = 2.0 * (street.half_road_width + street.sidewalk_width)
        lo, hi = street.block_size

        def lines() -> np.ndarray:
            pos = np.concatenate([[0.0], np.cumsum(rng.uniform(lo, hi, n_lines - 1) + road)])
            return pos - pos[n_lines // 2]

        return cls(lines(), lines())

    def node(self, i: int, j: int) -> np.ndarray:
        return np.array([self.xs[i], self.ys[j]])

    def inside(self, i: int, j: int) -> bool:
        return 0 <= i < len(self.xs) and 0 <= j < len(self.ys)


@dataclass(frozen=True)
class Path:
    """A planar path sampled at vertices with exact tangent headings.

    Positions and the (unwrapped) heading are interpolated linearly in arc length,
    so a lateral offset moves continuously even through a corner.  Arc lengths
    outside [0, length] are clamped: an agent at either end stands still.
    ``nodes_s`` holds the arc lengths of the intersections passed (corner middles),
    ``turn_spans`` the (start, end) arc lengths of each corner.
    """

    s: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    nodes_s: np.ndarray
    turn_spans: np.ndarray  # (K, 2)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def pose(self, s: np.ndarray, lateral: float | np.ndarray = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, yaw) at arc lengths ``s``, shifted ``lateral`` metres to the left."""
        s = np.clip(np.asarray(s, float), 0.0, self.length)
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        yaw = np.interp(s, self.s, self.yaw)
        x = x - lateral * np.sin(yaw)
        y = y + lateral * np.cos(yaw)
        return x, y, yaw

    def speed_limit(self, turn_speed: float, decel: float) -> Callable[[float], float]:
        """A driver's limit at arc length s: ``turn_speed`` in corners, braking in time before them."""
        starts, ends = self.turn_spans[:, 0], self.turn_spans[:, 1]

        def limit(s: float) -> float:
            k = int(np.searchsorted(ends, s))
            if k >= len(starts):
                return math.inf
            dist = max(starts[k] - s, 0.0)
            return turn_speed + math.sqrt(2.0 * decel * dist)

        return limit

    def offset(self, lateral: float) -> "Path":
        """The parallel path ``lateral`` metres to the left, with its own arc length.

        Agents on a lane or sidewalk move along their own curve, so their speed is
        their true speed also in corners (the inner side of a turn is shorter).
        """
        if lateral == 0.0:
            return self
        xy = self.xy + lateral * np.column_stack([-np.sin(self.yaw), np.cos(self.yaw)])
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        if (np.diff(s) <= 0).any():
            raise ConfigError(f"offset {lateral} m folds the path in a corner: use a larger turn_radius")
        return Path(s, xy, self.yaw.copy(), np.interp(self.nodes_s, self.s, s),
                    np.interp(self.turn_spans, self.s, s))

    @classmethod
    def from_nodes(cls, points: np.ndarray, radius: float, arc_steps: int = 12) -> "Path":
        """A path through grid ``points`` (K, 2), every 90-degree corner rounded with ``radius``."""
        pts = np.asarray(points, float)
        first = pts[1] - pts[0]
        verts: list[np.ndarray] = [pts[0]]
        yaws: list[float] = [float(np.arctan2(first[1], first[0]))]
        node_vertex: list[int] = []
        turn_vertex: list[tuple[int, int]] = []
        for k in range(1, len(pts) - 1):
            a = (pts[k] - pts[k - 1]) / np.linalg.norm(pts[k] - pts[k - 1])
            b = (pts[k + 1] - pts[k]) / np.linalg.norm(pts[k + 1] - pts[k])
            cross = float(a[0] * b[1] - a[1] * b[0])
            heading = float(np.arctan2(a[1], a[0]))
            if abs(cross) < 1e-9:  # straight through the intersection
                verts.append(pts[k])
                yaws.append(heading)
                node_vertex.append(len(verts) - 1)
                continue
            turn = np.sign(cross)
            start = pts[k] - radius * a
            center = start + radius * turn * np.array([-a[1], a[0]])
            phi0 = float(np.arctan2(start[1] - center[1], start[0] - center[0]))
            phis = phi0 + turn * np.linspace(0.0, np.pi / 2, arc_steps + 1)
            verts.extend(center + radius * np.stack([np.cos(phis), np.sin(phis)], axis=1))
            yaws.extend(phis + turn * np.pi / 2)
            node_vertex.append(len(verts) - 1 - arc_steps // 2)
            turn_vertex.append((len(verts) - 1 - arc_steps, len(verts) - 1))
        last = pts[-1] - pts[-2]
        verts.append(pts[-1])
        yaws.append(float(np.arctan2(last[1], last[0])))
        xy = np.asarray(verts)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        return cls(s, xy, np.unwrap(np.asarray(yaws)), s[np.asarray(node_vertex, int)],
                   s[np.asarray(turn_vertex, int).reshape(-1, 2)])


def random_route(rng: np.random.Generator, grid: StreetGrid, street: StreetConfig, min_length: float,
                 start: tuple[int, int] | None = None, heading: int | None = None) -> Path:
    """A random walk over the grid's intersections, at least ``min_length`` long (or until the grid ends).

    It never makes U-turns; at each intersection it goes straight with
    ``street.straight_prob``, else turns left or right, and turns away from the
    grid's edge when it must.
    """
    i, j = start if start is not None else (len(grid.xs) // 2, len(grid.ys) // 2)
    h = int(rng.integers(4)) if heading is None else heading
    nodes = [grid.node(i, j)]
    length = 0.0
    while length < min_length:
        straight = rng.random() < street.straight_prob
        options = [h] if straight else [(h + 1) % 4, (h + 3) % 4]
        rng.shuffle(options)
        options += [(h + 1) % 4, (h + 3) % 4, h]
        for cand in options:
            di, dj = _STEPS[cand]
            if grid.inside(i + di, j + dj):
                h = cand
                break
        else:
            break
        di, dj = _STEPS[h]
        i, j = i + di, j + dj
        nxt = grid.node(i, j)
        length += float(np.linalg.norm(nxt - nodes[-1]))
        nodes.append(nxt)
    return Path.from_nodes(np.asarray(nodes), street.turn_radius)
