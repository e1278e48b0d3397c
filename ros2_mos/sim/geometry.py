"""Triangle soups with per-triangle labels, and the few primitives a street is built of.

Every surface the LiDAR can hit is a triangle that carries its semantic id,
instance id and base remission, so that a ray's hit triangle index is all it
takes to label the point.  Objects are boxes, prisms and octahedra: a few
triangles each, which is plenty at LiDAR resolution and keeps ray casting fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The 8 corners of the unit cube centred at the origin, and its 12 outward triangles.
_CUBE_CORNERS = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_CUBE_FACES = np.array(
    [
        [0, 2, 3], [0, 3, 1],  # x = -0.5
        [4, 5, 7], [4, 7, 6],  # x = +0.5
        [0, 1, 5], [0, 5, 4],  # y = -0.5
        [2, 6, 7], [2, 7, 3],  # y = +0.5
        [0, 4, 6], [0, 6, 2],  # z = -0.5 (bottom)
        [1, 3, 7], [1, 7, 5],  # z = +0.5 (top)
    ]
)


@dataclass
class TriangleSoup:
    """Triangles (T, 3, 3) float64 with their semantic id, instance id and base remission."""

    tris: np.ndarray
    sem: np.ndarray
    inst: np.ndarray
    remission: np.ndarray

    def __len__(self) -> int:
        return len(self.tris)

    @classmethod
    def empty(cls) -> "TriangleSoup":
        return cls(np.zeros((0, 3, 3)), np.zeros(0, np.uint16), np.zeros(0, np.uint32), np.zeros(0, np.float32))

    @classmethod
    def labelled(cls, tris: np.ndarray, sem: int, inst: int = 0, remission: float = 0.3) -> "TriangleSoup":
        """One label for all of ``tris``."""
        tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
        n = len(tris)
        return cls(tris, np.full(n, sem, np.uint16), np.full(n, inst, np.uint32), np.full(n, remission, np.float32))

    @classmethod
    def concat(cls, parts: list["TriangleSoup"]) -> "TriangleSoup":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(
            np.concatenate([p.tris for p in parts]),
            np.concatenate([p.sem for p in parts]),
            np.concatenate([p.inst for p in parts]),
            np.concatenate([p.remission for p in parts]),
        )


def box(size: tuple[float, float, float], center: tuple[float, float, float] = (0.0, 0.0, 0.0),
        bottom: bool = True) -> np.ndarray:
    """Axis-aligned box triangles (12, or 10 without the bottom, which nothing sees on the ground)."""
    verts = _CUBE_CORNERS * np.asarray(size, float) + np.asarray(center, float)
    faces = _CUBE_FACES if bottom else np.delete(_CUBE_FACES, [8, 9], axis=0)
    return verts[faces]


def boxes(sizes: np.ndarray, centers: np.ndarray, yaws: np.ndarray | None = None, bottom: bool = False) -> np.ndarray:
    """Many boxes at once: (B, 3) sizes and centres, optional yaw about z; returns (B*F, 3, 3)."""
    sizes = np.asarray(sizes, float).reshape(-1, 3)
    centers = np.asarray(centers, float).reshape(-1, 3)
    faces = _CUBE_FACES if bottom else np.delete(_CUBE_FACES, [8, 9], axis=0)
    local = _CUBE_CORNERS[faces][None] * sizes[:, None, None, :]  # (B, F, 3, 3)
    if yaws is not None:
        local = rotate_z(local, np.asarray(yaws, float)[:, None, None])
    return (local + centers[:, None, None, :]).reshape(-1, 3, 3)


def prism(radius: float, z0: float, z1: float, sides: int = 6) -> np.ndarray:
    """A vertical n-gon prism (poles, trunks) centred on the z axis, without its bottom."""
    ang = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(ang), radius * np.sin(ang)], axis=1)
    nxt = np.roll(ring, -1, axis=0)
    lo0 = np.column_stack([ring, np.full(sides, z0)])
    lo1 = np.column_stack([nxt, np.full(sides, z0)])
    hi0 = np.column_stack([ring, np.full(sides, z1)])
    hi1 = np.column_stack([nxt, np.full(sides, z1)])
    side = np.concatenate([np.stack([lo0, lo1, hi1], 1), np.stack([lo0, hi1, hi0], 1)])
    top_c = np.tile([0.0, 0.0, z1], (sides, 1))
    top = np.stack([top_c, hi0, hi1], 1)
    return np.concatenate([side, top])


def octahedron(radius_xy: float, radius_z: float, center_z: float) -> np.ndarray:
    """A tree crown: 8 triangles around (0, 0, center_z)."""
    c = np.array([0.0, 0.0, center_z])
    eq = np.array([[radius_xy, 0, 0], [0, radius_xy, 0], [-radius_xy, 0, 0], [0, -radius_xy, 0]]) + c
    top, bot = c + [0, 0, radius_z], c - [0, 0, radius_z]
    nxt = np.roll(eq, -1, axis=0)
    upper = np.stack([eq, nxt, np.tile(top, (4, 1))], 1)
    lower = np.stack([nxt, eq, np.tile(bot, (4, 1))], 1)
    return np.concatenate([upper, lower])


def quad(x0: float, y0: float, x1: float, y1: float, z: float) -> np.ndarray:
    """A horizontal rectangle at height z as 2 triangles."""
    a, b, c, d = [x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]
    return np.array([[a, b, c], [a, c, d]], float)


def rotate_z(points: np.ndarray, yaw: np.ndarray | float) -> np.ndarray:
    """Rotate (..., 3) points about z by ``yaw`` (broadcast against the leading axes)."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = points[..., 0], points[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, np.broadcast_to(points[..., 2], x.shape)], axis=-1)


def place(
    template: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, z: float | np.ndarray = 0.0
) -> np.ndarray:
    """Copies of ``template`` (T, 3, 3) at poses (x, y, yaw) of shape (K,): returns (K, T, 3, 3)."""
    x, y, yaw = (np.asarray(a, float).reshape(-1) for a in (x, y, yaw))
    z = np.broadcast_to(np.asarray(z, float), x.shape)
    rotated = rotate_z(template[None], yaw[:, None, None])
    return rotated + np.stack([x, y, z], axis=1)[:, None, None, :]
