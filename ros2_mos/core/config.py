"""Typed configuration: the sensor model, the pipeline's knobs, and their YAML form.

Everything the pipeline does differently from one robot to another lives here as
data, so that the node, the CLI and the training all read the same description.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ros2_mos.core.errors import ConfigError

#: Ranges above this are no LiDAR's (and break KISS-ICP's voxel hashing: inf or 1e300 aborts it).
MAX_RANGE_LIMIT = 1000.0
#: The far end of the residual window (m) where neither the settings nor the model say otherwise (LiDAR-MOS's).
DEFAULT_RESIDUAL_MAX_RANGE = 50.0


def read_yaml_mapping(path: str | Path, what: str, loader: Any = None) -> Mapping[str, Any]:
    """The top-level mapping of a YAML file; every way it can fail is one :class:`ConfigError` line.

    ``what`` names the file in the messages ("training config", "params file"); ``loader`` is a PyYAML
    loader class (default: the safe loader). An empty file is an empty mapping.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{what} not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}); a {what} must be UTF-8 YAML") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what} ({exc.strerror})") from None
    try:
        data = yaml.load(text, Loader=loader or yaml.SafeLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def check_finite(what: str, **values: Any) -> None:
    """Every value a real, finite number (NaN, inf, bools and strings are refused with one clear line)."""
    for name, value in values.items():
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(float(value)):
            raise ConfigError(f"{what} {name} must be a finite number, got {value!r}")


@dataclass(frozen=True)
class Knob:
    """The one definition of a configuration value besides its name and default: type, meaning, limits.

    The dataclasses below validate themselves from it, and the node's ROS parameters
    (:mod:`ros2_mos.ros.params`: descriptors, config/mos.yaml, the table of docs/parameters.md) are made from it.
    ``min``/``max`` are inclusive unless ``above`` is set (then the value must exceed ``min``);
    ``unset`` is the value a ROS parameter (which has no None) takes for an optional field's None.
    """

    kind: type
    description: str
    min: float | None = None
    max: float | None = None
    above: bool = False
    choices: tuple[str, ...] = ()
    unset: Any = None

    def check(self, what: str, name: str, value: Any) -> None:
        """One clear :class:`ConfigError` line unless ``value`` has this knob's type, limits and choices."""
        if value is None and self.unset is not None:
            return
        if self.kind is float:
            check_finite(what, **{name: value})
        elif self.kind is int:
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ConfigError(f"{what} {name} must be an integer, got {value!r}")
        elif type(value) is not self.kind:
            raise ConfigError(f"{what} {name} must be a {self.kind.__name__}, got {value!r}")
        if self.choices and value not in self.choices:
            raise ConfigError(f"{what} {name} must be one of {', '.join(self.choices)}; got {value!r}")
        if self.min is not None and (value <= self.min if self.above else value < self.min):
            raise ConfigError(f"{what} {name} must be {'>' if self.above else '>='} {self.min:g}, got {value!r}")
        if self.max is not None and value > self.max:
            raise ConfigError(f"{what} {name} must be <= {self.max:g}, got {value!r}")


def knob(default: Any, description: str, *, kind: type | None = None, min: float | None = None,
         max: float | None = None, above: bool = False, choices: tuple[str, ...] = (), unset: Any = None) -> Any:
    """A dataclass field with its :class:`Knob` (``kind`` defaults to the default's type)."""
    spec = Knob(kind or type(default), description, min, max, above, tuple(choices), unset)
    return field(default=default, metadata={"knob": spec})


def knobs(cls: Any) -> list[tuple[dataclasses.Field, Knob]]:
    """The fields of a configuration dataclass that carry a :class:`Knob`, in declaration order."""
    return [(f, f.metadata["knob"]) for f in dataclasses.fields(cls) if "knob" in f.metadata]


def check_knobs(obj: Any, what: str) -> None:
    """Validate every knob of a configuration dataclass instance."""
    for f, spec in knobs(obj):
        spec.check(what, f.name, getattr(obj, f.name))


@dataclass(frozen=True)
class SensorConfig:
    """Geometry of the range image a rotating LiDAR is projected to (paper eq. 1).

    ``fov_up_deg``/``fov_down_deg`` are the elevations of the top and bottom image
    rows; ``fov_down_deg`` is negative for sensors that look down.  Points closer
    than ``min_range`` or farther than ``max_range`` are left out of the image.
    """

    name: str = "hdl64"
    height: int = knob(64, "range image rows (beams)", min=1, max=1024)
    width: int = knob(2048, "range image columns", min=1, max=16384)
    fov_up_deg: float = knob(3.0, "elevation of the top row (deg)", min=-90.0, max=90.0)
    fov_down_deg: float = knob(-25.0, "elevation of the bottom row (deg)", min=-90.0, max=90.0)
    min_range: float = knob(0.0, "points closer than this are left out (m)", min=0.0)
    # Ranges above MAX_RANGE_LIMIT are no LiDAR's (and break KISS-ICP's voxel hashing).
    max_range: float = knob(120.0, "points farther than this are left out (m)", min=0.0, max=MAX_RANGE_LIMIT)

    def __post_init__(self) -> None:
        check_knobs(self, f"sensor {self.name!r}:")
        if not self.fov_down_deg < self.fov_up_deg:
            raise ConfigError(
                f"sensor {self.name!r}: fov_up_deg ({self.fov_up_deg}) must be greater than "
                f"fov_down_deg ({self.fov_down_deg})"
            )
        if not self.min_range < self.max_range:
            raise ConfigError(
                f"sensor {self.name!r}: need 0 <= min_range < max_range, got {self.min_range} and {self.max_range}"
            )

    @property
    def fov_up(self) -> float:
        """Top elevation in radians."""
        return math.radians(self.fov_up_deg)

    @property
    def fov_down(self) -> float:
        """Bottom elevation in radians (negative when the sensor looks down)."""
        return math.radians(self.fov_down_deg)

    @property
    def fov(self) -> float:
        """Total vertical field of view in radians."""
        return self.fov_up - self.fov_down

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "SensorConfig":
        return _from_mapping(cls, data, "sensor")


SENSOR_PRESETS: dict[str, SensorConfig] = {
    # SemanticKITTI / LiDAR-MOS settings for the Velodyne HDL-64E.
    "hdl64": SensorConfig("hdl64", 64, 2048, 3.0, -25.0, 0.0, 120.0),
    "vlp16": SensorConfig("vlp16", 16, 1024, 15.0, -15.0, 0.0, 100.0),
    "vlp32c": SensorConfig("vlp32c", 32, 1024, 15.0, -25.0, 0.0, 200.0),
    "os1-64": SensorConfig("os1-64", 64, 1024, 22.5, -22.5, 0.0, 120.0),
    "os1-128": SensorConfig("os1-128", 128, 1024, 22.5, -22.5, 0.0, 120.0),
}


def sensor_preset(name: str) -> SensorConfig:
    """Look up a preset by name, with a message that lists the known ones."""
    try:
        return SENSOR_PRESETS[name.lower()]
    except KeyError:
        raise ConfigError(f"unknown sensor preset {name!r}; known presets: {', '.join(SENSOR_PRESETS)}") from None


def same_beams(a: SensorConfig, b: SensorConfig) -> bool:
    """Whether two range images have the same rows and vertical field of view, whatever their columns."""
    return (a.height, a.fov_up_deg, a.fov_down_deg) == (b.height, b.fov_up_deg, b.fov_down_deg)


def lidar_of(sensor: SensorConfig) -> SensorConfig:
    """The preset of the LiDAR a model's range image was made for (its name, :func:`same_beams`), else ``sensor``
    itself. A model may sample the azimuth more coarsely than its LiDAR fires (the HDL-64E model's 64 x 1024 image of
    a 64 x 2048 scan); whatever simulates or labels that LiDAR's clouds needs the LiDAR's own."""
    preset = SENSOR_PRESETS.get(sensor.name.lower())
    return preset if preset is not None and same_beams(preset, sensor) else sensor


def estimate_fov(points: np.ndarray, percentile: float = 0.1, margin_deg: float = 0.1) -> tuple[float, float]:
    """Estimate (fov_up_deg, fov_down_deg) from the elevations of one scan.

    Percentiles rather than min/max, so that a few noisy returns do not stretch the
    image and waste rows; a small margin keeps the extreme beams inside.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3 or len(pts) == 0:
        raise ConfigError(f"estimate_fov needs an (N, 3) array with N > 0, got shape {pts.shape}")
    xyz = pts[:, :3]
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    r = np.linalg.norm(xyz, axis=1)
    xyz, r = xyz[r > 0], r[r > 0]
    if len(r) == 0:
        raise ConfigError("estimate_fov: the scan has no finite point with positive range")
    elevation = np.degrees(np.arcsin(np.clip(xyz[:, 2] / r, -1.0, 1.0)))
    up = float(np.percentile(elevation, 100.0 - percentile)) + margin_deg
    down = float(np.percentile(elevation, percentile)) - margin_deg
    return up, down


@dataclass(frozen=True)
class ResidualConfig:
    """Where residual images are computed: only where both ranges lie in (min_range, max_range).

    ``max_range`` None is the model's own window, recorded when it was trained
    (:meth:`for_model`), or LiDAR-MOS's 50 m for a model that records none; (2, 50) m are the
    LiDAR-MOS reference implementation's. Beyond the window every residual reads 0, so a
    model must be run with the window it was trained with.
    """

    min_range: float = knob(2.0, "residuals only where both ranges exceed this (m)", min=0.0)
    max_range: float | None = knob(None, "residuals only where both ranges are below this (m); 0 = the model's own "
                                         f"window ({DEFAULT_RESIDUAL_MAX_RANGE:g} m for a model that records none)",
                                   kind=float, min=0.0, above=True, max=MAX_RANGE_LIMIT, unset=0.0)

    def __post_init__(self) -> None:
        check_knobs(self, "residuals")
        if not self.min_range < self.upper:
            raise ConfigError(f"residuals: need 0 <= min_range < max_range <= {MAX_RANGE_LIMIT:g}, "
                              f"got {self.min_range} and {self.upper}")

    @property
    def upper(self) -> float:
        """The window's far end (m): ``max_range``, or LiDAR-MOS's 50 m where it is left to the model."""
        return DEFAULT_RESIDUAL_MAX_RANGE if self.max_range is None else self.max_range

    def for_model(self, model_max_range: float | None) -> "ResidualConfig":
        """The window to run a model with: the configured far end, else the one the model was trained with."""
        if self.max_range is not None or model_max_range is None:
            return self
        return dataclasses.replace(self, max_range=model_max_range)


@dataclass(frozen=True)
class RegistrationConfig:
    """Each past scan's relative pose refined against the current scan before the residuals (core/registration.py).

    KISS-ICP's relative poses are centimetres off, more where the ego pulls away along a featureless street; a
    few steps of projective point-to-plane ICP at the range image's resolution remove most of that.
    """

    iterations: int = knob(4, "scan-to-scan ICP steps against the previous scan; 0 = off (the odometry's relative "
                              "poses as they are)", min=0, max=50)
    other_iterations: int = knob(1, "steps for each farther past scan, from the registered trajectory", min=0,
                                 max=50)
    point_stride: int = knob(32, "every n-th point of the current scan takes part in it", min=1, max=64)
    max_error: float = knob(0.3, "pairs farther from the past scan's surface are left out (m)", min=0.0, above=True,
                            max=5.0)
    # Exact (simulated) poses lost 0.3-0.7 IoU to it (benchmarks/experiments.md, row 21).
    refine_given_poses: bool = knob(False, "also refine poses given with the scans (`--use-poses`); off: they are "
                                           "used as they are")

    def __post_init__(self) -> None:
        check_knobs(self, "registration")


@dataclass(frozen=True)
class PostprocessConfig:
    """kNN back-projection over the range image, as RangeNet++ / LiDAR-MOS do it, and what follows it.

    ``mode='nearest'`` takes each point's own pixel instead, for comparison.
    """

    mode: str = knob("knn", "label back-projection: kNN over the range image or nearest pixel",
                     choices=("knn", "nearest"))
    k: int = knob(5, "kNN: neighbours that vote", min=1, max=225)
    window: int = knob(5, "kNN: odd search window size (pixels)", min=1, max=15)
    sigma: float = knob(1.0, "kNN: Gaussian weight of the window", min=0.0, above=True)
    cutoff: float = knob(1.0, "kNN: neighbours farther than this in range do not vote (m)", min=0.0, above=True)
    # ros2_mos.core.segments.fill_segments
    segment_fill: float = knob(0.0, "a connected non-ground range-image segment at least this share moving is "
                                    "labelled moving whole; 0 = off", min=0.0, max=1.0)
    # ros2_mos.core.segments.drop_small_regions: speckle on foliage and depth edges
    min_region_pixels: int = knob(30, "connected moving range-image regions smaller than this (pixels of a "
                                      "64 x 2048 image, scaled for others) are labelled static; 0 = off",
                                  min=0, max=10000)
    # ros2_mos.core.temporal.BeliefFilter
    temporal_weight: float = knob(0.5, "temporal fusion: share of the last scan's moving belief (log-odds) at the "
                                       "same surface carried into this scan's; 0 = off", min=0.0, max=1.0)

    def __post_init__(self) -> None:
        check_knobs(self, "postprocess")
        if self.window % 2 == 0:
            raise ConfigError(f"postprocess window must be a positive odd number, got {self.window}")
        if not self.k <= self.window * self.window:
            raise ConfigError(f"postprocess k must be in 1..window^2 ({self.window * self.window}), got {self.k}")


@dataclass(frozen=True)
class OdometryConfig:
    """KISS-ICP settings. ``voxel_size`` None lets KISS-ICP pick max_range / 100."""

    max_range: float = knob(100.0, "KISS-ICP: ignore points beyond (m)", min=0.0, max=MAX_RANGE_LIMIT)
    min_range: float = knob(0.0, "KISS-ICP: ignore points closer than (m)", min=0.0)
    voxel_size: float | None = knob(None, "KISS-ICP voxel size (m); 0 = max_range / 100", kind=float, min=0.0,
                                    above=True, unset=0.0)
    # Registration cost grows with it (benchmarks/bench.md).
    max_points_per_voxel: int = knob(10, "KISS-ICP: map points kept per voxel (KISS-ICP's own default is 20; "
                                         "fewer is faster)", min=1, max=1000)
    # KISS-ICP voxelises at 0.5 m and registers ~2.5k points anyway (benchmarks/bench.md).
    point_stride: int = knob(2, "KISS-ICP registers every k-th point of the scan (1 = all; MOS still labels "
                                "every point)", min=1, max=16)
    deskew: bool = knob(False, "KISS-ICP constant-velocity deskewing; needs per-point times, which are not passed "
                               "yet: no effect (the first scan's warning says so). The MOS models do not need it: "
                               "KITTI raw's scans deskewed changed their labels by under 1 IoU")
    # ~30 ICP iterations per scan at KISS-ICP's 1e-4; 1e-3 stops sooner (benchmarks/experiments.md, round 6).
    convergence_criterion: float = knob(1e-3, "KISS-ICP: the ICP stops when a step is smaller than this (m and rad; "
                                              "KISS-ICP's own default is 1e-4)", min=0.0, above=True, max=0.01)
    # The limit grows with the time since the last processed scan, so dropped scans don't trip it.
    max_translation_jump: float = knob(5.0, "a larger motion per 0.1 s between two processed scans (m) is an "
                                            "odometry failure: the scan buffer is reset", min=0.0, above=True)
    # A second sensor's scans on the same topic (issue 32.1) turn the pose as no vehicle turns.
    max_rotation_jump: float = knob(30.0, "a larger turn per 0.1 s between two processed scans (deg) is an odometry "
                                          "failure (or another sensor): the scan buffer is reset", min=0.0,
                                    above=True, max=180.0)
    map_update: str = knob("all", "what enters KISS-ICP's map: every point, or only those labelled static",
                           choices=("all", "static"))
    # Its parallel sums add up in an order that varies with the machine's load: poses 1e-14 apart from run to run,
    # which an ICP stopping at a step of 1e-3 can grow into another pose (autolabel uses 1: repeatable labels).
    # KISS-ICP sets it for the whole process, from the first registration built there.
    threads: int = knob(0, "KISS-ICP's registration threads (0 = every core; 1: the same poses to the bit from run "
                           "to run); KISS-ICP takes it from the first odometry a process builds", min=0, max=256)

    def __post_init__(self) -> None:
        check_knobs(self, "odometry")
        if not self.min_range < self.max_range:
            raise ConfigError(f"odometry: need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}")


@dataclass(frozen=True)
class MoverMemoryConfig:
    """A memory of movers (core/mover_memory.py): a segment standing where movers were labelled moving a moment ago
    stays moving (a car waiting at a light, in a jam), ``max_age`` seconds after it was last seen moving at most."""

    # Off: on the validation drives no setting gained under SemanticKITTI's convention on traffic_jam
    # (benchmarks/mover_memory.md); the defaults below are the best balanced setting there.
    enabled: bool = knob(False, "keep a stopped mover's moving label while it stands where it was seen moving "
                                "(SemanticKITTI's convention)")
    max_age: float = knob(5.0, "movers are remembered this long after the network last labelled them moving (s); "
                                "bounds how long a false positive lives too", min=0.0, above=True, max=600.0)
    voxel_size: float = knob(0.5, "world voxel size of the memory (m)", min=0.05, max=5.0)
    share: float = knob(0.7, "a non-ground range-image segment at least this share in remembered voxels (or "
                             "moving now) is labelled moving whole", min=0.0, above=True, max=1.0)
    min_scans: int = knob(5, "a voxel is remembered once the network labelled it moving in this many scans (a one-scan "
                             "false positive is not)", min=1, max=100)

    def __post_init__(self) -> None:
        check_knobs(self, "movers")


@dataclass(frozen=True)
class MosConfig:
    """Everything the pipeline needs besides the model file.

    ``sensor`` None means: take the sensor the model was trained for (from its metadata).
    ``threshold`` 0 takes the model's own recommended threshold (tuned on its validation
    data, stored in its metadata), or 0.5 for a model without one.
    """

    model: str | None = knob(None, "ONNX model exported by `ros2-mos export`; empty = the model shipped with the "
                                   "package", kind=str, unset="")
    sensor: SensorConfig | None = None
    residuals: ResidualConfig = field(default_factory=ResidualConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    postprocess: PostprocessConfig = field(default_factory=PostprocessConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    movers: MoverMemoryConfig = field(default_factory=MoverMemoryConfig)
    # Its knob's limits are the whole check: the range the descriptor and the params file advertise (1 is allowed:
    # only a certain mover is labelled moving).
    threshold: float = knob(0.0, "moving probability at or above which a point is labelled moving; 0 = the model's "
                                 "recommended threshold (0.5 if none)", min=0.0, max=1.0)
    intra_op_threads: int = knob(0, "ONNX Runtime threads; 0 = runtime default", min=0, max=256)
    # On a GPU the residual images and the kNN vote, not the CNN, dominate.
    geometry_backend: str = knob("numpy", "residual images and kNN in numpy, or in torch (GPU path; needs torch "
                                          "installed)", choices=("numpy", "torch"))
    device: str = knob("auto", "torch device of the torch geometry backend: auto (CUDA when present), cpu, cuda")
    # ros2_mos.core.memory (its cost: benchmarks/bench.md).
    tune_malloc: bool = knob(True, "keep freed heap memory mapped (glibc mallopt, whole process): saves page "
                                   "faults per scan")

    def __post_init__(self) -> None:
        check_knobs(self, "mos")
        if not re.fullmatch(r"auto|cpu|cuda(:[0-9]+)?", str(self.device)):
            raise ConfigError(f"device must be auto, cpu, cuda or cuda:N, got {self.device!r}")


def _from_mapping(cls: type, data: Mapping[str, Any], what: str, allow_objects: bool = False) -> Any:
    """Build a dataclass from a mapping, rejecting unknown keys with a clear message."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{what}: expected a mapping, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{what}: unknown keys {sorted(unknown)}; allowed: {sorted(names)}")
    try:
        return cls(**data)
    except TypeError as exc:
        raise ConfigError(f"{what}: {exc}") from None
