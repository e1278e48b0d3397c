"""The static world: road, sidewalks, terrain, buildings, trees, poles and parked cars.

Built once per sequence, only for the blocks the sensor can reach from the ego
route.  Facades vary in setback, width, height and gaps, trees and poles line
the curbs and cross streets come at irregular distances, so the scene gives
ICP constraints in every direction (a uniform corridor would not).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.sim import objects as ob
from ros2_mos.sim.geometry import TriangleSoup, boxes, octahedron, place, prism
from ros2_mos.sim.presets import SceneConfig, StreetConfig
from ros2_mos.sim.road import StreetGrid
from ros2_mos.sim.terrain import Terrain, curb_strip, height_grid

# Keep street furniture this far from a sidewalk's corners, so that people
# walking round a corner and cars turning never meet a pole or a trunk.
_CORNER_CLEARANCE = 4.0
# Parked cars keep this far from the curb's corner (out of the intersection).
_PARKING_CLEARANCE = 5.0
_SLOT_LENGTH = 6.0
# Ground mesh resolution (m): fine enough for the terrain's long waves, coarse enough to stay cheap.
_ROAD_SPACING, _TERRAIN_SPACING = 4.0, 6.0


@dataclass(frozen=True)
class Ground:
    """The walkable surface: terrain height, raised by the curb inside a block's sidewalk ring."""

    terrain: Terrain
    grid: StreetGrid
    street: StreetConfig

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height under (x, y): road level, or curb height above it off the road."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        xs, ys, hr = self.grid.xs, self.grid.ys, self.street.half_road_width
        i = np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2)
        j = np.clip(np.searchsorted(ys, y) - 1, 0, len(ys) - 2)
        off_road = (x - xs[i] > hr) & (xs[i + 1] - x > hr) & (y - ys[j] > hr) & (ys[j + 1] - y > hr)
        return self.terrain.height(x, y) + np.where(off_road, self.street.curb_height, 0.0)


@dataclass
class StaticScene:
    """The static triangles with their labels, and the parked cars' instance ids and positions."""

    soup: TriangleSoup
    parked_ids: np.ndarray
    parked_xy: np.ndarray
    next_instance: int


def blocks_near(grid: StreetGrid, points: np.ndarray, reach: float) -> list[tuple[int, int]]:
    """Grid cells (i, j) whose rectangle lies within ``reach`` of any of ``points`` (P, 2)."""
    x0, x1 = grid.xs[:-1], grid.xs[1:]
    y0, y1 = grid.ys[:-1], grid.ys[1:]
    px, py = points[:, 0], points[:, 1]
    dy2 = np.maximum(np.maximum(y0[:, None] - py[None], py[None] - y1[:, None]), 0.0) ** 2  # (J, P)
    cells: list[tuple[int, int]] = []
    for i in range(len(x0)):  # one row of cells at a time keeps memory at (J, P)
        dx2 = np.maximum(np.maximum(x0[i] - px, px - x1[i]), 0.0) ** 2
        if dx2.min() >= reach**2:
            continue
        near = ((dx2[None, :] + dy2) < reach**2).any(axis=1)
        cells.extend((i, int(j)) for j in np.nonzero(near)[0])
    return cells


def _along(rng: np.random.Generator, length: float, spacing: tuple[float, float], margin: float) -> np.ndarray:
    """Positions along a side of ``length``: random spacing, ``margin`` from both ends."""
    if length <= 2 * margin:
        return np.zeros(0)
    count = int(length / spacing[0]) + 2
    pos = margin + np.cumsum(rng.uniform(*spacing, count)) - rng.uniform(0, spacing[0])
    return pos[(pos >= margin) & (pos <= length - margin)]


def _sides(x0: float, y0: float, x1: float, y1: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The 4 sides of a rectangle as (start corner, unit direction, length), walked counter-clockwise.

    The rectangle's inside is to the left of each direction.
    """
    return [
        (np.array([x0, y0]), np.array([1.0, 0.0]), x1 - x0),
        (np.array([x1, y0]), np.array([0.0, 1.0]), y1 - y0),
        (np.array([x1, y1]), np.array([-1.0, 0.0]), x1 - x0),
        (np.array([x0, y1]), np.array([0.0, -1.0]), y1 - y0),
    ]


class _Builder:
    """Collects labelled pieces of one sequence's static scene."""

    def __init__(self, rng: np.random.Generator, street: StreetConfig, scene: SceneConfig, terrain: Terrain,
                 first_instance: int):
        self.rng, self.street, self.scene, self.terrain = rng, street, scene, terrain
        self.parts: list[TriangleSoup] = []
        self.parked_ids: list[int] = []
        self.parked_xy: list[np.ndarray] = []
        self.next_instance = first_instance

    def add(self, tris: np.ndarray, sem: int, remission: float | np.ndarray, inst: int = 0) -> None:
        tris = np.asarray(tris, float).reshape(-1, 3, 3)
        soup = TriangleSoup.labelled(tris, sem, inst)
        soup.remission[:] = remission
        self.parts.append(soup)

    def block(self, x0: float, y0: float, x1: float, y1: float) -> None:
        st, rng = self.street, self.rng
        hr, sw, ch = st.half_road_width, st.sidewalk_width, st.curb_height
        tr = self.terrain
        self.add(height_grid(tr, x0, y0, x1, y1, _ROAD_SPACING), ob.ROAD, rng.uniform(0.08, 0.2))
        ox0, oy0, ox1, oy1 = x0 + hr, y0 + hr, x1 - hr, y1 - hr  # curb
        ix0, iy0, ix1, iy1 = ox0 + sw, oy0 + sw, ox1 - sw, oy1 - sw  # back of the sidewalk
        strips = [(ox0, oy0, ox1, iy0), (ox0, iy1, ox1, oy1), (ox0, iy0, ix0, iy1), (ix1, iy0, ox1, iy1)]
        walk = [height_grid(tr, *rect, _ROAD_SPACING, dz=ch) for rect in strips]
        corners = [np.array(c) for c in ((ox0, oy0), (ox1, oy0), (ox1, oy1), (ox0, oy1))]
        walk += [curb_strip(tr, corners[k], corners[(k + 1) % 4], _ROAD_SPACING, -0.05, ch) for k in range(4)]
        self.add(np.concatenate(walk), ob.SIDEWALK, rng.uniform(0.25, 0.4))
        self.add(height_grid(tr, ix0, iy0, ix1, iy1, _TERRAIN_SPACING, dz=ch), ob.TERRAIN, rng.uniform(0.35, 0.55))
        for start, direction, length in _sides(ix0, iy0, ix1, iy1):
            self._frontage(start, direction, length, depth_limit=0.5 * min(ix1 - ix0, iy1 - iy0))
        for start, direction, length in _sides(ox0, oy0, ox1, oy1):
            self._curbside(start, direction, length)

    def _frontage(self, start: np.ndarray, direction: np.ndarray, length: float, depth_limit: float) -> None:
        """Buildings (and hedges in front gardens) along one side of a block's interior."""
        sc, rng, ch = self.scene, self.rng, self.street.curb_height
        inward = np.array([-direction[1], direction[0]])
        u = 0.0
        sizes, centers, rems = [], [], []
        hedge_sizes, hedge_centers = [], []
        while u < length - 3.0:
            width = min(rng.uniform(*sc.building_width), length - u)
            if rng.random() >= sc.empty_lot_prob:
                setback = rng.uniform(*sc.setback) if rng.random() > 0.2 else rng.uniform(5.0, 9.0)
                depth = min(rng.uniform(*sc.building_depth), max(depth_limit - setback - 0.5, 3.0))
                height = rng.uniform(*sc.building_height)
                gap = rng.uniform(0.0, 3.0) if rng.random() < 0.4 else 0.0
                mid = start + direction * (u + width / 2) + inward * (setback + depth / 2)
                size_along = max(width - gap, 2.0)
                size = (abs(direction[0]) * size_along + abs(inward[0]) * depth,
                        abs(direction[1]) * size_along + abs(inward[1]) * depth, height)
                base = float(self.terrain.height(mid[0], mid[1])) - 1.0  # foundations reach below the ground
                top = base + 1.0 + self.street.curb_height + height
                sizes.append((size[0], size[1], top - base))
                centers.append((mid[0], mid[1], (top + base) / 2))
                rems.append(rng.uniform(0.15, 0.6))
                if setback > 1.5 and rng.random() < sc.bush_prob:
                    h = rng.uniform(0.6, 1.6)
                    hm = start + direction * (u + width / 2) + inward * (setback / 2)
                    d = min(0.8, setback - 0.4)
                    ground = float(self.terrain.height(hm[0], hm[1])) + ch
                    hedge_sizes.append((abs(direction[0]) * width * 0.8 + abs(inward[0]) * d,
                                        abs(direction[1]) * width * 0.8 + abs(inward[1]) * d, h + 0.4))
                    hedge_centers.append((hm[0], hm[1], ground + h / 2 - 0.2))  # 0.4 m sunk into the ground
            u += width
        if sizes:
            tris = boxes(np.array(sizes), np.array(centers))
            self.add(tris, ob.BUILDING, np.repeat(np.array(rems, np.float32), len(tris) // len(sizes)))
        if hedge_sizes:
            self.add(boxes(np.array(hedge_sizes), np.array(hedge_centers)), ob.VEGETATION, rng.uniform(0.4, 0.6))

    def _curbside(self, start: np.ndarray, direction: np.ndarray, length: float) -> None:
        """Trees and poles on the sidewalk along a curb, parked cars in the parking lane before it."""
        sc, st, rng = self.scene, self.street, self.rng
        inward = np.array([-direction[1], direction[0]])  # from the curb into the block
        ch = st.curb_height
        tree_u = _along(rng, length, sc.tree_spacing, _CORNER_CLEARANCE)
        tree_u = tree_u[rng.random(len(tree_u)) < sc.tree_prob]
        if len(tree_u):
            xy = start + np.outer(tree_u, direction) + inward * 0.6
            for x, y in xy:  # a handful per side; each tree has its own size
                self._tree(x, y, float(self.terrain.height(x, y)) + ch)
        pole_u = _along(rng, length, sc.pole_spacing, _CORNER_CLEARANCE)
        if len(pole_u):
            xy = start + np.outer(pole_u, direction) + inward * 0.3
            heights = rng.uniform(4.5, 8.0, len(pole_u))
            base = self.terrain.height(xy[:, 0], xy[:, 1]) + ch
            tris = np.concatenate([place(prism(0.1, -0.2, h), x, y, 0.0, z)[0]
                                   for (x, y), h, z in zip(xy, heights, base)])
            self.add(tris, ob.POLE, rng.uniform(0.4, 0.6))
        self._parking(start, direction, length, -inward)

    def _tree(self, x: float, y: float, z: float) -> None:
        """A trunk and a crown of ``crown_blobs`` octahedra, scaled by a draw from ``tree_scale``."""
        sc, rng = self.scene, self.rng
        # The default (one blob, scale 1) draws exactly what it always drew, so the presets' scenes are unchanged.
        scale = 1.0 if sc.tree_scale == (1.0, 1.0) else float(rng.uniform(*sc.tree_scale))
        trunk_h = rng.uniform(2.0, 3.5) * scale
        self.add(place(prism(rng.uniform(0.12, 0.2) * min(scale, 2.0), -0.2, trunk_h), x, y, rng.uniform(0, np.pi), z),
                 ob.TRUNK, rng.uniform(0.3, 0.45))
        rz = rng.uniform(1.2, 2.5) * scale
        rxy = rng.uniform(1.5, 3.0) * scale
        crowns = [octahedron(rxy, rz, trunk_h + 0.7 * rz)]
        for _ in range(sc.crown_blobs - 1):  # lumps around the main crown
            dx, dy, dz = rng.uniform(-0.6, 0.6, 3) * (rxy, rxy, rz)
            lump = octahedron(rxy * rng.uniform(0.4, 0.8), rz * rng.uniform(0.4, 0.8), trunk_h + 0.7 * rz + dz)
            crowns.append(lump + np.array([dx, dy, 0.0]))
        self.add(place(np.concatenate(crowns), x, y, rng.uniform(0, np.pi), z), ob.VEGETATION, rng.uniform(0.4, 0.65))

    def _parking(self, start: np.ndarray, direction: np.ndarray, length: float, outward: np.ndarray) -> None:
        st, rng = self.street, self.rng
        usable = length - 2 * _PARKING_CLEARANCE
        n_slots = int(usable // _SLOT_LENGTH)
        if n_slots <= 0:
            return
        slot_u = _PARKING_CLEARANCE + _SLOT_LENGTH * (np.arange(n_slots) + 0.5) + (usable - n_slots * _SLOT_LENGTH) / 2
        slot_u = slot_u[rng.random(n_slots) < self.scene.parked_prob]
        heading = float(np.arctan2(direction[1], direction[0]))
        for u in slot_u:
            # Drawn only where vans are parked at all, so that the presets' scenes (no vans) stay as they were.
            van = self.scene.parked_van_prob > 0 and rng.random() < self.scene.parked_van_prob
            tris, remission = ob.van_shape(rng) if van else ob.car_shape(rng)
            lateral = 0.5 * st.parking_width + rng.uniform(-0.15, 0.1)
            xy = start + direction * (u + rng.uniform(-0.4, 0.4)) + outward * lateral
            yaw = heading + (np.pi if rng.random() < 0.3 else 0.0) + rng.normal(0.0, 0.03)
            inst = self.next_instance
            self.next_instance += 1
            self.add(place(tris, xy[0], xy[1], yaw, self.terrain.height(xy[0], xy[1]))[0], ob.TRUCK if van else ob.CAR,
                     remission, inst)
            self.parked_ids.append(inst)
            self.parked_xy.append(xy)


def build_static_scene(rng: np.random.Generator, grid: StreetGrid, street: StreetConfig, scene: SceneConfig,
                       terrain: Terrain, route_points: np.ndarray, reach: float,
                       first_instance: int = 1) -> StaticScene:
    """Every block within ``reach`` of ``route_points``; parked cars get instance ids from ``first_instance``."""
    builder = _Builder(rng, street, scene, terrain, first_instance)
    for i, j in blocks_near(grid, route_points, reach):
        builder.block(grid.xs[i], grid.ys[j], grid.xs[i + 1], grid.ys[j + 1])
    return StaticScene(
        TriangleSoup.concat(builder.parts),
        np.asarray(builder.parked_ids, np.int64),
        np.asarray(builder.parked_xy, float).reshape(-1, 2),
        builder.next_instance,
    )
