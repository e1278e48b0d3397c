"""The node's parameters: one table, validation, and the ROS params-file format.

Pure Python (no rclpy), so the offline ``process`` command reads the same
``config/mos.yaml`` the node gets through ``--ros-args --params-file`` and
builds the same pipeline. The table :data:`PARAMS` lists every parameter: the
pipeline's come from the knobs of the configuration dataclasses
(:mod:`ros2_mos.core.config`), the node's own are defined here. The node turns each
entry into a ``declare_parameter`` call with a descriptor; ``config/mos.yaml``
(:func:`params_file_text`, ``ros2-mos params``) and the table of docs/parameters.md (:func:`describe`,
``ros2-mos params --markdown``) are made from it: one definition per parameter (name, type, default, limits,
description), nowhere repeated.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ros2_mos.core.config import (
    SENSOR_PRESETS,
    Knob,
    MosConfig,
    MoverMemoryConfig,
    OdometryConfig,
    PostprocessConfig,
    RegistrationConfig,
    ResidualConfig,
    SensorConfig,
    knobs,
    read_yaml_mapping,
    sensor_preset,
)
from ros2_mos.core.errors import ConfigError
from ros2_mos.ros.outputs import OUTPUT_KEYS, OUTPUTS

NODE_NAME = "mos_node"



@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter: its name, its default (whose type is the parameter's type) and its :class:`Knob`."""

    name: str
    default: bool | int | float | str
    knob: Knob

    @property
    def type(self) -> type:
        return type(self.default)

    @property
    def description(self) -> str:
        return self.knob.description

    @property
    def choices(self) -> tuple[str, ...]:
        return self.knob.choices

    @property
    def min(self) -> float | None:
        return self.knob.min

    @property
    def max(self) -> float | None:
        return self.knob.max

    @property
    def constraints(self) -> str:
        """The limits in words ("one of: a, b", ">= 1; <= 16"), for descriptors, the params file and the docs."""
        parts = ["one of: " + ", ".join(self.choices)] if self.choices else []
        if self.min is not None:
            parts.append(f"{'>' if self.knob.above else '>='} {self.min:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        return "; ".join(parts)


def _param(name: str, default: bool | int | float | str, description: str, **limits: Any) -> ParamSpec:
    """A parameter of the node alone (not of the pipeline)."""
    return ParamSpec(name, default, Knob(type(default), description, **limits))


def _pipeline_params(prefix: str, cls: type, describe: str = "") -> list[ParamSpec]:
    """The ROS parameters of a configuration dataclass: one per :class:`Knob` field, named ``prefix + field``."""
    specs = []
    for f, knob in knobs(cls):
        default = knob.unset if f.default is None else f.default
        if knob.kind is float:
            default = float(default)
        specs.append(ParamSpec(prefix + f.name, default, dataclasses.replace(knob, description=describe +
                                                                             knob.description)))
    return specs


_MODEL, *_MOS_TOP = _pipeline_params("", MosConfig)  # ``model`` is MosConfig's first knob

PARAMS: tuple[ParamSpec, ...] = (
    # --- pipeline (ros2_mos.core.config: the dataclasses define these)
    _MODEL,
    _param("sensor.preset", "",
           "Sensor preset (" + ", ".join(SENSOR_PRESETS) + "), 'custom' for the sensor.* values, "
           "or empty for the sensor the model was trained for"),
    *_pipeline_params("sensor.", SensorConfig, describe="custom sensor: "),
    *_MOS_TOP,
    *_pipeline_params("residuals.", ResidualConfig),
    *_pipeline_params("registration.", RegistrationConfig),
    *_pipeline_params("postprocess.", PostprocessConfig),
    *_pipeline_params("odometry.", OdometryConfig),
    *_pipeline_params("movers.", MoverMemoryConfig),
    # --- input
    _param("input_topic", "/points", "PointCloud2 input topic (remapping works too)"),
    _param("qos.reliability", "best_effort", "input QoS: best_effort (sensor data: newest scan only) or reliable",
           choices=("best_effort", "reliable")),
    _param("qos.depth", 1, "input QoS history depth", min=1, max=100),
    _param("qos.publish_depth", 2, "history depth of the (reliable) output publishers", min=1, max=100),
    _param("min_points", 100, "clouds with fewer finite points are skipped with a warning", min=1),
    _param("reset_after_gap", 1.0,
           "a gap between scans longer than this (s), e.g. a silent driver, resets the scan buffer; 0 = never",
           min=0.0),
    _param("stamp_tolerance", 0.05,
           "a cloud stamped at most this much (s) before the last processed one (driver jitter) is skipped and the "
           "history kept; time going back further (a replay restarted) resets the scan buffer and odometry",
           min=0.0, max=10.0),
    _param("frame_change", "reset",
           "a cloud whose frame_id is not the stream's (another sensor on the topic): reset = start over with it "
           "(scan buffer and odometry reset), skip = keep labelling the first sensor and skip the other's clouds",
           choices=("reset", "skip")),
    _param("publish_incomplete", True,
           "publish labels while fewer than N past scans exist (sequence start, after a reset); "
           "they are flagged degraded in the diagnostics either way"),
    # --- outputs
    *(_param(f"topics.{o.key}", f"/mos/{o.key}", f"output topic: {o.description}") for o in OUTPUTS),
    _param("odom_frame", "odom", "frame of /mos/odometry and the parent of the published transform"),
    _param("sensor_frame", "", "child frame of the odometry/transform; empty = the input cloud's frame_id"),
    _param("publish_tf", True, "publish odom -> sensor on /tf (where tf2_msgs is installed)"),
    _param("diagnostics_period", 1.0, "seconds between /diagnostics messages", min=0.1, max=3600.0),
    _param("log_period", 10.0, "seconds between statistics log lines; 0 = never", min=0.0, max=86400.0),
    # --- cleaned local map (the paper's clean-map application, online)
    _param("static_map.enabled", False, "publish a voxel map of the static points around the sensor"),
    _param("static_map.topic", "/mos/static_map", "output topic of the static map (PointCloud2 in odom_frame)"),
    _param("static_map.voxel_size", 0.25, "static map: one point per voxel of this size (m)", min=0.01, max=10.0),
    _param("static_map.max_radius", 60.0, "static map: points farther than this from the sensor are dropped (m)",
           min=1.0),
    _param("static_map.max_points", 300000, "static map: at most this many points (the nearest are kept)",
           min=1000),
    _param("static_map.insert_every", 3, "static map: add the static points of every n-th processed scan",
           min=1, max=100),
    _param("static_map.publish_period", 1.0, "static map: seconds between publications", min=0.1, max=3600.0),
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
    stamp_tolerance: float
    frame_change: str
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
    if spec.knob.unset is None or value != spec.knob.unset:  # the unset value stands for None ("" model: shipped)
        spec.knob.check("parameter", repr(spec.name), value)
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
        return SensorConfig(name="custom", **_section(SensorConfig, values, "sensor."))
    return sensor_preset(name)


def _section(cls: type, values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """The keyword arguments of a configuration dataclass out of resolved parameters (a knob's unset value: None)."""
    out = {}
    for f, knob in knobs(cls):
        if prefix + f.name in values:
            value = values[prefix + f.name]
            out[f.name] = None if knob.unset is not None and value == knob.unset else value
    return out


def mos_config(values: Mapping[str, Any]) -> MosConfig:
    """The pipeline configuration the parameters describe (ConfigError on invalid combinations)."""
    v = resolve(values)
    return MosConfig(
        sensor=_sensor(v),
        residuals=ResidualConfig(**_section(ResidualConfig, v, "residuals.")),
        registration=RegistrationConfig(**_section(RegistrationConfig, v, "registration.")),
        postprocess=PostprocessConfig(**_section(PostprocessConfig, v, "postprocess.")),
        odometry=OdometryConfig(**_section(OdometryConfig, v, "odometry.")),
        movers=MoverMemoryConfig(**_section(MoverMemoryConfig, v, "movers.")),
        **_section(MosConfig, v),
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
    if v["sensor_frame"] == v["odom_frame"]:
        raise ConfigError(f"parameters 'sensor_frame' and 'odom_frame' are both {v['odom_frame']!r}: the odometry "
                          "would be a transform from a frame to itself; give the sensor's own frame (or leave "
                          "sensor_frame empty for the clouds' frame_id)")
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
        stamp_tolerance=v["stamp_tolerance"],
        frame_change=v["frame_change"],
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


#: A params-file section key rcl accepts: names or wildcards (``*`` one name, ``**`` any number) between slashes.
_SECTION_RE = re.compile(r"^/?(\*\*?|[A-Za-z_][A-Za-z0-9_]*)(/(\*\*?|[A-Za-z_][A-Za-z0-9_]*))*$")


def fully_qualified_name(name: str = NODE_NAME, namespace: str = "/") -> str:
    """``/namespace/name`` as ROS writes it (``mos_node`` in ``/``: ``/mos_node``)."""
    namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{namespace}/{name}"


def section_applies(key: str, node: str) -> bool:
    """Whether rcl gives a params-file section keyed ``key`` to the node with the fully qualified name ``node``.

    rclpy's rule (Jazzy, checked against it in test_node_params): a leading ``/`` is added to the key, then
    ``/*`` stands for one name and ``/**`` for any number of them, and the key must match the whole name. So
    ``mos_node`` is ``/mos_node`` and nothing else; ``/**``, ``/**/mos_node``, ``/robot1/*`` and
    ``/robot1/mos_node`` all reach ``/robot1/mos_node``.
    """
    pattern = ("/" + key.lstrip("/")).replace("/*", r"(/\w+)")
    return re.fullmatch(pattern, node, flags=re.ASCII) is not None


def _sections(path: str | Path) -> list[tuple[str, Any]]:
    """The top-level sections of a params file in file order, the repeats of a key merged into its first place (as
    rcl's parser merges them); each checked to be a node name rcl accepts holding a ``ros__parameters`` mapping."""
    data = read_yaml_mapping(path, "params file", _ros_yaml_loader())  # every way of failing to read: one line
    if not data:
        return []
    loader = _ros_yaml_loader()(Path(path).read_text(encoding="utf-8"))
    try:
        root = loader.get_single_node()
        pairs = [(loader.construct_object(k, deep=True), loader.construct_object(v, deep=True))
                 for k, v in root.value]
    finally:
        loader.dispose()
    merged: dict[str, tuple[str, dict[str, Any]]] = {}  # key -> (key, values); `a` and `/a` are two (as in rcl)
    for key, entry in pairs:
        if not isinstance(key, str) or not _SECTION_RE.match(key):
            raise ConfigError(f"{path}: section {key!r} is not a node name rcl accepts (names and * or ** "
                              "between slashes, e.g. /robot1/mos_node or /**)")
        if not isinstance(entry, Mapping) or not isinstance(entry.get("ros__parameters"), Mapping):
            raise ConfigError(f"{path}: section {key!r} needs a 'ros__parameters' mapping")
        merged.setdefault(key, (key, {}))[1].update(_flatten(entry["ros__parameters"]))
    return list(merged.values())


def read_params_file(path: str | Path, node: str = NODE_NAME) -> tuple[dict[str, Any], list[str]]:
    """The parameters a ROS params file gives the node ``node`` (a name, or a fully qualified name such as
    ``/robot1/mos_node``) exactly as rcl applies them, flattened; and the sections meant for it that rcl would not
    apply (see below).

    Every section whose key matches the node's name applies (:func:`section_applies`), later sections over
    earlier ones, as rclpy applies them. A file without a section for the node is an error. Where only
    catch-all sections (``/**``) apply, a section that names this node but does not reach it (``mos_node:`` for a
    node in ``/robot1``) is returned as missed: its values would be silently lost.
    Numbers are read as ROS reads them (``1e4`` is a float, as for ``mos_node --params-file``).
    """
    node = node if node.startswith("/") else fully_qualified_name(node)
    name = node.rsplit("/", 1)[1]
    sections = _sections(path)
    values: dict[str, Any] = {}
    applied = [key for key, _ in sections if section_applies(key, node)]
    for key, params in sections:
        if key in applied:
            values.update(params)
    if sections and not applied:
        raise ConfigError(f"{path}: no parameters for node {node!r} (sections: {[k for k, _ in sections]}); "
                          f"rcl applies a section to the node whose full name it matches: key it {node!r}, or "
                          f"'/**/{name}' for any namespace")
    named = any(key.rsplit("/", 1)[-1] == name for key in applied)
    missed = [] if named else [key for key, _ in sections if key.rsplit("/", 1)[-1] == name and key not in applied]
    return values, missed


def load_params_file(path: str | Path, node: str = NODE_NAME) -> dict[str, Any]:
    """The parameters a ROS params file gives the node ``node`` (:func:`read_params_file`), flattened."""
    return read_params_file(path, node)[0]


def describe() -> str:
    """The parameter table in Markdown (docs/parameters.md; ``ros2-mos params --markdown`` prints it)."""
    rows = ["| parameter | default | limits | description |", "|---|---|---|---|"]
    for p in PARAMS:
        rows.append(f"| `{p.name}` | `{p.default!r}` | {p.constraints} | {p.description} |")
    return "\n".join(rows)


def params_file_text(node_name: str = NODE_NAME) -> str:
    """config/mos.yaml: every parameter at its default, nested as ROS params files are, each with its documentation.

    ``ros2-mos params`` prints it; the tests check the shipped file against it.
    """
    lines = [
        "# Parameters of mos_node, at their defaults: `mos_node --ros-args --params-file config/mos.yaml`",
        "# (`ros2 run ros2_mos mos_node ...` on a ROS install). Every command that runs the pipeline reads the same",
        "# file with --params (`ros2-mos infer/process/map/odometry/suite/calibrate --params config/mos.yaml`).",
        "# Generated from ros2_mos/core/config.py and ros2_mos/ros/params.py by `ros2-mos params > config/mos.yaml`.",
        f"{node_name}:",
        "  ros__parameters:",
    ]
    opened: list[str] = []
    for p in PARAMS:
        *groups, leaf = p.name.split(".")
        common = 0
        while common < min(len(opened), len(groups)) and opened[common] == groups[common]:
            common += 1
        opened = opened[:common]
        for group in groups[common:]:
            lines.append("    " + "  " * len(opened) + f"{group}:")
            opened.append(group)
        indent = "    " + "  " * len(opened)
        limits = f" ({p.constraints})" if p.constraints else ""
        lines.append(f"{indent}# {p.description}{limits}")
        lines.append(f"{indent}{leaf}: {_yaml_value(p.default)}")
    return "\n".join(lines) + "\n"


def _yaml_value(value: bool | int | float | str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def load_params(path: str | Path | None = None, model: str | Path | None = None,
                sensor: str | None = None) -> dict[str, Any]:
    """The parameter values of a params file (none: the defaults), with ``--model`` and ``--sensor`` on top.

    The one loader of the node's parameters for every command; the node reads the same file through ROS.
    """
    values = load_params_file(path) if path is not None else {}
    if model is not None:
        values["model"] = str(model)
    if sensor is not None:
        values["sensor.preset"] = sensor
    return values


__all__ = [
    "NODE_NAME", "PARAMS", "SPECS", "NodeSettings", "ParamSpec", "StaticMapSettings", "check_value",
    "defaults", "describe", "fully_qualified_name", "load_params", "load_params_file", "mos_config", "node_settings",
    "params_file_text", "read_params_file", "section_applies",
    "resolve",
]
