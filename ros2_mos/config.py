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

from ros2_mos.errors import ConfigError

#: Ranges above this are no LiDAR's (and break KISS-ICP's voxel hashing: inf or 1e300 aborts it).
MAX_RANGE_LIMIT = 1000.0


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
class SensorConfig:
    """Geometry of the range image a rotating LiDAR is projected to (paper eq. 1).

    ``fov_up_deg``/``fov_down_deg`` are the elevations of the top and bottom image
    rows; ``fov_down_deg`` is negative for sensors that look down.  Points closer
    than ``min_range`` or farther than ``max_range`` are left out of the image.
    """

    name: str = "hdl64"
    height: int = 64
    width: int = 2048
    fov_up_deg: float = 3.0
    fov_down_deg: float = -25.0
    min_range: float = 0.0
    max_range: float = 120.0

    def __post_init__(self) -> None:
        check_finite(f"sensor {self.name!r}:", fov_up_deg=self.fov_up_deg, fov_down_deg=self.fov_down_deg,
                     min_range=self.min_range, max_range=self.max_range)
        if not -90.0 <= self.fov_down_deg < self.fov_up_deg <= 90.0:
            raise ConfigError(f"sensor {self.name!r}: need -90 <= fov_down_deg < fov_up_deg <= 90, "
                              f"got {self.fov_down_deg} and {self.fov_up_deg}")
        if self.max_range > MAX_RANGE_LIMIT:
            raise ConfigError(f"sensor {self.name!r}: max_range must be <= {MAX_RANGE_LIMIT:g} m, got {self.max_range}")
        if self.height <= 0 or self.width <= 0:
            raise ConfigError(f"sensor {self.name!r}: height and width must be positive, "
                              f"got {self.height} x {self.width}")
        if not self.fov_up_deg > self.fov_down_deg:
            raise ConfigError(
                f"sensor {self.name!r}: fov_up_deg ({self.fov_up_deg}) must be greater than "
                f"fov_down_deg ({self.fov_down_deg})"
            )
        if not (0.0 <= self.min_range < self.max_range):
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

    The defaults (2, 50) m are those of the LiDAR-MOS reference implementation.
    """

    min_range: float = 2.0
    max_range: float = 50.0

    def __post_init__(self) -> None:
        check_finite("residuals", min_range=self.min_range, max_range=self.max_range)
        if not 0.0 <= self.min_range < self.max_range <= MAX_RANGE_LIMIT:
            raise ConfigError(f"residuals: need 0 <= min_range < max_range <= {MAX_RANGE_LIMIT:g}, "
                              f"got {self.min_range} and {self.max_range}")


@dataclass(frozen=True)
class PostprocessConfig:
    """kNN back-projection over the range image, as RangeNet++ / LiDAR-MOS do it.

    ``mode='nearest'`` takes each point's own pixel instead, for comparison.
    """

    mode: str = "knn"
    k: int = 5
    window: int = 5
    sigma: float = 1.0
    cutoff: float = 1.0
    # Segment consistency (ros2_mos.segments.fill_segments): a connected non-ground segment of the
    # range image of which at least this share is moving is labelled moving as a whole; 0 = off.
    segment_fill: float = 0.0
    # Connected moving range-image regions smaller than this many pixels of a 64 x 2048 image (scaled
    # with the image size for other sensors) are labelled static (ros2_mos.segments.drop_small_regions):
    # speckle on foliage and depth edges; 0 = off.
    min_region_pixels: int = 30
    # Temporal fusion (ros2_mos.temporal.BeliefFilter): how much of the last scan's moving belief (log-odds)
    # at the same surface carries into this scan's; 0 = off (each scan labelled on its own), at most 1.
    temporal_weight: float = 0.5

    def __post_init__(self) -> None:
        if self.mode not in ("knn", "nearest"):
            raise ConfigError(f"postprocess mode must be 'knn' or 'nearest', got {self.mode!r}")
        check_finite("postprocess", sigma=self.sigma, cutoff=self.cutoff, segment_fill=self.segment_fill,
                     temporal_weight=self.temporal_weight)
        if not 0.0 <= self.temporal_weight <= 1.0:
            raise ConfigError(f"postprocess temporal_weight must be in [0, 1] (0 = off), got {self.temporal_weight}")
        if not 0.0 <= self.segment_fill <= 1.0:
            raise ConfigError(f"postprocess segment_fill must be in [0, 1] (0 = off), got {self.segment_fill}")
        if isinstance(self.min_region_pixels, bool) or not isinstance(self.min_region_pixels, int) \
                or not 0 <= self.min_region_pixels <= 10000:
            raise ConfigError(f"postprocess min_region_pixels must be an integer in [0, 10000] (0 = off), "
                              f"got {self.min_region_pixels!r}")
        if self.window < 1 or self.window % 2 == 0:
            raise ConfigError(f"postprocess window must be a positive odd number, got {self.window}")
        if not 1 <= self.k <= self.window * self.window:
            raise ConfigError(f"postprocess k must be in 1..window^2 ({self.window * self.window}), got {self.k}")
        if self.sigma <= 0 or self.cutoff <= 0:
            raise ConfigError(f"postprocess sigma and cutoff must be positive, got {self.sigma} and {self.cutoff}")


@dataclass(frozen=True)
class OdometryConfig:
    """KISS-ICP settings. ``voxel_size`` None lets KISS-ICP pick max_range / 100."""

    max_range: float = 100.0
    min_range: float = 0.0
    voxel_size: float | None = None
    # KISS-ICP's cap on map points per voxel (its default is 20). Registration cost grows with it
    # (measured: README, Speed).
    max_points_per_voxel: int = 10
    # KISS-ICP sees every k-th point of the scan: it voxelises them at 0.5 m and registers ~2.5k
    # points anyway, so half a 120k-point scan covers the same voxels (measured: README, Speed).
    point_stride: int = 2
    deskew: bool = False
    # A relative motion larger than this per 0.1 s (one scan at 10 Hz; 50 m/s) is treated as a
    # failure of the odometry: the scan buffer is reset instead of producing garbage residuals.
    # The limit grows with the time since the last processed scan, so dropped scans don't trip it.
    max_translation_jump: float = 5.0
    # 'all': KISS-ICP's map takes every point (plain KISS-ICP); 'static': only the points MOS
    # labelled static, so that moving objects never enter the map the next scans register to.
    map_update: str = "all"

    def __post_init__(self) -> None:
        if self.map_update not in ("all", "static"):
            raise ConfigError(f"odometry map_update must be 'all' or 'static', got {self.map_update!r}")
        check_finite("odometry", max_range=self.max_range, min_range=self.min_range, voxel_size=self.voxel_size,
                     max_translation_jump=self.max_translation_jump)
        if self.max_range > MAX_RANGE_LIMIT:
            raise ConfigError(f"odometry max_range must be <= {MAX_RANGE_LIMIT:g} m, got {self.max_range}")
        if not (0.0 <= self.min_range < self.max_range):
            raise ConfigError(f"odometry: need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}")
        if not 1 <= self.point_stride <= 16:
            raise ConfigError(f"odometry point_stride must be in 1..16, got {self.point_stride}")
        if self.max_points_per_voxel < 1:
            raise ConfigError(f"odometry max_points_per_voxel must be >= 1, got {self.max_points_per_voxel}")
        if self.voxel_size is not None and self.voxel_size <= 0:
            raise ConfigError(f"odometry voxel_size must be positive, got {self.voxel_size}")
        if self.max_translation_jump <= 0:
            raise ConfigError(f"odometry max_translation_jump must be positive, got {self.max_translation_jump}")


@dataclass(frozen=True)
class MosConfig:
    """Everything the pipeline needs besides the model file.

    ``sensor`` None means: take the sensor the model was trained for (from its metadata).
    ``threshold`` is the moving probability at or above which a point is labelled moving;
    0 takes the model's own recommended threshold (tuned on its validation data, stored
    in its metadata), or 0.5 for a model without one.
    """

    model: str | None = None
    sensor: SensorConfig | None = None
    residuals: ResidualConfig = field(default_factory=ResidualConfig)
    postprocess: PostprocessConfig = field(default_factory=PostprocessConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    threshold: float = 0.0
    intra_op_threads: int = 0
    # 'numpy' (default, no torch) or 'torch': residual images and the kNN vote as torch ops on
    # ``device`` ('auto' = CUDA when present) -- on a GPU these, not the CNN, dominate.
    geometry_backend: str = "numpy"
    device: str = "auto"
    # Keep freed heap blocks mapped (glibc mallopt, process-wide): see ros2_mos.memory (its cost: README, Speed).
    tune_malloc: bool = True

    def __post_init__(self) -> None:
        if self.geometry_backend not in ("numpy", "torch"):
            raise ConfigError(f"geometry_backend must be 'numpy' or 'torch', got {self.geometry_backend!r}")
        if not re.fullmatch(r"auto|cpu|cuda(:[0-9]+)?", str(self.device)):
            raise ConfigError(f"device must be auto, cpu, cuda or cuda:N, got {self.device!r}")
        check_finite("mos", threshold=self.threshold)
        if not 0.0 <= self.threshold < 1.0:
            raise ConfigError(f"threshold must be in (0, 1), or 0 for the model's own, got {self.threshold}")
        if self.intra_op_threads < 0:
            raise ConfigError(f"intra_op_threads must be >= 0 (0 = runtime default), got {self.intra_op_threads}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "MosConfig":
        data = dict(data)
        sensor = data.pop("sensor", None)
        if isinstance(sensor, str):
            sensor_cfg: SensorConfig | None = sensor_preset(sensor)
        elif isinstance(sensor, Mapping):
            sensor_cfg = SensorConfig.from_dict(sensor)
        elif sensor is None:
            sensor_cfg = None
        else:
            raise ConfigError(f"sensor must be a preset name or a mapping, got {type(sensor).__name__}")
        parts = {
            "residuals": ResidualConfig,
            "postprocess": PostprocessConfig,
            "odometry": OdometryConfig,
        }
        kwargs: dict[str, Any] = {"sensor": sensor_cfg}
        for key, klass in parts.items():
            if key in data:
                kwargs[key] = _from_mapping(klass, data.pop(key) or {}, key)
        kwargs.update(data)
        return _from_mapping(cls, kwargs, "mos", allow_objects=True)

    @classmethod
    def from_yaml(cls, path: str | Path) -> "MosConfig":
        return cls.from_dict(read_yaml_mapping(path, "config file"))


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
