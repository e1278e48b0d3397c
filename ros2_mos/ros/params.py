"""The node's parameters: one table, validation, and the ROS params-file format.

Pure Python (no rclpy), so the offline ``process`` command reads the same
``config/mos.yaml`` the node gets through ``--ros-args --params-file`` and
builds the same pipeline. The table :data:`PARAMS` is the single source of the
names, types, defaults and documentation; the node turns each entry into a
``declare_parameter`` call with a descriptor, and ``config/mos.yaml`` is checked
against it by the tests so the file and the defaults cannot drift apart.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ros2_mos.config import (
    SENSOR_PRESETS,
    MosConfig,
    OdometryConfig,
    PostprocessConfig,
    ResidualConfig,
    SensorConfig,
    read_yaml_mapping,
    sensor_preset,
)
from ros2_mos.errors import ConfigError

NODE_NAME = "mos_node"

#: Names of the published outputs; each is also the parameter suffix ``topics.<key>``.
OUTPUT_KEYS: tuple[str, ...] = ("static_points", "moving_points", "labels", "range_image", "mask", "odometry")


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter: name, default (its type is the parameter's type), doc, bounds or choices."""

    name: str
    default: bool | int | float | str
    description: str
    choices: tuple[str, ...] = ()
    min: float | None = None
    max: float | None = None

    @property
    def type(self) -> type:
        return type(self.default)


_DEF_RES, _DEF_POST, _DEF_ODOM, _DEF_MOS = ResidualConfig(), PostprocessConfig(), OdometryConfig(), MosConfig()

PARAMS: tuple[ParamSpec, ...] = (
    # --- pipeline
    ParamSpec("model", "", "ONNX model exported by `ros2-mos export`; empty = the model shipped with the package"),
    ParamSpec("sensor.preset", "",
              "Sensor preset (" + ", ".join(SENSOR_PRESETS) + "), 'custom' for the sensor.* values, "
              "or empty for the sensor the model was trained for"),
    ParamSpec("sensor.height", 64, "custom sensor: range image rows (beams)", min=1, max=1024),
    ParamSpec("sensor.width", 2048, "custom sensor: range image columns", min=1, max=16384),
    ParamSpec("sensor.fov_up_deg", 3.0, "custom sensor: elevation of the top row (deg)", min=-90.0, max=90.0),
    ParamSpec("sensor.fov_down_deg", -25.0, "custom sensor: elevation of the bottom row (deg)", min=-90.0, max=90.0),
    ParamSpec("sensor.min_range", 0.0, "custom sensor: points closer than this are left out (m)", min=0.0),
    ParamSpec("sensor.max_range", 120.0, "custom sensor: points farther than this are left out (m)", min=0.0),
    ParamSpec("threshold", _DEF_MOS.threshold,
              "moving probability at or above which a point is labelled moving; "
              "0 = the model's recommended threshold (0.5 if none)", min=0.0, max=1.0),
    ParamSpec("intra_op_threads", _DEF_MOS.intra_op_threads, "ONNX Runtime threads; 0 = runtime default",
              min=0, max=256),
    ParamSpec("geometry_backend", _DEF_MOS.geometry_backend,
              "residual images and kNN in numpy, or in torch (GPU path; needs torch installed)",
              choices=("numpy", "torch")),
    ParamSpec("device", _DEF_MOS.device,
              "torch device of the torch geometry backend: auto (CUDA when present), cpu, cuda"),
    ParamSpec("tune_malloc", _DEF_MOS.tune_malloc,
              "keep freed heap memory mapped (glibc mallopt, whole process): saves ~7 ms of page faults per scan"),
    ParamSpec("residuals.min_range", _DEF_RES.min_range, "residuals only where both ranges exceed this (m)", min=0.0),
    ParamSpec("residuals.max_range", _DEF_RES.max_range, "residuals only where both ranges are below this (m)",
              min=0.0),
    ParamSpec("postprocess.mode", _DEF_POST.mode, "label back-projection: kNN over the range image or nearest pixel",
              choices=("knn", "nearest")),
    ParamSpec("postprocess.k", _DEF_POST.k, "kNN: neighbours that vote", min=1, max=225),
    ParamSpec("postprocess.window", _DEF_POST.window, "kNN: odd search window size (pixels)", min=1, max=15),
    ParamSpec("postprocess.sigma", _DEF_POST.sigma, "kNN: Gaussian weight of the window", min=0.0),
    ParamSpec("postprocess.cutoff", _DEF_POST.cutoff, "kNN: neighbours farther than this in range do not vote (m)",
              min=0.0),
    ParamSpec("postprocess.segment_fill", _DEF_POST.segment_fill,
              "a connected non-ground range-image segment at least this share moving is labelled moving whole; "
              "0 = off", min=0.0, max=1.0),
    ParamSpec("postprocess.min_region_pixels", _DEF_POST.min_region_pixels,
              "connected moving range-image regions smaller than this (pixels of a 64 x 2048 image, scaled for "
              "others) are labelled static; 0 = off",
              min=0, max=10000),
    ParamSpec("postprocess.temporal_weight", _DEF_POST.temporal_weight,
              "temporal fusion: share of the last scan's moving belief (log-odds) at the same surface carried into "
              "this scan's; 0 = off", min=0.0, max=1.0),
    ParamSpec("odometry.max_range", _DEF_ODOM.max_range, "KISS-ICP: ignore points beyond (m)", min=0.0),
    ParamSpec("odometry.min_range", _DEF_ODOM.min_range, "KISS-ICP: ignore points closer than (m)", min=0.0),
    ParamSpec("odometry.voxel_size", 0.0, "KISS-ICP voxel size (m); 0 = max_range / 100", min=0.0),
    ParamSpec("odometry.max_points_per_voxel", _DEF_ODOM.max_points_per_voxel,
              "KISS-ICP: map points kept per voxel (KISS-ICP's own default is 20; fewer is faster)", min=1, max=1000),
    ParamSpec("odometry.point_stride", _DEF_ODOM.point_stride,
              "KISS-ICP registers every k-th point of the scan (1 = all; MOS still labels every point)", min=1, max=16),
    ParamSpec("odometry.deskew", _DEF_ODOM.deskew, "KISS-ICP constant-velocity deskewing"),
    ParamSpec("odometry.max_translation_jump", _DEF_ODOM.max_translation_jump,
              "a larger motion per 0.1 s between two processed scans (m) is an odometry failure: "
              "the scan buffer is reset", min=0.0),
    ParamSpec("odometry.map_update", _DEF_ODOM.map_update,
              "what enters KISS-ICP's map: every point, or only those labelled static", choices=("all", "static")),
    # --- input
    ParamSpec("input_topic", "/points", "PointCloud2 input topic (remapping works too)"),
    ParamSpec("qos.reliability", "best_effort", "input QoS: best_effort (sensor data: newest scan only) or reliable",
              choices=("best_effort", "reliable")),
    ParamSpec("qos.depth", 1, "input QoS history depth", min=1, max=100),
    ParamSpec("qos.publish_depth", 2, "history depth of the (reliable) output publishers", min=1, max=100),
    ParamSpec("min_points", 100, "clouds with fewer finite points are skipped with a warning", min=1),
    ParamSpec("reset_after_gap", 1.0,
              "a gap between scans longer than this (s), e.g. a silent driver, resets the scan buffer; 0 = never",
              min=0.0),
    ParamSpec("publish_incomplete", True,
              "publish labels while fewer than N past scans exist (sequence start, after a reset); "
              "they are flagged degraded in the diagnostics either way"),
    # --- outputs
    *(ParamSpec(f"topics.{key}", f"/mos/{key}", f"output topic of {key.replace('_', ' ')}") for key in OUTPUT_KEYS),
    ParamSpec("odom_frame", "odom", "frame of /mos/odometry and the parent of the published transform"),
    ParamSpec("sensor_frame", "", "child frame of the odometry/transform; empty = the input cloud's frame_id"),
    ParamSpec("publish_tf", True, "publish odom -> sensor on /tf (where tf2_msgs is installed)"),
    ParamSpec("diagnostics_period", 1.0, "seconds between /diagnostics messages", min=0.1, max=3600.0),
    ParamSpec("log_period", 10.0, "seconds between statistics log lines; 0 = never", min=0.0, max=86400.0),
    # --- cleaned local map (the paper's clean-map application, online)
    ParamSpec("static_map.enabled", False, "publish a voxel map of the static points around the sensor"),
    ParamSpec("static_map.topic", "/mos/static_map", "output topic of the static map (PointCloud2 in odom_frame)"),
    ParamSpec("static_map.voxel_size", 0.25, "static map: one point per voxel of this size (m)", min=0.01, max=10.0),
    ParamSpec("static_map.max_radius", 60.0, "static map: points farther than this from the sensor are dropped (m)",
              min=1.0),
    ParamSpec("static_map.max_points", 300000, "static map: at most this many points (the nearest are kept)",
              min=1000),
    ParamSpec("static_map.insert_every", 3, "static map: add the static points of every n-th processed scan",
              min=1, max=100),
    ParamSpec("static_map.publish_period", 1.0, "static map: seconds between publications", min=0.1, max=3600.0),
)

SPECS: dict[str, ParamSpec] = {p.name: p for p in PARAMS}
_TOPIC_RE = re.compile(r"^~?/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$")
_FRAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_/.\-]*$")


@dataclass(frozen=True)
class NodeSettings:
    """Everything the node does besides the pipeline, validated."""

    input_topic: str
    reliable: bool
    depth: int
    publish_depth: int
    min_points: int
    reset_after_gap: float
    publish_incomplete: bool
    topics: dict[str, str]
    odom_frame: str
    sensor_frame: str
    publish_tf: bool
    diagnostics_period: float
    log_period: float
    static_map: "StaticMapSettings | None" = None  # None: not published


@dataclass(frozen=True)
class StaticMapSettings:
    topic: str
    voxel_size: float
    max_radius: float
    max_points: int
    insert_every: int
    publish_period: float


def defaults() -> dict[str, Any]:
    """name -> default value of every parameter."""
    return {p.name: p.default for p in PARAMS}


def check_value(spec: ParamSpec, value: Any) -> Any:
    """Type, bounds and choices of one value; ints are accepted for floats (YAML `1` for `1.0`)."""
    if spec.type is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if type(value) is not spec.type:
        raise ConfigError(
            f"parameter {spec.name!r} must be a {spec.type.__name__}, got {value!r} ({type(value).__name__})"
        )
    if spec.choices and value not in spec.choices:
        raise ConfigError(f"parameter {spec.name!r} must be one of {', '.join(spec.choices)}; got {value!r}")
    if spec.min is not None and value < spec.min:
        raise ConfigError(f"parameter {spec.name!r} must be >= {spec.min}, got {value!r}")
    if spec.max is not None and value > spec.max:
        raise ConfigError(f"parameter {spec.name!r} must be <= {spec.max}, got {value!r}")
    return value


def resolve(values: Mapping[str, Any]) -> dict[str, Any]:
    """Defaults overlaid with ``values`` (unknown names rejected), each value checked."""
    unknown = sorted(set(values) - set(SPECS))
    if unknown:
        raise ConfigError(f"unknown parameters {unknown}; see config/mos.yaml for the known ones")
    merged = defaults()
    merged.update(values)
    return {name: check_value(SPECS[name], value) for name, value in merged.items()}


def _sensor(values: Mapping[str, Any]) -> SensorConfig | None:
    name = values["sensor.preset"]
    if name == "":
        return None
    if name == "custom":
        return SensorConfig(
            name="custom",
            **{k.split(".", 1)[1]: values[k] for k in values if k.startswith("sensor.") and k != "sensor.preset"},
        )
    return sensor_preset(name)


def mos_config(values: Mapping[str, Any]) -> MosConfig:
    """The pipeline configuration the parameters describe (ConfigError on invalid combinations)."""
    v = resolve(values)

    def group(prefix: str) -> dict[str, Any]:
        return {k.split(".", 1)[1]: val for k, val in v.items() if k.startswith(prefix + ".")}

    odometry = group("odometry")
    odometry["voxel_size"] = odometry["voxel_size"] or None
    return MosConfig(
        model=v["model"] or None,
        sensor=_sensor(v),
        residuals=ResidualConfig(**group("residuals")),
        postprocess=PostprocessConfig(**group("postprocess")),
        odometry=OdometryConfig(**odometry),
        threshold=v["threshold"],
        intra_op_threads=v["intra_op_threads"],
        geometry_backend=v["geometry_backend"],
        device=v["device"],
        tune_malloc=v["tune_malloc"],
    )


def _check_topic(name: str, value: str) -> str:
    if not _TOPIC_RE.match(value):
        raise ConfigError(f"parameter {name!r}: {value!r} is not a valid ROS topic name")
    return value


def node_settings(values: Mapping[str, Any]) -> NodeSettings:
    """The node's own settings the parameters describe (ConfigError on invalid values)."""
    v = resolve(values)
    topics = {key: _check_topic(f"topics.{key}", v[f"topics.{key}"]) for key in OUTPUT_KEYS}
    static_map = None
    if v["static_map.enabled"]:
        static_map = StaticMapSettings(
            topic=_check_topic("static_map.topic", v["static_map.topic"]), voxel_size=v["static_map.voxel_size"],
            max_radius=v["static_map.max_radius"], max_points=v["static_map.max_points"],
            insert_every=v["static_map.insert_every"], publish_period=v["static_map.publish_period"])
    all_topics = [v["input_topic"], *topics.values(), *([static_map.topic] if static_map else [])]
    if len(set(all_topics)) != len(all_topics):
        raise ConfigError(f"input and output topics must all differ, got {all_topics}")
    for frame_param in ("odom_frame", "sensor_frame"):
        if v[frame_param] and not _FRAME_RE.match(v[frame_param]):
            raise ConfigError(f"parameter {frame_param!r}: {v[frame_param]!r} is not a valid frame id")
    if not v["odom_frame"]:
        raise ConfigError("parameter 'odom_frame' must not be empty")
    return NodeSettings(
        input_topic=_check_topic("input_topic", v["input_topic"]),
        reliable=v["qos.reliability"] == "reliable",
        depth=v["qos.depth"],
        publish_depth=v["qos.publish_depth"],
        min_points=v["min_points"],
        reset_after_gap=v["reset_after_gap"],
        publish_incomplete=v["publish_incomplete"],
        topics=topics,
        odom_frame=v["odom_frame"],
        sensor_frame=v["sensor_frame"],
        publish_tf=v["publish_tf"],
        diagnostics_period=v["diagnostics_period"],
        log_period=v["log_period"],
        static_map=static_map,
    )


def _flatten(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested YAML mappings -> dotted names, as ROS does for params files."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def _ros_yaml_loader() -> Any:
    """PyYAML's safe loader reading numbers as ROS's params parser does (YAML 1.2: ``1e4`` is a float)."""
    import re

    import yaml

    class RosParamsLoader(yaml.SafeLoader):
        pass

    RosParamsLoader.yaml_implicit_resolvers = {
        first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:float"]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    RosParamsLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+\.[0-9]*|[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)"
                   r"|\.(?:nan|NaN|NAN))$"),
        list("-+0123456789."))
    return RosParamsLoader


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """The parameters a ROS params file gives ``node_name`` (its own section over ``/**``), flattened.

    Numbers are read as ROS reads them (``1e4`` is a float, as for ``mos_node --params-file``), and a
    file without a section for the node is an error for the node and every command alike.
    """
    data = read_yaml_mapping(path, "params file", _ros_yaml_loader())
    values: dict[str, Any] = {}
    for section in ("/**", node_name, f"/{node_name}"):
        entry = data.get(section)
        if entry is None:
            continue
        if not isinstance(entry, Mapping) or not isinstance(entry.get("ros__parameters"), Mapping):
            raise ConfigError(f"{path}: section {section!r} needs a 'ros__parameters' mapping")
        values.update(_flatten(entry["ros__parameters"]))
    if not values and data:
        raise ConfigError(f"{path}: no parameters for node {node_name!r} (sections: {sorted(data)})")
    return values


def describe() -> str:
    """A Markdown table of the parameters (for the README)."""
    rows = ["| parameter | default | description |", "|---|---|---|"]
    for p in PARAMS:
        extra = f" ({'/'.join(p.choices)})" if p.choices else ""
        rows.append(f"| `{p.name}` | `{p.default!r}` | {p.description}{extra} |")
    return "\n".join(rows)


def replace_model(values: Mapping[str, Any], model: str | None, sensor: str | None = None) -> dict[str, Any]:
    """``values`` with ``model`` and ``sensor.preset`` set (CLI ``--model``, ``--sensor`` on top of a params file)."""
    out = dict(values)
    if model is not None:
        out["model"] = model
    if sensor is not None:
        out["sensor.preset"] = sensor
    return out


__all__ = [
    "NODE_NAME", "OUTPUT_KEYS", "PARAMS", "SPECS", "NodeSettings", "ParamSpec", "StaticMapSettings", "check_value",
    "defaults", "describe", "load_params_file", "mos_config", "node_settings", "resolve", "replace_model",
]
