"""The node's parameter table, its validation, and config/mos.yaml (no rclpy needed)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ros2_mos.errors import ConfigError
from ros2_mos.ros.params import (
    PARAMS,
    defaults,
    describe,
    load_params_file,
    mos_config,
    node_settings,
    resolve,
)

CONFIG = Path(__file__).resolve().parents[1] / "config" / "mos.yaml"


def test_config_file_lists_every_parameter_with_its_default():
    values = load_params_file(CONFIG)
    assert set(values) == {p.name for p in PARAMS}
    assert resolve(values) == defaults()


def test_defaults_build_a_pipeline_config_and_settings():
    cfg = mos_config({})
    assert cfg.model is None and cfg.sensor is None and cfg.odometry.voxel_size is None
    s = node_settings({})
    assert s.input_topic == "/points" and not s.reliable and s.depth == 1
    assert s.topics["static_points"] == "/mos/static_points"


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"threshold": 1.5}, "threshold"),
        ({"threshold": "high"}, "must be a float"),
        ({"qos.reliability": "sometimes"}, "qos.reliability"),
        ({"qos.depth": 0}, "qos.depth"),
        ({"postprocess.window": 4}, "odd"),
        ({"postprocess.k": 50, "postprocess.window": 5}, "k must be"),
        ({"sensor.preset": "hdl65"}, "unknown sensor preset"),
        ({"sensor.preset": "custom", "sensor.fov_up_deg": -30.0}, "fov_up_deg"),
        ({"odometry.map_update": "some"}, "map_update"),
        ({"topics.labels": "not a topic"}, "valid ROS topic"),
        ({"topics.labels": "/points"}, "must all differ"),
        ({"odom_frame": ""}, "odom_frame"),
        ({"treshold": 0.4}, "unknown parameters"),
        ({"publish_tf": 1}, "must be a bool"),
    ],
)
def test_invalid_values_are_rejected_with_the_parameter_name(values, match):
    with pytest.raises(ConfigError, match=match):
        mos_config(values)
        node_settings(values)


def test_ints_are_accepted_for_floats_and_custom_sensor():
    cfg = mos_config({"threshold": 0.4, "odometry.voxel_size": 1, "sensor.preset": "custom", "sensor.height": 32,
                      "sensor.width": 512})
    assert cfg.odometry.voxel_size == 1.0 and cfg.sensor.height == 32 and cfg.sensor.name == "custom"
    assert mos_config({"sensor.preset": "vlp16"}).sensor.height == 16


def test_params_file_sections(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    threshold: 0.3\n    min_points: 5\n"
                 "mos_node:\n  ros__parameters:\n    threshold: 0.7\n    qos:\n      reliability: reliable\n")
    assert load_params_file(f) == {"threshold": 0.7, "min_points": 5, "qos.reliability": "reliable"}
    f.write_text("other_node:\n  ros__parameters:\n    a: 1\n")
    with pytest.raises(ConfigError, match="no parameters for node"):
        load_params_file(f)
    f.write_text("mos_node:\n  threshold: 0.3\n")
    with pytest.raises(ConfigError, match="ros__parameters"):
        load_params_file(f)
    f.write_text("mos_node: [\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_params_file(f)
    with pytest.raises(ConfigError, match="not found"):
        load_params_file(tmp_path / "missing.yaml")


def test_describe_is_a_table_of_every_parameter():
    table = describe()
    assert all(f"`{p.name}`" in table for p in PARAMS)
