"""Configuration: presets, fov estimation, and rejection of bad values."""

import re

import numpy as np
import pytest

from ros2_mos.core.config import (
    SENSOR_PRESETS,
    MosConfig,
    OdometryConfig,
    PostprocessConfig,
    ResidualConfig,
    SensorConfig,
    estimate_fov,
    lidar_of,
    sensor_preset,
)
from ros2_mos.core.errors import ConfigError


def test_hdl64_preset_matches_lidar_mos():
    s = sensor_preset("HDL64")
    assert (s.height, s.width, s.fov_up_deg, s.fov_down_deg) == (64, 2048, 3.0, -25.0)
    assert {"vlp16", "vlp32c", "os1-64", "os1-128"} <= set(SENSOR_PRESETS)


def test_a_models_coarser_image_maps_back_to_its_lidar():
    half = SensorConfig("hdl64", 64, 1024, 3.0, -25.0)
    assert lidar_of(half) is sensor_preset("hdl64")  # 64 x 2048: what the LiDAR fires
    for other in (SensorConfig("hdl64", 32, 1024, 3.0, -25.0), SensorConfig("custom", 64, 1024, 3.0, -25.0),
                  SensorConfig("hdl64", 64, 1024, 2.0, -25.0)):
        assert lidar_of(other) is other


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


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: PostprocessConfig(mode="foo"), "postprocess mode must be one of knn, nearest; got 'foo'"),
        (lambda: PostprocessConfig(sigma=0.0), "postprocess sigma must be > 0, got 0.0"),
        (lambda: PostprocessConfig(k=1.5), "postprocess k must be an integer, got 1.5"),
        (lambda: PostprocessConfig(temporal_weight=float("nan")), "postprocess temporal_weight must be a finite"),
        (lambda: OdometryConfig(point_stride=0), "odometry point_stride must be >= 1, got 0"),
        (lambda: OdometryConfig(max_points_per_voxel=1001), "odometry max_points_per_voxel must be <= 1000"),
        (lambda: OdometryConfig(voxel_size=0.0), "odometry voxel_size must be > 0, got 0.0"),
        (lambda: OdometryConfig(deskew=1), "odometry deskew must be a bool, got 1"),
        (lambda: MosConfig(threshold=1.5), "mos threshold must be <= 1, got 1.5"),
        (lambda: MosConfig(geometry_backend="jax"), "mos geometry_backend must be one of numpy, torch"),
        (lambda: SensorConfig(max_range=float("inf")), "sensor 'hdl64': max_range must be a finite number"),
        (lambda: ResidualConfig(max_range=float("nan")), "residuals max_range must be a finite number"),
        (lambda: ResidualConfig(max_range=0.0), "residuals max_range must be > 0, got 0.0"),
        (lambda: ResidualConfig(max_range=1e4), "residuals max_range must be <= 1000"),
        (lambda: ResidualConfig(min_range=60.0), "need 0 <= min_range < max_range <= 1000, got 60.0 and 50.0"),
    ],
)
def test_each_knob_is_checked_from_its_one_definition(build, message):
    """Issue 17.2: type, limits and choices live in the dataclass field (config.knob) and nowhere else."""
    with pytest.raises(ConfigError, match=re.escape(message)):
        build()


def test_optional_knobs_accept_none_and_ros_params_derive_from_the_same_knob():
    from ros2_mos.ros.params import SPECS

    assert OdometryConfig(voxel_size=None).voxel_size is None and MosConfig(model=None).model is None
    spec = SPECS["postprocess.window"]
    assert (spec.type, spec.default, spec.min, spec.max) == (int, 5, 1, 15)
    assert SPECS["odometry.voxel_size"].default == 0.0 and SPECS["model"].default == ""
    assert SPECS["sensor.height"].description == "custom sensor: range image rows (beams)"


def test_the_residual_window_is_the_models_unless_set():
    """max_range None (ROS param 0): the model's own far end, or LiDAR-MOS's 50 m for a model that records none."""
    from ros2_mos.ros.params import SPECS, mos_config

    assert ResidualConfig().upper == 50.0 and ResidualConfig().for_model(None).upper == 50.0
    assert ResidualConfig().for_model(100.0) == ResidualConfig(2.0, 100.0)
    assert ResidualConfig(max_range=45.0).for_model(100.0).upper == 45.0
    with pytest.raises(ConfigError, match="min_range < max_range"):
        ResidualConfig(min_range=40.0).for_model(30.0)
    assert SPECS["residuals.max_range"].default == 0.0
    assert mos_config({"residuals.max_range": 0.0}).residuals.max_range is None
    assert mos_config({"residuals.max_range": 80.0}).residuals.upper == 80.0


def test_yaml_files_that_cannot_be_read_are_one_line_errors(tmp_path):
    """Issue 13.10: non-UTF-8 or invalid YAML gave a traceback in train and in every --config."""
    from ros2_mos.core.config import read_yaml_mapping

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
