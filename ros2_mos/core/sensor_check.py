"""Does a cloud come from the configured sensor?  Rings and vertical field of view, from the points alone.
And is it a LiDAR scan at all?  Neighbouring pixels of its range image, from the image alone.

A rotating LiDAR's points lie on a few cones: every laser has its own fixed elevation, so within a
narrow azimuth wedge the points' elevation angles (as seen from the sensor) fall into one tight
cluster per ring.  Counting the clusters and reading the elevation span tells a 16-ring VLP-16 (+-15 deg) from a
64-ring HDL-64E (+2..-25 deg) or a 128-ring OS1-128 (+-22.5 deg) on the very first scan, before a
wrong projection turns into wrong labels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.config import SENSOR_PRESETS, SensorConfig

#: Rings are counted in azimuth wedges this wide (deg), split at elevation gaps above RING_GAP_DEG: less
#: than the closest rings of any preset (HDL-64E: 1/3 deg), more than a ring's own spread in a wedge.
WEDGE_DEG = 1.0
RING_GAP_DEG = 0.12
#: A ring count this far (relative) from the sensor's rows, or an elevation span this many degrees
#: beyond its field of view, does not fit it.
RING_TOLERANCE = 0.25
FOV_TOLERANCE_DEG = 3.0
#: Without a known sensor's shape, a cloud is only called foreign when more of its points than this
#: lie beyond the configured field of view.
MAX_OUTSIDE_SHARE = 0.25
#: Fewer points than this give no reliable verdict (a cropped or filtered cloud): no check.
MIN_POINTS = 2000

#: Plausibility (:func:`implausible_message`): two horizontally adjacent pixels of the range image "agree" when
#: their ranges differ by at most this share of the smaller one.  A LiDAR sees surfaces, so most neighbours agree:
#: >= 94 % of them in 64 real KITTI HDL-64E scans, >= 96 % in simulated scans of every preset, still 64 % in a real
#: scan voxel-filtered at 0.5 m, 70 % in the tests' hand-made street; uniformly random points (a cube, a Gaussian
#: blob, in any preset's image) agree at 6-13 %, by chance.
NEIGHBOUR_RANGE_STEP = 0.05
#: A range image in which fewer neighbours than this share agree is not a scan of surfaces: the cloud is refused.
MIN_AGREEING_NEIGHBOURS = 0.35
#: Fewer adjacent pairs of occupied pixels than this give no verdict (a tiny, sparse or foreign-layout cloud).
MIN_NEIGHBOUR_PAIRS = 500


@dataclass(frozen=True)
class CloudShape:
    """What the points say about the sensor: rings, elevation span (deg) and points per ring."""

    rings: int
    elevation_top_deg: float
    elevation_bottom_deg: float
    points: int

    def describe(self) -> str:
        return (f"~{self.rings} rings over {self.elevation_bottom_deg:+.1f}..{self.elevation_top_deg:+.1f} deg "
                f"({self.points} points)")


def cloud_shape(points: np.ndarray) -> CloudShape | None:
    """Rings and elevation span of a cloud in its sensor frame (N, 3); None for too few points.

    Rings are counted locally: within a 1-degree azimuth wedge the points' elevations fall into one
    tight cluster per laser (across the whole sweep real sensors' rings smear, e.g. by the HDL-64E's
    per-laser offsets), clusters split where sorted elevations jump by more than ``RING_GAP_DEG``.
    The 80th percentile over 36 wedges is the ring count.
    """
    xyz = np.asarray(points, np.float64)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    keep = horizontal > 2.0  # points on or next to the sensor say little about its beams
    xyz, horizontal = xyz[keep], horizontal[keep]
    if len(xyz) < MIN_POINTS:
        return None
    elevation = np.degrees(np.arctan2(xyz[:, 2], horizontal))
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    counts = []
    for start in np.arange(-180.0, 180.0, 10.0):
        wedge = np.sort(elevation[(azimuth >= start) & (azimuth < start + WEDGE_DEG)])
        if len(wedge) >= 8:
            counts.append(1 + int((np.diff(wedge) > RING_GAP_DEG).sum()))
    if len(counts) < 6:
        return None
    top, bottom = np.percentile(elevation, [99.9, 0.1])
    # Rings go missing in a wedge (sky, dark or absent surfaces), extra ones are rare: the wedges that see the
    # most rings tell the count (the 80th percentile, robust to a few that split a ring in two).
    return CloudShape(int(round(float(np.percentile(counts, 80)))), float(top), float(bottom), len(elevation))


def fits(shape: CloudShape, sensor: SensorConfig) -> bool:
    """True when the rings and the elevation span agree with ``sensor`` (within the tolerances)."""
    rings_ok = abs(shape.rings - sensor.height) <= RING_TOLERANCE * sensor.height
    span = shape.elevation_top_deg - shape.elevation_bottom_deg
    fov = sensor.fov_up_deg - sensor.fov_down_deg
    span_ok = (shape.elevation_top_deg <= sensor.fov_up_deg + FOV_TOLERANCE_DEG
               and shape.elevation_bottom_deg >= sensor.fov_down_deg - FOV_TOLERANCE_DEG and span >= 0.5 * fov)
    # Rings per degree over the part of the field of view that returned points (sky returns nothing).
    spacing_ok = span > 0 and abs((shape.rings - 1) / span / ((sensor.height - 1) / fov) - 1.0) <= RING_TOLERANCE
    return rings_ok and span_ok and spacing_ok


def closest_preset(shape: CloudShape) -> str | None:
    """The known sensor whose rings and field of view the cloud fits best; None if none fits."""
    best, best_cost = None, float("inf")
    for name, preset in SENSOR_PRESETS.items():
        if not fits(shape, preset):
            continue
        cost = (abs(shape.rings - preset.height) / preset.height
                + abs(shape.elevation_top_deg - preset.fov_up_deg) / 10.0
                + abs(shape.elevation_bottom_deg - preset.fov_down_deg) / 10.0)
        if cost < best_cost:
            best, best_cost = name, cost
    return best


def outside_share(points: np.ndarray, sensor: SensorConfig) -> float:
    """Share of the finite points whose elevation lies beyond ``sensor``'s field of view (with the tolerance)."""
    xyz = np.asarray(points, np.float64)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if not len(xyz):
        return 0.0
    elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    beyond = (elevation > sensor.fov_up_deg + FOV_TOLERANCE_DEG) | (elevation < sensor.fov_down_deg - FOV_TOLERANCE_DEG)
    return float(beyond.mean())


def mismatch_message(points: np.ndarray, sensor: SensorConfig) -> str | None:
    """None when the cloud fits ``sensor`` or nothing can be told; otherwise one line saying what it looks like.

    A verdict needs evidence: the cloud fits another known sensor and not this one, or more than
    ``MAX_OUTSIDE_SHARE`` of its points lie beyond this sensor's field of view.  A cloud without
    clear rings (already merged, filtered or synthetic) that stays inside the field of view passes.
    """
    shape = cloud_shape(points)
    if shape is None or fits(shape, sensor):
        return None
    guess = closest_preset(shape)
    if guess is None and outside_share(points, sensor) <= MAX_OUTSIDE_SHARE:
        return None
    hint = (f"it looks like a {guess}: set sensor.preset to {guess} (--sensor {guess} in the CLI)" if guess else
            "it matches no known preset: set sensor.preset to custom with its sensor.* values")
    return (f"the cloud does not fit the configured sensor {sensor.name} ({sensor.height} rows, "
            f"{sensor.fov_down_deg:+.1f}..{sensor.fov_up_deg:+.1f} deg): it has {shape.describe()}; {hint}")


def neighbour_agreement(range_image: np.ndarray) -> tuple[float, int]:
    """Share of horizontally adjacent occupied pixel pairs whose ranges agree (``NEIGHBOUR_RANGE_STEP``), and
    how many pairs there are.  O(H x W) (its cost: benchmarks/design_figures.md)."""
    image = np.asarray(range_image, np.float32)
    right, left = image[:, 1:], image[:, :-1]
    both = (right > 0) & (left > 0)  # 0 = empty pixel
    pairs = int(np.count_nonzero(both))
    if pairs == 0:
        return 1.0, 0
    agree = np.abs(right - left) <= np.float32(NEIGHBOUR_RANGE_STEP) * np.minimum(right, left)
    return np.count_nonzero(agree & both) / pairs, pairs


def implausible_message(range_image: np.ndarray) -> str | None:
    """None when the range image looks like a scan of surfaces (or is too sparse to tell); else one line why not.

    A rotating LiDAR's neighbouring beams hit the same wall, road or car, so adjacent pixels of its range
    image have nearly the same range; points scattered through a volume (uniform random noise, a broken
    driver) do not.  Such a cloud is no scan to label, and it can hold KISS-ICP for seconds (issue 13).
    """
    share, pairs = neighbour_agreement(range_image)
    if pairs < MIN_NEIGHBOUR_PAIRS or share >= MIN_AGREEING_NEIGHBOURS:
        return None
    return (f"not a plausible LiDAR scan: only {share:.0%} of {pairs} pairs of adjacent range-image pixels are within "
            f"{NEIGHBOUR_RANGE_STEP:.0%} in range (a scan of surfaces: over {MIN_AGREEING_NEIGHBOURS:.0%}; scattered "
            "points such as uniform random noise: ~10%)")
