"""Label ids the simulator writes, and the shapes of its traffic participants.

Shapes are a few boxes each with realistic sizes (car ~4.5 x 1.8 x 1.5 m,
bus ~11 x 2.5 x 3.2 m, parked van ~5.6 x 2.0 x 2.3 m, cyclist ~1.8 x 0.6 x 1.75 m,
pedestrian ~0.5 x 0.5 x 1.75 m), in the object's own frame: x forward, y left, z up from
the ground.  Each kind has a static and a moving semantic id; which one a point gets depends on whether the object's
pose changed since the previous scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.sim.geometry import boxes

# SemanticKITTI ids (see ros2_mos.io.labels.SEMANTIC_NAMES).
CAR, BUS, TRUCK, PERSON, BICYCLIST = 10, 13, 18, 30, 31
ROAD, SIDEWALK, BUILDING = 40, 48, 50
VEGETATION, TRUNK, TERRAIN, POLE = 70, 71, 72, 80
MOVING_CAR, MOVING_BICYCLIST, MOVING_PERSON, MOVING_BUS = 252, 253, 254, 257


@dataclass(frozen=True)
class ObjectKind:
    """A kind of traffic participant: its label ids, its collision circles and how to shape one."""

    name: str
    static_id: int
    moving_id: int
    # Collision model: circles at these offsets along the heading, all of this radius.
    circle_offsets: tuple[float, ...]
    circle_radius: float


CAR_KIND = ObjectKind("car", CAR, MOVING_CAR, (-1.35, 0.0, 1.35), 1.0)
BUS_KIND = ObjectKind("bus", BUS, MOVING_BUS, (-4.5, -1.5, 1.5, 4.5), 1.35)
CYCLIST_KIND = ObjectKind("cyclist", BICYCLIST, MOVING_BICYCLIST, (-0.5, 0.5), 0.4)
PEDESTRIAN_KIND = ObjectKind("pedestrian", PERSON, MOVING_PERSON, (0.0,), 0.35)
KINDS = {k.name: k for k in (CAR_KIND, BUS_KIND, CYCLIST_KIND, PEDESTRIAN_KIND)}
#: Length (m) a column reserves for one of each kind of vehicle.
LENGTH = {"car": 4.9, "bus": 12.0}


def car_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A car: lower skirt (wheels), body and cabin; ~4.5 x 1.8 x 1.5 m, jittered in size and paint."""
    length, width = rng.uniform(4.1, 4.9), rng.uniform(1.7, 1.9)
    cabin_top = rng.uniform(1.4, 1.6)
    sizes = np.array([
        [length - 0.9, width - 0.2, 0.3],
        [length, width, 0.75],
        [length * rng.uniform(0.45, 0.6), width - 0.15, cabin_top - 1.05],
    ])
    centers = np.array([[0.0, 0.0, 0.15], [0.0, 0.0, 0.675], [-0.15 * length, 0.0, 0.5 * (1.05 + cabin_top)]])
    tris = boxes(sizes, centers)
    paint = rng.uniform(0.05, 0.9)
    remission = np.repeat([0.1, paint, 0.08], len(tris) // 3).astype(np.float32)  # tyres, paint, glass
    return tris, remission


def bus_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A bus or lorry: a tall box on a skirt, ~11 x 2.5 x 3.2 m; it hides much of the street beside it."""
    length, height = rng.uniform(10.0, 12.0), rng.uniform(3.0, 3.5)
    sizes = np.array([[length - 1.5, 2.3, 0.35], [length, 2.5, height - 0.35]])
    centers = np.array([[0.0, 0.0, 0.175], [0.0, 0.0, 0.35 + (height - 0.35) / 2]])
    tris = boxes(sizes, centers)
    remission = np.repeat([0.1, rng.uniform(0.2, 0.8)], len(tris) // 2).astype(np.float32)
    return tris, remission


def van_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A van or small lorry (parked only): a tall body with a lower bonnet, ~5.6 x 2.0 x 2.3 m (4.8-6.5 long,
    1.9-2.8 tall): taller than any car, so a network cannot learn that whatever is tall and close is a passing bus."""
    length, width, height = rng.uniform(4.8, 6.5), rng.uniform(1.9, 2.1), rng.uniform(1.9, 2.8)
    bonnet = rng.uniform(0.5, 1.0)
    sizes = np.array([[length - 0.9, width - 0.2, 0.3], [length - bonnet, width, height - 0.3],
                      [bonnet, width - 0.1, 0.75]])
    centers = np.array([[0.0, 0.0, 0.15], [-0.5 * bonnet, 0.0, 0.3 + (height - 0.3) / 2],
                        [0.5 * (length - bonnet), 0.0, 0.675]])
    tris = boxes(sizes, centers)
    remission = np.repeat([0.1, rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9)], len(tris) // 3).astype(np.float32)
    return tris, remission


def cyclist_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A bicycle (a thin slab) with a rider (torso and head): ~1.8 x 0.6 x 1.75 m."""
    sizes = np.array([[1.75, 0.12, 0.9], [0.55, 0.5, 0.7], [0.22, 0.2, 0.2]])
    centers = np.array([[0.0, 0.0, 0.5], [-0.15, 0.0, 1.3], [-0.05, 0.0, rng.uniform(1.7, 1.8)]])
    tris = boxes(sizes, centers)
    remission = np.repeat([0.35, rng.uniform(0.1, 0.6), 0.3], len(tris) // 3).astype(np.float32)
    return tris, remission


def pedestrian_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Legs, torso and head: ~0.5 x 0.5 x 1.75 m, height jittered."""
    h = rng.uniform(1.6, 1.9)
    sizes = np.array([[0.25, 0.38, 0.48 * h], [0.3, 0.5, 0.37 * h], [0.22, 0.2, 0.15 * h]])
    centers = np.array([[0.0, 0.0, 0.24 * h], [0.0, 0.0, 0.665 * h], [0.0, 0.0, 0.925 * h]])
    tris = boxes(sizes, centers)
    remission = np.repeat([rng.uniform(0.05, 0.5), rng.uniform(0.05, 0.6), 0.3], len(tris) // 3).astype(np.float32)
    return tris, remission


SHAPES = {"car": car_shape, "bus": bus_shape, "cyclist": cyclist_shape, "pedestrian": pedestrian_shape}
