"""Simulation presets: every number that shapes a simulated sequence, as typed data.

A preset fixes the street layout, the static clutter, the ego vehicle's driving
style, the traffic and the sensor's imperfections.  ``easy`` is small and quick
(tests), ``benchmark`` aims at SemanticKITTI-like statistics (a few percent of
moving points, more parked than moving cars, slow movers, the ego vehicle
standing at lights), ``traffic_jam`` fills the view with moving cars to stress
odometry, which is where masking moving points should pay off.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from ros2_mos.core.errors import ConfigError

Range = tuple[float, float]


def _check_range(name: str, value: Range, low: float = 0.0) -> None:
    if len(value) != 2 or not (low <= value[0] <= value[1]):
        raise ConfigError(f"{name} must be (min, max) with {low} <= min <= max, got {value}")


def _check_prob(name: str, value: float) -> None:
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"{name} must be a probability in [0, 1], got {value}")


@dataclass(frozen=True)
class StreetConfig:
    """Cross-section of every street and the size of the blocks between them.

    Driving is on the right.  From the centre line outwards each side has
    ``lanes_per_direction`` driving lanes, a bike lane, a parking lane, then the
    raised sidewalk; the blocks behind hold buildings, trees and terrain.
    """

    lanes_per_direction: int = 1
    lane_width: float = 3.5
    bike_lane_width: float = 1.5
    parking_width: float = 2.3
    sidewalk_width: float = 3.0
    curb_height: float = 0.15
    block_size: Range = (45.0, 110.0)
    turn_radius: float = 12.0
    # Probability that a route goes straight at an intersection (else left/right alike).
    straight_prob: float = 0.6

    def __post_init__(self) -> None:
        if self.lanes_per_direction < 1:
            raise ConfigError(f"lanes_per_direction must be >= 1, got {self.lanes_per_direction}")
        _check_range("block_size", self.block_size, 20.0)
        _check_prob("straight_prob", self.straight_prob)
        if min(self.lane_width, self.sidewalk_width, self.turn_radius) <= 0:
            raise ConfigError("lane_width, sidewalk_width and turn_radius must be positive")
        # Every lane and the sidewalks are offsets of a route: the inner one must not fold in a corner.
        if self.turn_radius <= self.half_road_width + self.sidewalk_width:
            raise ConfigError(
                f"turn_radius ({self.turn_radius}) must exceed the half street width with sidewalk "
                f"({self.half_road_width + self.sidewalk_width})"
            )

    @property
    def half_road_width(self) -> float:
        """Centre line to curb."""
        return self.lanes_per_direction * self.lane_width + self.bike_lane_width + self.parking_width

    def lane_offset(self, lane: int) -> float:
        """Lateral offset (left positive) of driving lane ``lane`` (0 = innermost) in driving direction."""
        return -(lane + 0.5) * self.lane_width

    @property
    def ego_lane(self) -> int:
        """The ego vehicle keeps to the rightmost driving lane."""
        return self.lanes_per_direction - 1

    @property
    def bike_offset(self) -> float:
        return -(self.lanes_per_direction * self.lane_width + 0.5 * self.bike_lane_width)

    @property
    def parking_offset(self) -> float:
        return -(self.half_road_width - 0.5 * self.parking_width)

    @property
    def sidewalk_offset(self) -> float:
        return -(self.half_road_width + 0.5 * self.sidewalk_width)


@dataclass(frozen=True)
class SceneConfig:
    """The static clutter of each block: buildings with varied setbacks and heights, trees, poles, parked cars.

    The variation is what keeps ICP well conditioned along the street: a uniform
    corridor of facades leaves the driving direction unobservable.
    """

    building_width: Range = (8.0, 25.0)
    building_depth: Range = (8.0, 18.0)
    building_height: Range = (4.0, 24.0)
    setback: Range = (0.0, 5.0)
    empty_lot_prob: float = 0.15
    tree_spacing: Range = (8.0, 18.0)
    tree_prob: float = 0.6
    # Tree size: trunk height and crown radii are scaled by a draw from this range (per tree), and a
    # crown is this many overlapping octahedra (1: one smooth crown; more: a lumpy canopy, as real trees).
    tree_scale: Range = (1.0, 1.0)
    crown_blobs: int = 1
    pole_spacing: Range = (22.0, 40.0)
    bush_prob: float = 0.3
    parked_prob: float = 0.5
    # Share of the parked vehicles that are vans (taller than cars; the presets park none: their scenes stay as they
    # were, and every moving heavy vehicle is a bus).
    parked_van_prob: float = 0.0
    # RMS height (m) of the ground's long undulations; 0 gives a flat world.
    ground_rms: float = 0.12

    def __post_init__(self) -> None:
        for name in ("building_width", "building_depth", "building_height", "setback", "tree_spacing", "pole_spacing",
                     "tree_scale"):
            _check_range(name, getattr(self, name))
        for name in ("empty_lot_prob", "tree_prob", "bush_prob", "parked_prob", "parked_van_prob"):
            _check_prob(name, getattr(self, name))
        if self.ground_rms < 0:
            raise ConfigError(f"ground_rms must be >= 0, got {self.ground_rms}")
        if not 1 <= self.crown_blobs <= 8:
            raise ConfigError(f"crown_blobs must be 1..8, got {self.crown_blobs}")
        if (self.building_width[0] <= 0 or self.tree_spacing[0] <= 0 or self.pole_spacing[0] <= 0
                or self.tree_scale[0] <= 0):
            raise ConfigError("building widths and tree/pole spacings must be positive")


@dataclass(frozen=True)
class EgoConfig:
    """How the ego vehicle drives: cruise speeds, turns, stops at lights, a standing start."""

    speed: Range = (6.0, 13.0)
    turn_speed: float = 5.0
    stop_prob: float = 0.4
    stop_duration: Range = (3.0, 10.0)
    start_stopped_prob: float = 0.3
    accel: float = 1.5
    decel: float = 2.5
    # RMS of the body's pitch/roll vibration on its springs (deg); it also dips when braking.
    body_vibration_deg: float = 0.1

    def __post_init__(self) -> None:
        _check_range("ego speed", self.speed, 0.1)
        _check_range("ego stop_duration", self.stop_duration)
        _check_prob("ego stop_prob", self.stop_prob)
        _check_prob("ego start_stopped_prob", self.start_stopped_prob)
        if min(self.turn_speed, self.accel, self.decel) <= 0:
            raise ConfigError("ego turn_speed, accel and decel must be positive")


@dataclass(frozen=True)
class TrafficConfig:
    """Moving and movable participants; densities are per 100 m of the ego vehicle's route.

    Lanes are filled by *columns*: copies of one speed profile shifted in time
    (``headway``) and space, so that cars in a lane queue at the same lights
    without ever overlapping.  Independent agents (cross traffic, slow cars,
    cyclists, pedestrians) are rejected when they would overlap another one.
    """

    lead_cars: tuple[int, int] = (0, 2)
    follow_cars: tuple[int, int] = (0, 2)
    headway: Range = (1.2, 2.5)
    gap: Range = (2.0, 5.0)
    oncoming_per_100m: float = 1.2
    oncoming_speed: Range = (5.0, 13.0)
    cross_cars_per_100m: float = 0.6
    car_speed: Range = (4.0, 12.0)
    slow_cars_per_100m: float = 0.3
    slow_speed: Range = (0.6, 2.0)
    stop_and_go_prob: float = 0.4
    cyclists_per_100m: float = 0.6
    cyclist_speed: Range = (2.5, 6.0)
    pedestrians_per_100m: float = 3.0
    pedestrian_speed: Range = (0.5, 2.0)
    standing_pedestrian_prob: float = 0.3
    # Traffic-jam column in the lane left of the ego lane (needs lanes_per_direction >= 2).
    side_column: bool = False
    side_column_speed: Range = (2.0, 6.0)
    # Share of buses/lorries among the cars of the lane columns.
    heavy_vehicle_prob: float = 0.05
    max_attempts: int = 6

    def __post_init__(self) -> None:
        for name in ("headway", "gap", "oncoming_speed", "car_speed", "slow_speed", "cyclist_speed",
                     "pedestrian_speed", "side_column_speed"):
            _check_range(name, getattr(self, name))
        for name in ("lead_cars", "follow_cars"):
            value = getattr(self, name)
            if len(value) != 2 or not 0 <= value[0] <= value[1]:
                raise ConfigError(f"{name} must be (min, max) counts, got {value}")
        _check_prob("stop_and_go_prob", self.stop_and_go_prob)
        _check_prob("standing_pedestrian_prob", self.standing_pedestrian_prob)
        _check_prob("heavy_vehicle_prob", self.heavy_vehicle_prob)
        for name in ("oncoming_per_100m", "cross_cars_per_100m", "slow_cars_per_100m", "cyclists_per_100m",
                     "pedestrians_per_100m"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0")


@dataclass(frozen=True)
class SensorEffects:
    """What makes a simulated scan look measured rather than rendered.

    ``ego_clearance``: returns closer than this are dropped, as the ego vehicle's
    own body blocks them on a real car.  ``intra_sweep_motion`` casts each column
    from the ego pose at its own firing time (a skewed scan, as real sensors
    deliver it); off by default, as the written poses are then mid-sweep poses.
    """

    range_sigma: float = 0.02
    dropout: float = 0.01
    grazing_dropout: float = 0.5
    far_dropout: float = 0.15
    remission_sigma: float = 0.03
    ego_clearance: float = 2.5
    max_range: float = 120.0
    sensor_height: float = 1.73
    intra_sweep_motion: bool = False
    # Foliage is porous: a ray that hits a crown or hedge goes on into it with this probability,
    # by an exponentially distributed extra depth of this mean (m), anew in every scan. Real
    # vegetation's ranges flicker from scan to scan like that, which residuals see; 0 = solid.
    vegetation_penetration: float = 0.0
    vegetation_depth: float = 0.0
    # Mixed pixels: where neighbouring rays of a beam land on surfaces at different depths (an object's
    # edge), the footprint straddles both and a real sensor may return a range in between; with this
    # probability per edge ray, anew in every scan. 0 = clean edges.
    edge_mixing: float = 0.0
    # Beam layout: a real unit's lasers sit where its calibration says, not on the nominal grid (KITTI's
    # HDL-64E reaches +2.6 deg, the nominal top beam +2.0). Every beam is raised by the offset and moved by
    # a fixed per-beam deviation of this sigma (deg), drawn once per sequence from ``beam_seed``.
    beam_elevation_offset_deg: float = 0.0
    beam_elevation_jitter_deg: float = 0.0
    beam_seed: int = 0

    def __post_init__(self) -> None:
        if not (-5.0 <= self.beam_elevation_offset_deg <= 5.0 and 0.0 <= self.beam_elevation_jitter_deg <= 2.0):
            raise ConfigError("need -5 <= beam_elevation_offset_deg <= 5 and 0 <= beam_elevation_jitter_deg <= 2, got "
                              f"{self.beam_elevation_offset_deg} and {self.beam_elevation_jitter_deg}")
        if self.range_sigma < 0 or self.remission_sigma < 0:
            raise ConfigError("range_sigma and remission_sigma must be >= 0")
        if not 0.0 <= self.vegetation_depth <= 10.0:
            raise ConfigError(f"vegetation_depth must be in [0, 10] m, got {self.vegetation_depth}")
        for name in ("dropout", "grazing_dropout", "far_dropout", "vegetation_penetration", "edge_mixing"):
            _check_prob(name, getattr(self, name))
        if not 0 <= self.ego_clearance < self.max_range:
            raise ConfigError(f"need 0 <= ego_clearance < max_range, got {self.ego_clearance}, {self.max_range}")


@dataclass(frozen=True)
class SimPreset:
    """A complete simulation setup; build variants with :func:`dataclasses.replace`."""

    name: str
    street: StreetConfig = field(default_factory=StreetConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    ego: EgoConfig = field(default_factory=EgoConfig)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    effects: SensorEffects = field(default_factory=SensorEffects)
    scan_period: float = 0.1

    def __post_init__(self) -> None:
        if self.scan_period <= 0:
            raise ConfigError(f"scan_period must be positive, got {self.scan_period}")
        if self.traffic.side_column and self.street.lanes_per_direction < 2:
            raise ConfigError("traffic.side_column needs street.lanes_per_direction >= 2")


SIM_PRESETS: dict[str, SimPreset] = {
    "easy": SimPreset(
        "easy",
        scene=SceneConfig(tree_prob=0.4, parked_prob=0.35),
        ego=EgoConfig(speed=(5.0, 9.0), stop_prob=0.3, start_stopped_prob=0.0),
        traffic=TrafficConfig(
            lead_cars=(1, 1), follow_cars=(0, 1), oncoming_per_100m=1.0, cross_cars_per_100m=0.3,
            slow_cars_per_100m=0.0, cyclists_per_100m=0.5, pedestrians_per_100m=1.5, standing_pedestrian_prob=0.2,
        ),
        effects=SensorEffects(range_sigma=0.01, dropout=0.005),
    ),
    "benchmark": SimPreset("benchmark"),
    "traffic_jam": SimPreset(
        "traffic_jam",
        street=StreetConfig(lanes_per_direction=2, block_size=(60.0, 120.0), turn_radius=15.0),
        ego=EgoConfig(speed=(2.0, 6.0), stop_prob=0.6, stop_duration=(2.0, 6.0), start_stopped_prob=0.7),
        traffic=TrafficConfig(
            lead_cars=(2, 3), follow_cars=(2, 3), headway=(1.0, 1.6), gap=(1.5, 3.0),
            oncoming_per_100m=8.0, oncoming_speed=(3.0, 8.0), cross_cars_per_100m=1.5,
            slow_cars_per_100m=0.5, cyclists_per_100m=1.0, pedestrians_per_100m=6.0,
            side_column=True, side_column_speed=(3.0, 7.0), heavy_vehicle_prob=0.3,
        ),
    ),
    # A narrow street lined with parked cars, as the real KITTI drive r2 (benchmarks/experiments.md, row 40): lanes,
    # bike lane and parking lane narrower than the presets' (3.5, 1.5, 2.3 m), so the sensor passes parked cars'
    # sides about 2.2 m away instead of 3.4-3.6 m. The benchmark preset's traffic otherwise.
    "narrow_street": SimPreset(
        "narrow_street",
        street=StreetConfig(lane_width=3.0, bike_lane_width=0.5, parking_width=2.1),
        scene=SceneConfig(parked_prob=0.8),
    ),
    # Slow movers 20-50 m away, the ones the held-out benchmark drives miss most (benchmarks/experiments.md,
    # row 24): people walking away along the sidewalks, cars creeping off from junctions and lights, a lead car
    # far ahead, seen by an ego vehicle that often stands or drives slowly. A training preset, not a suite one.
    "slow_traffic": SimPreset(
        "slow_traffic",
        ego=EgoConfig(speed=(3.0, 10.0), stop_prob=0.5, start_stopped_prob=0.5),
        traffic=TrafficConfig(
            lead_cars=(0, 1), headway=(2.0, 5.0), gap=(4.0, 15.0), oncoming_per_100m=1.0,
            cross_cars_per_100m=1.2, car_speed=(2.0, 8.0), stop_and_go_prob=0.6,
            slow_cars_per_100m=1.0, slow_speed=(0.5, 4.0), cyclists_per_100m=1.0, cyclist_speed=(1.5, 5.0),
            pedestrians_per_100m=7.0, pedestrian_speed=(0.6, 2.0), standing_pedestrian_prob=0.15,
        ),
    ),
}


def sim_preset(name: str) -> SimPreset:
    """Look up a simulation preset by name, listing the known ones on a miss."""
    try:
        return SIM_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown simulation preset {name!r}; known presets: {', '.join(SIM_PRESETS)}") from None


def with_effects(preset: SimPreset, **changes: object) -> SimPreset:
    """A copy of ``preset`` with some sensor effects changed (e.g. ``intra_sweep_motion=True``)."""
    return replace(preset, effects=replace(preset.effects, **changes))


def randomized_for_sequence(preset: SimPreset, seed: int, name: str, large_trees: bool = False,
                            beam_layout: bool = True, narrow_street: bool = False,
                            parked_vans: bool = False) -> SimPreset:
    """:func:`randomized` with the generator seeded by the simulation seed and the sequence name."""
    rng = np.random.default_rng([int(seed), zlib.crc32(name.encode()), 7])
    return randomized(preset, rng, large_trees, beam_layout, narrow_street, parked_vans)


#: ``narrow_street``: lanes, bike lane and parking lane drawn from these (m). With the preset's widths (3.5, 1.5,
#: 2.3) the sensor passes parked cars about 3.4-3.6 m away; on narrow streets about 1.5-3.6 m, as on KITTI's (a
#: parked car 2.4 m beside the sensor in the real drive r2: benchmarks/experiments.md, row 40).
NARROW_LANE_WIDTH: Range = (2.8, 3.5)
NARROW_BIKE_LANE_WIDTH: Range = (0.3, 1.5)
NARROW_PARKING_WIDTH: Range = (2.0, 2.3)
#: ``parked_vans``: the share of parked vehicles that are vans, drawn from this range (real streets park vans and small
#: lorries, 1.9-2.8 m tall; the presets park cars only: benchmarks/experiments.md, row 43).
PARKED_VAN_SHARE: Range = (0.15, 0.4)


def randomized(preset: SimPreset, rng: np.random.Generator, large_trees: bool = False,
               beam_layout: bool = True, narrow_street: bool = False, parked_vans: bool = False) -> SimPreset:
    """A copy of ``preset`` with the sensor's imperfections and the car's mounting drawn at random.

    For training data (domain randomisation): real sensors differ in noise, dropout and
    skew, so a network should not learn one simulated sensor's exact statistics.  The
    ranges bracket the presets' own values; about half of the sequences are skewed
    (each column cast from the pose at its firing time), as unprocessed driver output is,
    beams sit off the nominal grid (``beam_layout``), trees may be larger and lumpier (``large_trees``), streets
    narrower, so that parked cars are passed closer (``narrow_street``), some parked vehicles are vans
    (``parked_vans``),
    foliage is porous (its ranges flicker from
    scan to scan, as real trees' do), and object edges
    return mixed ranges between foreground and background.
    """
    u = rng.uniform
    effects = replace(
        preset.effects,
        range_sigma=float(u(0.005, 0.04)),
        dropout=float(u(0.0, 0.05)),
        grazing_dropout=float(u(0.2, 0.8)),
        far_dropout=float(u(0.05, 0.35)),
        remission_sigma=float(u(0.01, 0.08)),
        sensor_height=float(u(1.5, 2.1)),
        intra_sweep_motion=bool(rng.random() < 0.5),
        vegetation_penetration=float(u(0.2, 0.8)),
        vegetation_depth=float(u(0.2, 1.5)),
        edge_mixing=float(u(0.1, 0.6)),
    )
    ego = replace(preset.ego, body_vibration_deg=float(u(0.02, 0.3)))
    scene = preset.scene
    if large_trees:  # tried in round 4 (benchmarks/experiments.md, row 6): not used by the shipped recipe
        scene = replace(scene, tree_prob=float(u(0.5, 0.95)), tree_scale=(1.0, float(u(1.3, 2.5))),
                        crown_blobs=int(rng.integers(1, 6)))
    if beam_layout:  # real units' beams are off the nominal grid and reach the image's top rows
        effects = replace(effects, beam_elevation_offset_deg=float(u(0.2, 1.0)),
                          beam_elevation_jitter_deg=float(u(0.0, 0.12)), beam_seed=int(rng.integers(0, 2**31)))
    street = preset.street
    if narrow_street:  # drawn last, so that the other draws (and every earlier recipe's data) stay what they were
        street = replace(street, lane_width=float(u(*NARROW_LANE_WIDTH)),
                         bike_lane_width=float(u(*NARROW_BIKE_LANE_WIDTH)),
                         parking_width=float(u(*NARROW_PARKING_WIDTH)))
    if parked_vans:  # drawn after the narrow street, for the same reason
        scene = replace(scene, parked_van_prob=float(u(*PARKED_VAN_SHARE)))
    return replace(preset, effects=effects, ego=ego, scene=scene, street=street)
