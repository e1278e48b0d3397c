"""Configuration: presets, fov estimation, YAML round trip and rejection of bad values."""

import re

import numpy as np
import pytest

from ros2_mos.config import SENSOR_PRESETS, MosConfig, SensorConfig, estimate_fov, sensor_preset
from ros2_mos.errors import ConfigError


def test_hdl64_preset_matches_lidar_mos():
    s = sensor_preset("HDL64")
    assert (s.height, s.width, s.fov_up_deg, s.fov_down_deg) == (64, 2048, 3.0, -25.0)
    assert {"vlp16", "vlp32c", "os1-64", "os1-128"} <= set(SENSOR_PRESETS)


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ConfigError, match="hdl64"):
        sensor_preset("hdl128")


@pytest.mark.parametrize("kwargs", [{"height": 0}, {"fov_up_deg": -30.0}, {"min_range": 5.0, "max_range": 1.0}])
def test_bad_sensor_values_are_rejected(kwargs):
    with pytest.raises(ConfigError):
        SensorConfig(**kwargs)


def test_estimate_fov_from_a_scan():
    rng = np.random.default_rng(0)
    elev = np.radians(rng.uniform(-24.8, 2.0, 50000))
    az = rng.uniform(-np.pi, np.pi, 50000)
    pts = np.column_stack([np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)]) * 20
    up, down = estimate_fov(pts)
    assert up == pytest.approx(2.1, abs=0.1) and down == pytest.approx(-24.9, abs=0.1)


def test_yaml_config_with_preset_and_nested_sections(tmp_path):
    path = tmp_path / "mos.yaml"
    path.write_text("sensor: vlp16\nthreshold: 0.6\npostprocess: {k: 3, window: 3}\nodometry: {max_range: 60.0}\n")
    cfg = MosConfig.from_yaml(path)
    assert cfg.sensor == sensor_preset("vlp16") and cfg.threshold == 0.6
    assert cfg.postprocess.k == 3 and cfg.odometry.max_range == 60.0


@pytest.mark.parametrize(
    "text, message",
    [("threshold: 1.5\n", "threshold"), ("knn: 3\n", "unknown keys"), ("postprocess: {mode: foo}\n", "mode"),
     ("sensor: {beams: 64}\n", "sensor: unknown keys"), ("- a\n", "mapping"),
     ("odometry: {point_stride: 0}\n", "point_stride"),
     ("odometry: {max_points_per_voxel: 0}\n", "max_points_per_voxel")],
)
def test_bad_yaml_values_are_rejected_with_the_key_named(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        MosConfig.from_yaml(path)


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        MosConfig.from_yaml(tmp_path / "none.yaml")


def test_yaml_files_that_cannot_be_read_are_one_line_errors(tmp_path):
    """Issue 13.10: non-UTF-8 or invalid YAML gave a traceback in train and in every --config."""
    from ros2_mos.config import read_yaml_mapping

    cases = {
        "latin1.yaml": (b"name: caf\xe9\n", "not UTF-8 text (byte 9)"),
        "broken.yaml": (b"name: [unclosed\n", "not valid YAML"),
        "list.yaml": (b"- a\n- b\n", "expected a mapping at the top level, got list"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ConfigError, match=re.escape(message)):
            read_yaml_mapping(tmp_path / name, "training config")
    with pytest.raises(ConfigError, match="training config not found"):
        read_yaml_mapping(tmp_path / "missing.yaml", "training config")
    (tmp_path / "empty.yaml").write_bytes(b"")
    assert read_yaml_mapping(tmp_path / "empty.yaml", "training config") == {}
