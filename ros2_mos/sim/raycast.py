"""Ray casting against triangle soups with Embree (through ``embreex``).

Two scenes per scan: the static one is built once per sequence (its BVH is the
expensive part for long routes), the small dynamic one anew for every scan;
casting against both and keeping the nearer hit was measured faster than
rebuilding one combined scene per scan (benchmarks/design_figures.md).
Embree reports the hit distance (``tfar``) and the geometric normal directly,
so nothing has to be recomputed from the triangle index.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.errors import ConfigError
from ros2_mos.sim.geometry import TriangleSoup


def _embree():  # type: ignore[no-untyped-def]
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ConfigError(
            "the simulator needs the 'embreex' package for ray casting (pip install embreex); "
            f"import failed: {exc}"
        ) from exc
    return rtcore_scene, TriangleMesh


@dataclass
class Hits:
    """Nearest hit per ray: distance (inf where none), triangle index (-1), unit normal, which soup."""

    distance: np.ndarray
    triangle: np.ndarray
    normal: np.ndarray
    soup: np.ndarray  # index of the soup in the caster's list


class SoupScene:
    """An Embree scene of one triangle soup.

    Coordinates are shifted by ``origin`` before they go to Embree's float32, so a
    route kilometres from the world origin keeps millimetre precision.
    """

    def __init__(self, soup: TriangleSoup, origin: np.ndarray) -> None:
        self.soup = soup
        self.origin = np.asarray(origin, float)
        self._scene = None
        if len(soup):
            rtcore_scene, triangle_mesh = _embree()
            self._scene = rtcore_scene.EmbreeScene()
            triangle_mesh(self._scene, (soup.tris - self.origin).astype(np.float32))

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distance, triangle index, unnormalised normal) of the first hit of each ray."""
        n = len(directions)
        if self._scene is None:
            return np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3), np.float32)
        out = self._scene.run(
            np.ascontiguousarray(origins - self.origin, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            output=1,
        )
        tri = np.asarray(out["primID"], np.int64)
        dist = np.where(tri >= 0, np.asarray(out["tfar"], float), np.inf)
        return dist, tri, np.asarray(out["Ng"], np.float32)


def cast_nearest(scenes: list[SoupScene], origins: np.ndarray, directions: np.ndarray) -> Hits:
    """Cast every ray against every scene and keep the nearest hit (directions must be unit vectors)."""
    n = len(directions)
    origins = np.broadcast_to(np.asarray(origins, float), (n, 3))
    best = Hits(np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3), np.float32), np.full(n, -1, np.int64))
    for k, scene in enumerate(scenes):
        dist, tri, normal = scene.cast(origins, directions)
        closer = dist < best.distance
        best.distance[closer] = dist[closer]
        best.triangle[closer] = tri[closer]
        best.normal[closer] = normal[closer]
        best.soup[closer] = k
    norm = np.linalg.norm(best.normal, axis=1, keepdims=True)
    best.normal = np.divide(best.normal, norm, out=np.zeros_like(best.normal), where=norm > 0)
    return best
