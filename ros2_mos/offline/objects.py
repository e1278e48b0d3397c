"""One scan's object candidates: ground removed from a local height grid, the rest cut into connected voxel clusters.

The ground under each point is the lowest point within ``ground_radius`` cells of a ``ground_cell``-metre grid, so
that slopes and curbs stay ground and a car's body does not (points ``ground_outlier`` below the lower quartile of
their neighbourhood's lowest points are spurious and left out); points more than ``ground_height`` above it are
candidates. Candidates are grouped into clusters of 26-connected occupied voxels (``voxel`` metres): a car close to
the sensor stays one cluster (in a range image its roof and sides break into bands at grazing angles), two cars
queueing a metre apart stay two, and a canopy above a car is a cluster of its own when there is a free voxel
between. A cluster is an *object* when it is object-sized: few enough metres long and high, standing on the ground,
with enough points. Points on no object that belong to one join it by label (they take its label but no part in
its evidence): the low ones (wheels, feet, a car's lowest ring), within ``ground_height`` of the ground, and the
fragments too small or flat to be objects, where an object's point lies within ``attach_distance`` metres of them
seen from above; and, given the sensor, loose points under an object's steep face in their range-image column
(:func:`attach_below`), and points of clusters too high off the ground to be objects over an object's steep face in
their column (:func:`attach_over`: a sparse sensor's upper rings on a van). Where the sensor's lowest beam cannot
reach the ground, the ground is at most the plane fitted just beyond (:func:`blind_floor`, ``blind_floor``). A
cluster longer than ``max_length`` (cars queueing bumper to bumper) is cut again with half-size voxels.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ros2_mos.core import kernels
from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.projection import closest_point_image, pixel_index_columns
from ros2_mos.core.segments import _union_find


def column_min(values: np.ndarray) -> np.ndarray:
    """Per column of (N, K) ``values`` its minimum: ``values.min(axis=0)``, column by column (numpy reduces a short
    trailing axis of a long array 10-20 times slower than each column alone)."""
    return np.array([values[:, i].min() for i in range(values.shape[1])], values.dtype)


def column_max(values: np.ndarray) -> np.ndarray:
    """Per column of (N, K) ``values`` its maximum (as :func:`column_min`)."""
    return np.array([values[:, i].max() for i in range(values.shape[1])], values.dtype)


def check_numbers(config: object, what: str, zero_ok: tuple[str, ...] = (), at_most_one: tuple[str, ...] = (),
                  whole: tuple[str, ...] = ()) -> None:
    """Every number of a config dataclass finite and > 0 (>= 0 for ``zero_ok``; <= 1 for ``at_most_one``); the fields
    named in ``whole`` whole numbers (not bools)."""
    import dataclasses
    import math

    for name in whole:
        value = getattr(config, name)
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{what}: {name} must be a whole number, got {value!r}")
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        low_ok = value >= 0 if f.name in zero_ok else value > 0
        if not math.isfinite(value) or not low_ok or (f.name in at_most_one and value > 1):
            bound = ">= 0" if f.name in zero_ok else "> 0"
            raise ConfigError(f"{what}: {f.name} must be a finite number {bound}"
                              f"{' and <= 1' if f.name in at_most_one else ''}, got {value!r}")


@dataclass(frozen=True)
class ObjectConfig:
    ground_cell: float = 1.0  # m
    ground_radius: int = 2  # cells
    ground_height: float = 0.3  # m above the local ground (kerbs and sidewalk edges stay below it)
    #: m: a point this far below the lower quartile of its neighbourhood's lowest points is not ground (the real 08a has
    #: returns 4-5 m under the road beneath the car ahead; taken as ground they lifted the road around them 5 m off
    #: it, into the car's object)
    ground_outlier: float = 1.5
    #: m: farther points are cut into no object (the ground grid, and memory, stay bounded whatever the farthest
    #: return). A 64-beam sensor sees a car 60-100 m away as rings enough to be one (60 m until round 50; 100 m:
    #: HDL-64E validation 96.56 / 95.87 -> 96.78 / 96.11, no drive down by more than 0.02; the sparser sensors
    #: unchanged; benchmarks/autolabel.md, round 50)
    max_range: float = 100.0
    #: The vehicle that carries the sensor (:class:`VehicleReturns`) is looked for this close to the sensor, seen
    #: from above (m; 0 = not at all): KITTI's HDL-64E sees parts of its own car 1.4-1.9 m away in every scan. Not
    #: farther: 2.2-2.7 m beside the sensor, a queue in the next lane that creeps along with it, or a wall, holds the
    #: same cells too (3 m: validation mean 93.87 -> 91.48, a jam 86.7 -> 69.4)
    ego_radius: float = 2.0
    ego_cell: float = 0.25  # m: sensor-frame cells ...
    ego_share: float = 0.5  # ... that hold points in at least this share of a drive's scans are the vehicle ...
    ego_travel: float = 0.5  # m: ... counting only scans this far from the last one counted (standing in a jam, ...
    ego_scans: int = 8  # ... the cars beside the sensor stand still in its frame too), and at least this many
    voxel: float = 0.4  # m
    #: a cluster of fewer points is a fragment, not an object: a sparse sensor sees a car 30-40 m away as 6-7 returns
    #: (8 before round 44; 4 cost the VLP-16's precision; such small objects are no seen-through evidence of their
    #: own, ``TrackConfig.evidence_points``: benchmarks/autolabel.md, round 44)
    min_points: int = 6
    max_length: float = 22.0  # m: a bus or a truck alongside still fits
    max_height: float = 4.5  # m
    min_height: float = 0.15  # m: a flatter cluster is one ring on the ground or a kerb, not something that moves ...
    #: m: ... when its top is this low above the ground too; higher up, one ring on a car's body (a sparse sensor
    #: sees most cars with one or two rings) is an object
    flat_top: float = 0.6
    max_bottom: float = 1.5  # m: an object's lowest point is this close to the ground
    attach_above: float = 0.08  # m: low points higher than this above the ground under an object are attached to it
    #: m: ... to the object with a point this close, seen from above: under it (0.4 m attached the road around
    #: pedestrians on the real r2, whose rings lie 0.1-0.2 m above the local ground's lowest point)
    attach_distance: float = 0.2
    #: Clusters too few (``min_points``) or too flat to be objects join the nearest object within ``attach_distance``
    #: the same way: a sparse sensor sees a car as rings, and a ring piece apart from the rest is such a fragment
    attach_fragments: bool = True
    #: degrees: a loose point (low or a fragment) also joins the object of the point just above it in its range-image
    #: column (the next ring up, found from the sensor's beams) when the two lie on a surface at least this steep
    #: (0: not at all). Where a sparse sensor sees no ground near an object (its beams reach the road only ~6 m from
    #: a VLP-16, and its rings lie 10-15 m apart 20-30 m out), the local ground is the object's own lowest ring,
    #: which the height rules above then take for ground; a car's side is steep, the road in front of it is not.
    attach_steep: float = 70.0
    #: m: a loose point also joins the object of the point just above it in its column where it lies lower than that
    #: point and behind it, seen from the sensor, by at most this much (0: not at all), however flat and whatever
    #: the ring below: the ray passed under the object's face to its recessed lower part (a car's wheels under its
    #: bumper and body), which lies at the height of the road in front of it; farther behind (1 m) takes more road
    #: than wheels ...
    attach_under: float = 0.6
    #: m: ... where the point lies more than this above the local ground (0: wherever): the road seen under a car's
    #: body is the ground itself, its wheels stand on it (a real road's rings lie up to 0.1 m over its local ground,
    #: so some of the road under a car near the sensor still joins it)
    attach_under_lift: float = 0.03
    #: cells, m: ... or more than ``attach_under_wide_lift`` above the lowest ground within ``attach_under_radius``
    #: ground cells (0: not at all). Where no ring reached the road near a car (24 m ahead of a VLP-32C the car hides
    #: the road behind it and the ring in front falls short), the car's own lowest ring under its bumper is the local
    #: ground, 0.2 m over the road, and was left on no object (VLP-32C suite easy-9301: 10 points a scan); farther
    #: around, the road is found. Not the narrow rule's 0.03 m: a road's rings lie that far over the lowest point of
    #: a window this wide (benchmarks/autolabel.md, round 49)
    attach_under_radius: int = 5
    attach_under_wide_lift: float = 0.1
    #: m: a low point that joined an object (by ``attach_distance``, ``attach_steep`` or ``attach_under``) leaves it
    #: again where its ring goes on as ground: the next return along its row of the range image, left or right,
    #: within this many metres, lies on no object and out of every object's ``attach_distance``, at its range and
    #: height within ``ring_ground_range`` and ``ring_ground_height`` (0: off). On flat ground a ring is a circle of
    #: one range: the sidewalk ring at a walker's feet (0.15 m over the road, so clear of the local ground) and the
    #: road seen under a car's body go on past the object at their range; a foot or a wheel stands in front of the
    #: ground its ring meets beyond it (VLP-32C suite: 1,754 sidewalk points on walkers, 4,413 road points under
    #: cars; real r2: road rings at the feet of cars, 8 % of its moving points; benchmarks/autolabel.md, round 49)
    ring_ground: float = 2.0
    ring_ground_range: float = 0.06
    ring_ground_height: float = 0.04
    #: Where the sensor's lowest beam cannot reach the ground (within ``|z| / tan(|fov_down|)`` of it: 6.5 m for a
    #: VLP-16 1.73 m up, 3.7 m for a HDL-64E), the local ground is the lowest ring of whatever stands there: where it
    #: lies more than ``ground_height`` above the plane through the local ground of the ``blind_ring`` metres just
    #: beyond, the plane is the ground (:func:`blind_floor`; with ``sensor`` only)
    blind_floor: bool = True
    blind_ring: float = 6.0
    #: A point of a cluster too high off the ground to be an object (``max_bottom``) joins the object of the next
    #: return below it in its range-image column where the two lie on a surface ``attach_steep`` steep and at most
    #: ``raised_rows`` rows' spacing apart at that range (with ``sensor`` only): a sparse sensor's rings on a van's
    #: or a bus's side lie so far apart that the upper ones are clusters of their own, up in the air; a tree crown or
    #: an awning over a car lies farther above it
    attach_raised: bool = True
    raised_rows: float = 2.0

    def __post_init__(self) -> None:
        check_numbers(self, "autolabel objects",
                      zero_ok=("ground_radius", "attach_above", "ego_radius", "attach_steep", "attach_under",
                               "attach_under_lift", "attach_under_radius", "ring_ground"),
                      at_most_one=("ego_share",),
                      whole=("ground_radius", "attach_under_radius", "min_points", "ego_scans"))
        if self.attach_steep > 90:
            raise ConfigError(f"autolabel objects: attach_steep must be at most 90 degrees, got {self.attach_steep!r}")


@dataclass
class ScanObjects:
    """Per point its object (-1: ground, background or too far); per object its point count."""

    point_object: np.ndarray  # (N,) int32, attached low points included
    counts: np.ndarray  # (K,) int64, the object's own points (not the attached ones)
    attached: np.ndarray  # (N,) bool: a low point that takes its object's label
    height_above_ground: np.ndarray  # (N,) float32
    #: (N,) bool: a point of a cluster too long or too tall to be an object (a wall, a hedge, a row of trees)
    structure: np.ndarray

    @property
    def n_objects(self) -> int:
        return len(self.counts)


def _cell_lowest(ij: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    lowest = np.full(shape[0] * shape[1], np.inf, np.float32)
    np.minimum.at(lowest, ij[:, 0] * shape[1] + ij[:, 1], z)  # a flat index: far faster than a tuple of two
    return lowest.reshape(shape)


def _windows(grid: np.ndarray, radius: int) -> np.ndarray:
    """(window cells, *grid.shape): each cell's (2 radius + 1)^2 neighbourhood, inf outside the grid."""
    padded = np.full((grid.shape[0] + 2 * radius, grid.shape[1] + 2 * radius), np.inf, np.float32)
    padded[radius: radius + grid.shape[0], radius: radius + grid.shape[1]] = grid
    return np.stack([padded[di: di + grid.shape[0], dj: dj + grid.shape[1]]
                     for di in range(2 * radius + 1) for dj in range(2 * radius + 1)])


def local_ground(points: np.ndarray, cell: float, radius: int, outlier_drop: float = np.inf) -> np.ndarray:
    """Per point the height of the lowest point within ``radius`` cells of its grid cell, leaving out points more
    than ``outlier_drop`` below the lower quartile of the neighbourhood's cells' lowest points (spurious returns
    under the road, which would lift everything around them off the ground; the quartile, not the median, so that
    ground under trees, whose neighbours' lowest points may be canopy, stays ground)."""
    ij = np.floor(points[:, :2] / cell).astype(np.int64)
    ij -= column_min(ij)
    shape = (int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1)
    if kernels.enabled() and points.dtype == np.float32:
        return kernels.local_ground(points, ij[:, 0] * shape[1] + ij[:, 1], shape, radius, outlier_drop)
    z = points[:, 2].astype(np.float32)
    lowest = _cell_lowest(ij, z, shape)
    if not np.isfinite(outlier_drop):
        return _windows(lowest, radius).min(axis=0)[ij[:, 0], ij[:, 1]]
    windows = np.sort(_windows(lowest, radius), axis=0)  # empty cells (inf) last; row 0 is the minimum
    filled = np.isfinite(windows).sum(axis=0)
    quartile = np.take_along_axis(windows, np.maximum(filled - 1, 0)[None] // 4, axis=0)[0]
    kept = z >= quartile[ij[:, 0], ij[:, 1]] - outlier_drop
    ground = windows[0] if kept.all() else _windows(_cell_lowest(ij[kept], z[kept], shape), radius).min(axis=0)
    return ground[ij[:, 0], ij[:, 1]]


#: :func:`blind_floor`: ground cells this far (m) off the fitted plane are left out of the second fit, and at least this
#: many cells must hold ground
FLOOR_OUTLIER = 0.3
FLOOR_MIN_CELLS = 12


def blind_floor(points: np.ndarray, ground: np.ndarray, sensor: SensorConfig, ring: float,
                lift: float) -> np.ndarray:
    """``ground`` (per point, :func:`local_ground`), with the ground plane where the sensor's beams cannot reach the
    ground and the local ground is something standing there.

    The plane (z = a + b x + c y, sensor frame, so that a pitched sensor is followed) is fitted twice by least
    squares to the local ground of the 1 m cells ``ring`` metres beyond where the lowest beam meets it (the second
    time without the cells :data:`FLOOR_OUTLIER` off the first), the sensor's height taken from the median local
    ground within 3-15 m. Within the blind radius a point's ground is the plane where its local ground lies more than
    ``lift`` above it (the lowest ring of something standing there; the real HDL-64E's first ground rings lie about
    that radius out, a little off the plane); elsewhere, and where fewer than :data:`FLOOR_MIN_CELLS` cells are left,
    ``ground`` as it is.
    """
    horizontal = np.hypot(points[:, 0], points[:, 1])
    slope = np.tan(-sensor.fov_down)
    if slope <= 0:
        return ground
    nearby = (horizontal > 3.0) & (horizontal < 15.0)
    if not nearby.any():
        return ground
    below = -float(np.median(ground[nearby]))
    if not below > 0:
        return ground
    blind = below / slope
    beyond = np.flatnonzero((horizontal > blind) & (horizontal < blind + ring))
    ij = np.floor(points[beyond, :2]).astype(np.int64)
    _, first = np.unique(_cell_keys(ij), return_index=True)  # one sample per 1 m cell
    if len(first) < FLOOR_MIN_CELLS:
        return ground
    xy = ij[first] + 0.5
    z = ground[beyond[first]].astype(np.float64)
    design = np.column_stack([np.ones(len(xy)), xy])
    keep = np.ones(len(z), bool)
    for _ in range(2):
        if keep.sum() < FLOOR_MIN_CELLS:
            return ground
        coef = np.linalg.lstsq(design[keep], z[keep], rcond=None)[0]
        keep = np.abs(design @ coef - z) <= FLOOR_OUTLIER
    inside = np.flatnonzero(horizontal < blind)
    plane = (coef[0] + coef[1] * points[inside, 0] + coef[2] * points[inside, 1]).astype(ground.dtype)
    out = ground.copy()
    lifted = ground[inside] - plane > lift  # only where the "ground" is clearly something standing on it
    out[inside[lifted]] = plane[lifted]
    return out


#: Half of the 26 neighbour offsets of a voxel: each edge is found once.
_HALF_NEIGHBOURS = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                    if (dx, dy, dz) > (0, 0, 0)]


def voxel_clusters(points: np.ndarray, voxel: float, groups: np.ndarray | None = None) -> np.ndarray:
    """Per point, the id (0..K-1) of its cluster of 26-connected occupied voxels; with ``groups`` (per point, >= 0),
    points of different groups are never in one cluster (many small sets cut in one call)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor(points / voxel).astype(np.int64)
    ijk -= column_min(ijk) - 1  # a free border: neighbours never wrap
    dims = column_max(ijk) + 2
    keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    if groups is not None:  # the group outermost: a neighbour step never leaves its group's block (the border)
        keys = keys + np.asarray(groups, np.int64) * (dims[0] * dims[1] * dims[2])
    cells, point_cell = np.unique(keys, return_inverse=True)
    steps = np.array([(dx * dims[1] + dy) * dims[2] + dz for dx, dy, dz in _HALF_NEIGHBOURS], np.int64)
    if kernels.enabled():
        return kernels.voxel_clusters(cells, steps)[point_cell.reshape(-1)]
    a, b = [], []
    for step in steps:
        shifted = cells + step
        at = np.searchsorted(cells, shifted)
        at = np.minimum(at, len(cells) - 1)
        hit = np.flatnonzero(cells[at] == shifted)
        a.append(hit)
        b.append(at[hit])
    roots = _union_find(len(cells), np.concatenate(a), np.concatenate(b))
    _, cluster = np.unique(roots, return_inverse=True)
    return cluster[point_cell.reshape(-1)]


def split_long_clusters(points: np.ndarray, cluster: np.ndarray, config: ObjectConfig) -> np.ndarray:
    """Clusters longer than ``max_length`` (cars queueing bumper to bumper, linked through one voxel) cut again
    with voxels half the size; returns compact ids."""
    k = int(cluster.max()) + 1 if len(cluster) else 0
    lo = np.full((k, 2), np.inf, np.float32)
    hi = np.full((k, 2), -np.inf, np.float32)
    for axis in range(2):
        np.minimum.at(lo[:, axis], cluster, points[:, axis])
        np.maximum.at(hi[:, axis], cluster, points[:, axis])
    long = np.flatnonzero(np.hypot(*(hi - lo).T) > config.max_length)
    if len(long) == 0:
        return cluster
    out = cluster.astype(np.int64).copy()
    inside = np.flatnonzero(np.isin(cluster, long))
    out[inside] = k + voxel_clusters(points[inside], config.voxel / 2)
    used = np.zeros(int(out.max()) + 1, bool)
    used[out] = True
    return (np.cumsum(used) - 1)[out]  # the ids in use, compact and in order (np.unique's inverse, without a sort)


_EGO_OFFSET = 1 << 15  # cell indices (clipped to +-2^15) made non-negative before they are packed into one key
_EGO_SPAN = 1 << 16


def _ego_keys(points: np.ndarray, config: ObjectConfig) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the points within ``ego_radius`` of the sensor seen from above, their sensor-frame cell keys)."""
    near = np.flatnonzero(np.einsum("ij,ij->i", points[:, :2], points[:, :2]) < config.ego_radius**2)
    scaled = np.clip(points[near, :3] / config.ego_cell, 2 - _EGO_OFFSET, _EGO_OFFSET - 2)
    ijk = np.floor(scaled).astype(np.int64) + _EGO_OFFSET
    return near, (ijk[:, 0] * _EGO_SPAN + ijk[:, 1]) * _EGO_SPAN + ijk[:, 2]


class VehicleReturns:
    """The returns of the vehicle that carries the sensor, found from a whole drive.

    Its body, mounts and mirrors move with the sensor, so while the sensor travels they fill the same sensor-frame
    cells (``ego_cell`` metres, within ``ego_radius``) in most scans (``ego_share`` of the scans ``ego_travel``
    apart); what passes close by (a car in the next lane, a cyclist, a wall) fills a cell for a few scans. Those
    cells, grown by one cell each way against the jitter of the returns, are no object. A fixed radius would also
    cut what passes within it (r1: a van 1.9 m beside the sensor). Scans taken standing are not counted: in a jam
    the queue beside the sensor stands still in its frame too. Fewer than ``ego_scans`` counted: no cells.
    """

    def __init__(self, config: ObjectConfig) -> None:
        self.config = config
        self.scans = 0  # counted
        self._keys: list[np.ndarray] = []
        self._last: np.ndarray | None = None  # where the last counted scan was taken

    def add(self, points: np.ndarray, pose: np.ndarray) -> None:
        """One scan (sensor frame) and its pose; counted when taken ``ego_travel`` from the last one counted."""
        if self.config.ego_radius <= 0:
            return
        if self._last is not None and np.linalg.norm(pose[:3, 3] - self._last) < self.config.ego_travel:
            return
        self._last = np.array(pose[:3, 3], np.float64)
        self.scans += 1
        self._keys.append(np.unique(_ego_keys(points, self.config)[1]))

    def cells(self) -> np.ndarray:
        """Sorted keys of the vehicle's cells, grown by one cell each way."""
        if self.scans < self.config.ego_scans:
            return np.zeros(0, np.int64)
        keys, count = np.unique(np.concatenate(self._keys), return_counts=True)
        held = keys[count >= self.config.ego_share * self.scans]
        steps = np.array([(a * _EGO_SPAN + b) * _EGO_SPAN + c
                          for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)], np.int64)
        return np.unique((held[:, None] + steps[None, :]).reshape(-1))


def on_vehicle(points: np.ndarray, cells: np.ndarray, config: ObjectConfig) -> np.ndarray:
    """Which points (sensor frame) fall in the vehicle's cells (:meth:`VehicleReturns.cells`)."""
    out = np.zeros(len(points), bool)
    if len(cells) and config.ego_radius > 0:
        near, keys = _ego_keys(points, config)
        out[near] = np.isin(keys, cells, assume_unique=False)
    return out


def find_objects(points: np.ndarray, config: ObjectConfig = ObjectConfig(),
                 vehicle: np.ndarray | None = None, sensor: SensorConfig | None = None) -> ScanObjects:
    """Ground, clusters and object-sized clusters of one scan (sensor frame, finite points); points in ``vehicle``'s
    cells (:meth:`VehicleReturns.cells`) are on no object. With ``sensor``, the ground in the sensor's blind spot
    comes from the plane beyond it (``blind_floor``) and loose points also join the object above them in their
    range-image column (``attach_steep``)."""
    n = len(points)
    horizontal = np.einsum("ij,ij->i", points[:, :2], points[:, :2])
    # The ground of the points that can be on an object or beside one (the grid's size, and memory, stay bounded
    # whatever the farthest return); farther points are ground (height 0).
    near = np.flatnonzero(horizontal < (config.max_range + (config.ground_radius + 1) * config.ground_cell) ** 2)
    height = np.zeros(n, np.float32)
    if len(near):
        ground = local_ground(points[near], config.ground_cell, config.ground_radius, config.ground_outlier)
        if sensor is not None and config.blind_floor:
            ground = blind_floor(points[near], ground, sensor, config.blind_ring, config.ground_height)
        height[near] = points[near, 2] - ground
    free = ~on_vehicle(points, vehicle, config) if vehicle is not None else True
    candidate = np.flatnonzero((height > config.ground_height) & free
                               & (horizontal + points[:, 2] ** 2 < config.max_range**2))
    cluster = voxel_clusters(points[candidate], config.voxel)
    cluster = split_long_clusters(points[candidate], cluster, config)
    k = int(cluster.max()) + 1 if len(cluster) else 0
    counts = np.bincount(cluster, minlength=k)
    pts = points[candidate]
    lo = np.full((k, 3), np.inf, np.float32)
    hi = np.full((k, 3), -np.inf, np.float32)
    for axis in range(3):
        np.minimum.at(lo[:, axis], cluster, pts[:, axis])
        np.maximum.at(hi[:, axis], cluster, pts[:, axis])
    bottom = np.full(k, np.inf, np.float32)
    np.minimum.at(bottom, cluster, height[candidate])
    top = np.full(k, -np.inf, np.float32)
    np.maximum.at(top, cluster, height[candidate])
    length = np.hypot(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
    tall = hi[:, 2] - lo[:, 2]
    too_large = (length > config.max_length) | (tall > config.max_height)  # a wall, a hedge: a structure
    good = ((counts >= config.min_points) & ~too_large
            & ((tall >= config.min_height) | (top >= config.flat_top)) & (bottom <= config.max_bottom))
    new_id = np.full(k, -1, np.int32)
    new_id[good] = np.arange(int(good.sum()), dtype=np.int32)
    point_object = np.full(n, -1, np.int32)
    point_object[candidate] = new_id[cluster]
    low = (height <= config.ground_height) & free & (horizontal < config.max_range**2)
    loose = low & (height > config.attach_above)
    if config.attach_fragments:
        fragment = (counts < config.min_points) | ((tall < config.min_height) & (top < config.flat_top))
        loose[candidate[fragment[cluster]]] = True
    attached = attach_to_nearest(points, np.flatnonzero(loose), point_object, config.attach_distance)
    if sensor is not None and config.attach_steep > 0 and (point_object >= 0).any():
        image = closest_point_image(points, sensor)  # one range image for both column rules
        # down to the ground: in a blind spot the object's lowest ring is the "ground"
        column = (loose | low) & (point_object < 0)
        lifted = height > config.attach_under_lift if config.attach_under_lift > 0 else None
        if lifted is not None and config.attach_under_radius > config.ground_radius:  # objects: ``near`` has points
            # ... or clear of the lowest ground farther around (a car's lowest ring that is its own local ground)
            wide = local_ground(points[near], config.ground_cell, config.attach_under_radius, config.ground_outlier)
            lifted[near] |= points[near, 2] - np.minimum(ground, wide) > config.attach_under_wide_lift
        attached |= attach_below(points, np.flatnonzero(column), point_object, sensor, config.attach_steep, image,
                                 config.attach_under, lifted)
        if config.ring_ground > 0:  # the ground rings that joined: not the raised rings below, which are no ground
            joined = np.flatnonzero(attached & low & (point_object >= 0))
            back = on_ground_ring(points, joined, point_object, np.where(attached, -1, point_object), low, image,
                                  config)
            point_object[back] = -1
            attached[back] = False
        if config.attach_raised:
            raised = candidate[((bottom > config.max_bottom) & ~good)[cluster]]
            attached |= attach_over(points, raised, point_object, sensor, config.attach_steep, config.raised_rows,
                                    image)
    structure = np.zeros(n, bool)
    structure[candidate] = too_large[cluster]
    return ScanObjects(point_object, counts[good], attached, height, structure)


class _StripIndex:
    """Points (indices into ``points``) sorted by x, for the ones within an axis-aligned box seen from above."""

    def __init__(self, points: np.ndarray, which: np.ndarray) -> None:
        order = np.argsort(points[which, 0], kind="stable")
        self._which = which[order]
        self._x = points[self._which, 0]
        self._y = points[self._which, 1]

    def within(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        a, b = np.searchsorted(self._x, lo[0]), np.searchsorted(self._x, hi[0], side="right")
        y = self._y[a:b]
        return self._which[a:b][(y >= lo[1]) & (y <= hi[1])]


def moving_clusters(points: np.ndarray, found: ScanObjects, moving: np.ndarray, config: ObjectConfig,
                    lift: float, apart: float, sensor: SensorConfig | None, spacing: float = 0.0) -> ScanObjects:
    """``found`` with the clusters (``config.voxel``) of points on no object that the online model labelled
    ``moving`` as objects of their own, numbered after ``found``'s: those of ``config.min_points`` or more, none of
    whose points lies within ``apart`` m of an object's, seen from above (0: wherever), and that stand more than
    ``lift`` m (their median height) over the lowest return of the scan's other rings within ``ground_cell *
    (ground_radius + 0.5)`` m of them, or have none around (with ``sensor``, whose rows are the rings; without it,
    none is dropped for this). Not on a structure (a wall), not within ``config.ego_radius`` of the sensor nor
    beyond ``config.max_range``; with ``sensor``, not nearer than where its rows lie ``spacing`` m apart (its field
    of view over its rows; 0: anywhere), for nearer, a car is seen by enough rings to be an object. A sparse sensor's
    one or two rings on a car 30 m away have no other ring near them; a piece of the road ring that the model
    labelled moving beside a car lies among the road's other rings."""
    horizontal = np.hypot(points[:, 0], points[:, 1])
    nearest = config.ego_radius
    if sensor is not None and spacing > 0:
        nearest = max(nearest, spacing / np.tan(sensor.fov / sensor.height))  # as attach_over spaces its rows
    loose = np.flatnonzero((found.point_object < 0) & moving & ~found.structure
                           & (horizontal > nearest) & (horizontal < config.max_range))
    if len(loose) < config.min_points:
        return found
    cluster = voxel_clusters(points[loose], config.voxel)
    counts = np.bincount(cluster)
    keep = counts >= config.min_points
    if not keep.any():
        return found
    members = np.split(loose[np.argsort(cluster, kind="stable")], np.cumsum(counts)[:-1])
    lo = np.full((len(counts), 2), np.inf, points.dtype)  # each cluster's box seen from above
    hi = np.full((len(counts), 2), -np.inf, points.dtype)
    np.minimum.at(lo, cluster, points[loose, :2])
    np.maximum.at(hi, cluster, points[loose, :2])
    if apart > 0:  # a cluster beside an object is left to it (``AutolabelConfig.cue_attach``)
        objects_by_x = _StripIndex(points, np.flatnonzero(found.point_object >= 0))
        for c in np.flatnonzero(keep):
            beside = points[objects_by_x.within(lo[c] - apart, hi[c] + apart), :2]
            keep[c] = not any((d2 <= apart * apart).any()
                              for _, d2 in _square_distances(points[members[c], :2], beside))
    if sensor is not None and keep.any():  # on the ground that the scan's other rings around it lie on: the road
        others = np.ones(len(points), bool)
        others[loose] = False
        others_by_x = _StripIndex(points, np.flatnonzero(others))
        rows = pixel_index_columns(*(np.ascontiguousarray(points[:, i], np.float32) for i in range(3)), sensor).v
        reach = config.ground_cell * (config.ground_radius + 0.5)
        for c in np.flatnonzero(keep):
            own = members[c]
            around = others_by_x.within(lo[c] - reach, hi[c] + reach)
            around = around[~np.isin(rows[around], rows[own])]
            if len(around) and np.median(points[own, 2]) - points[around, 2].min() <= lift:
                keep[c] = False
    new_id = np.full(len(counts), -1, np.int32)
    new_id[keep] = found.n_objects + np.arange(int(keep.sum()), dtype=np.int32)
    point_object = found.point_object.copy()
    point_object[loose] = new_id[cluster]
    return ScanObjects(point_object, np.concatenate([found.counts, counts[keep]]), found.attached,
                       found.height_above_ground, found.structure)


def on_ground_ring(points: np.ndarray, joined: np.ndarray, point_object: np.ndarray, own: np.ndarray,
                   low: np.ndarray, image: np.ndarray, config: ObjectConfig) -> np.ndarray:
    """Which of the points ``joined`` (indices: low points given an object, ``point_object``) lie on a ring that
    goes on as ground (``ObjectConfig.ring_ground``): in their row of ``image`` (the closest point per pixel), the
    nearest low return left or right on no object lies within ``ring_ground`` metres at their range and height, and
    out of ``attach_distance`` of every object's own points (``own``: the objects without what joined them, a
    scratch copy that this changes)."""
    out = np.zeros(len(points), bool)
    if len(joined) == 0:
        return out
    h, w = image.shape
    filled = image >= 0
    at = np.where(filled, image, 0)
    ground = filled & low[at] & (point_object[at] < 0)
    columns = np.broadcast_to(np.arange(w), (h, w))
    before = np.maximum.accumulate(np.where(ground, columns, -1), axis=1)  # the last ground column up to each
    after = np.flip(np.minimum.accumulate(np.flip(np.where(ground, columns, w), axis=1), axis=1), axis=1)
    chosen = np.zeros(len(points), bool)
    chosen[joined] = True
    v, u = np.nonzero(filled & chosen[at])
    pairs = []  # (joined point, the ground return beside it), both sides
    for side in (before, after):
        column = side[v, u]
        has = (column >= 0) & (column < w)
        pairs.append((image[v[has], u[has]], image[v[has], column[has]]))
    p, q = (np.concatenate(x) for x in zip(*pairs))
    same = (np.hypot(*(points[p, :2] - points[q, :2]).T) <= config.ring_ground) \
        & (np.abs(np.linalg.norm(points[p], axis=1) - np.linalg.norm(points[q], axis=1)) <= config.ring_ground_range) \
        & (np.abs(points[p, 2] - points[q, 2]) <= config.ring_ground_height)
    if same.any():  # ... and that return is out of every object's reach (else it is the object's own, unjoined)
        reached = attach_to_nearest(points, q[same], own, config.attach_distance)
        out[p[same][~reached[q[same]]]] = True
    return out


#: :func:`attach_below` looks this many rows up (and down) a column for the next ring (a VLP-32C's beams are spread
#: unevenly over its image's rows)
COLUMN_SEARCH_ROWS = 3
#: :func:`attach_below`: a point continues the ground of the ring below it in its column (the road at a car's foot)
#: where it rises at most this many metres over it, however far apart the two lie: a sparse sensor's rings meet the
#: road metres apart, and a car's lowest ring a few tenths of a metre up would continue the road below it as a
#: gentle grade (one that grew with the distance between them left far cars' lowest rings to the ground) ...
GROUND_STEP = 0.15
#: ... and no steeper than this (degrees): a car's side rises steeply from ring to ring
GROUND_STEEPEST = 20.0


def _next_return(image: np.ndarray, v: int, cols: np.ndarray, step: int) -> np.ndarray:
    """Per column ``cols``: the index of the first return from row ``v + step`` on in that direction (up to
    :data:`COLUMN_SEARCH_ROWS` rows), -1 where none."""
    out = np.full(len(cols), -1, np.int64)
    for k in range(1, COLUMN_SEARCH_ROWS + 1):
        row = v + step * k
        if not 0 <= row < image.shape[0]:
            break
        todo = out < 0
        out[todo] = image[row, cols[todo]]
    return out


def _column_rows(points: np.ndarray, which: np.ndarray, point_object: np.ndarray, sensor: SensorConfig,
                 rows: range, image: np.ndarray | None = None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Per row v of the range image, in the order of ``rows``: (v, the columns whose closest return in row v is one
    of the points ``which``, the image of closest returns: ``image`` where given, else computed); nothing where
    ``which`` is empty or no point is on an object."""
    if len(which) == 0 or not (point_object >= 0).any():
        return
    if image is None:
        image = closest_point_image(points, sensor)
    chosen = np.zeros(len(points), bool)
    chosen[which] = True
    for v in rows:
        cols = np.flatnonzero(image[v] >= 0)
        cols = cols[chosen[image[v, cols]]]
        if len(cols):
            yield v, cols, image


def _compiled_columns(points: np.ndarray, which: np.ndarray, point_object: np.ndarray, sensor: SensorConfig,
                      image: np.ndarray | None) -> np.ndarray | None:
    """The image of closest points for the compiled :func:`attach_below` / :func:`attach_over` (given or computed);
    None where the numpy code runs instead (kernels off, other dtypes, or nothing to attach, as
    :func:`_column_rows`)."""
    if not kernels.enabled() or points.dtype != np.float32 or point_object.dtype != np.int32:
        return None
    if len(which) == 0 or not (point_object >= 0).any():
        return None
    image = closest_point_image(points, sensor) if image is None else image
    return image if image.dtype == np.int32 and image.flags.c_contiguous else None


def attach_below(points: np.ndarray, loose: np.ndarray, point_object: np.ndarray, sensor: SensorConfig,
                 steep: float, image: np.ndarray | None = None, under: float = 0.0,
                 under_ok: np.ndarray | None = None) -> np.ndarray:
    """Give each of the points ``loose`` (indices; on no object) the object id of the next return above it in its
    range-image column where that return is on an object and the two lie on a surface at least ``steep`` degrees
    steep (height difference over horizontal distance), unless the point continues the ground of the return below
    it (:data:`GROUND_STEP`, :data:`GROUND_STEEPEST`: the road at the foot of a car); and,
    with ``under`` > 0, where the point lies lower than that return and behind it seen from the sensor by at most
    ``under`` metres (horizontally), whatever the slope and the ground below: under the object's face (only the
    points ``under_ok``, per point, where given). Row by row from the top, so that a column of loose points under an
    object joins it ring by ring. Returns which points were given one. ``image``: the points'
    :func:`closest_point_image`, where the caller has it."""
    attached = np.zeros(len(points), bool)
    horizontal = np.hypot(points[:, 0], points[:, 1])
    z = points[:, 2]
    steep_slope, gentle_slope = np.tan(np.radians(steep)), np.tan(np.radians(GROUND_STEEPEST))
    image = _compiled_columns(points, loose, point_object, sensor, image)
    if image is not None:
        return kernels.attach_below(image, loose, horizontal, z, point_object, steep_slope, gentle_slope,
                                    GROUND_STEP, COLUMN_SEARCH_ROWS, under, under_ok)
    for v, cols, image in _column_rows(points, loose, point_object, sensor, range(1, sensor.height), image):
        point, above, below = image[v, cols], _next_return(image, v, cols, -1), _next_return(image, v, cols, 1)
        has = above >= 0
        point, above, below = point[has], above[has], below[has]
        rise = z[above] - z[point]
        behind = horizontal[point] - horizontal[above]
        beneath = (behind > 0) & (behind <= under) if under > 0 else np.zeros(len(point), bool)
        if under_ok is not None:
            beneath &= under_ok[point]
        on_face = (point_object[above] >= 0) & (rise > 0) & ((rise >= steep_slope * np.abs(behind)) | beneath)
        b = np.maximum(below, 0)
        step, apart = z[point] - z[b], np.abs(horizontal[point] - horizontal[b])
        on_ground = (below >= 0) & (step <= np.minimum(GROUND_STEP, gentle_slope * apart))
        join = on_face & (~on_ground | beneath)
        point_object[point[join]] = point_object[above[join]]
        attached[point[join]] = True
    return attached


def attach_over(points: np.ndarray, raised: np.ndarray, point_object: np.ndarray, sensor: SensorConfig,
                steep: float, rows: float, image: np.ndarray | None = None) -> np.ndarray:
    """Give each of the points ``raised`` (indices; on no object) the object id of the next return below it in its
    range-image column where that return is on an object, the point rises over it, the two lie on a surface at
    least ``steep`` degrees steep and the rise is at most ``rows`` times the spacing of the sensor's rows at the
    point's horizontal range. Row by row from the bottom, so that a stack of rings over an object joins it ring by
    ring. Returns which points were given one. ``image`` as for :func:`attach_below`."""
    attached = np.zeros(len(points), bool)
    horizontal = np.hypot(points[:, 0], points[:, 1])
    z = points[:, 2]
    steep_slope, row_slope = np.tan(np.radians(steep)), rows * np.tan(sensor.fov / sensor.height)
    image = _compiled_columns(points, raised, point_object, sensor, image)
    if image is not None:
        return kernels.attach_over(image, raised, horizontal, z, point_object, steep_slope, row_slope,
                                   COLUMN_SEARCH_ROWS)
    for v, cols, image in _column_rows(points, raised, point_object, sensor, range(sensor.height - 2, -1, -1),
                                       image):
        point, below = image[v, cols], _next_return(image, v, cols, 1)
        has = below >= 0
        point, below = point[has], below[has]
        rise = z[point] - z[below]
        join = ((point_object[below] >= 0) & (rise > 0)
                & (rise >= steep_slope * np.abs(horizontal[point] - horizontal[below]))
                & (rise <= row_slope * horizontal[point]))
        point_object[point[join]] = point_object[below[join]]
        attached[point[join]] = True
    return attached


#: :func:`attach_to_nearest` measures top-view distances on cells of this size (m)
ATTACH_GRID = 0.1
_ATTACH_OFFSET = 1 << 20  # cell indices made non-negative before they are packed into one key
_ATTACH_SPAN = 1 << 21


def _cell_keys(ij: np.ndarray) -> np.ndarray:
    ij = np.clip(ij, 1 - _ATTACH_OFFSET, _ATTACH_OFFSET - 1) + _ATTACH_OFFSET
    return ij[:, 0] * _ATTACH_SPAN + ij[:, 1]


def _top_cells(points: np.ndarray, which: np.ndarray, size: float) -> np.ndarray:
    """The keys of the top-view cells (``size`` metres) that the points ``which`` (indices) lie in."""
    return _cell_keys(np.floor(points[which, :2] / size).astype(np.int64))


_AROUND = np.array([di * _ATTACH_SPAN + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)], np.int64)


def _cells_around(keys: np.ndarray) -> np.ndarray:
    """The sorted keys of the cells ``keys`` and of the 8 cells beside each."""
    return np.unique((np.unique(keys)[:, None] + _AROUND).ravel())


#: :func:`nearest_object_within` compares at most this many (point, object point) pairs at once (12 bytes each)
NEAREST_PAIRS = 1 << 21


def _square_distances(a: np.ndarray, b: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """The squared distances from the (N, 2) points ``a`` to the (M, 2) points ``b``, in chunks of rows of at most
    :data:`NEAREST_PAIRS` pairs: (the chunk's first row, its (rows, M) distances)."""
    step = max(1, NEAREST_PAIRS // max(len(b), 1))
    for start in range(0, len(a), step):
        d = a[start: start + step, None] - b[None]
        yield start, np.einsum("ijk,ijk->ij", d, d)


def nearest_object_within(points: np.ndarray, which: np.ndarray, point_object: np.ndarray, reach: float) -> np.ndarray:
    """Per point ``which`` (indices), the id in ``point_object`` of the object with the nearest point within ``reach``
    metres of it seen from above (exact distances), -1 where none. Only the objects' points in and beside the
    ``reach``-sized cells of the points ``which`` are compared, so a few points near a large scene cost little."""
    if not reach > 0:
        raise ValueError(f"reach must be a positive number of metres, got {reach!r}")
    ids = np.full(len(which), -1, np.int32)
    on_object = np.flatnonzero(point_object >= 0)
    if len(which) == 0 or len(on_object) == 0:
        return ids
    around = _cells_around(_top_cells(points, which, reach))
    on_object = on_object[np.isin(_top_cells(points, on_object, reach), around)]
    if len(on_object) == 0:
        return ids
    for start, d2 in _square_distances(points[which, :2], points[on_object, :2]):
        nearest = np.argmin(d2, axis=1)
        hit = d2[np.arange(len(nearest)), nearest] <= reach * reach
        ids[start: start + len(nearest)][hit] = point_object[on_object[nearest[hit]]]
    return ids


def attach_to_nearest(points: np.ndarray, loose: np.ndarray, point_object: np.ndarray, reach: float) -> np.ndarray:
    """Give each of the points ``loose`` (indices; on no object) the id of the nearest object with a point within
    ``reach`` metres of it seen from above (distances between :data:`ATTACH_GRID` cells), in ``point_object``;
    returns which points were given one."""
    on_object = np.flatnonzero(point_object >= 0)
    attached = np.zeros(len(points), bool)
    if len(on_object) == 0 or len(loose) == 0:
        return attached
    # Only loose points in or beside an object's cell of ``reach`` metres can be that close to one (the kernel
    # checks that itself, point by point).
    compiled = kernels.enabled() and points.dtype == np.float32 and point_object.dtype == np.int32
    object_cells = _top_cells(points, on_object, reach)
    if not compiled:
        loose = loose[np.isin(_top_cells(points, loose, reach), _cells_around(object_cells))]
    cells, first = np.unique(_top_cells(points, on_object, ATTACH_GRID), return_index=True)
    owner = point_object[on_object[first]]
    r = int(np.ceil(reach / ATTACH_GRID))
    steps = np.array([(di, dj) for di in range(-r, r + 1) for dj in range(-r, r + 1)
                      if np.hypot(di, dj) * ATTACH_GRID <= reach + 1e-9])
    steps = steps[np.argsort(np.hypot(steps[:, 0], steps[:, 1]), kind="stable")]
    if compiled:
        return kernels.attach_nearest(points, loose, np.unique(object_cells), reach, cells, owner, ATTACH_GRID, steps,
                                      point_object)
    if len(loose) == 0:
        return attached
    loose_ij = np.floor(points[loose, :2] / ATTACH_GRID).astype(np.int64)
    todo = np.arange(len(loose))
    for step in steps:  # nearest first: a loose point goes to the object nearest to it
        keys = _cell_keys(loose_ij[todo] + step)
        at = np.minimum(np.searchsorted(cells, keys), len(cells) - 1)
        hit = cells[at] == keys
        if hit.any():
            point_object[loose[todo[hit]]] = owner[at[hit]]
            attached[loose[todo[hit]]] = True
            todo = todo[~hit]
            if len(todo) == 0:
                break
    return attached
