"""Which sensor a cloud comes from, from its rings and field of view (ros2_mos.core.sensor_check)."""

import numpy as np
import pytest

from ros2_mos.core.config import SENSOR_PRESETS, MosConfig
from ros2_mos.core.projection import project
from ros2_mos.core.sensor_check import (
    MIN_AGREEING_NEIGHBOURS,
    MIN_NEIGHBOUR_PAIRS,
    closest_preset,
    cloud_shape,
    fits,
    implausible_message,
    mismatch_message,
    neighbour_agreement,
)
from ros2_mos.sim import SequenceSimulator
from ros2_mos.sim.lidar import beam_elevations, column_azimuths


def rings_cloud(name: str, seed: int = 0, dropout: float = 0.3) -> np.ndarray:
    """One sweep of preset ``name``: every beam at every column, ranges 5-55 m on a smooth surface (a LiDAR sees
    surfaces: ranges scattered at random are refused, see test_scattered_points_are_no_lidar_scan), some rays lost
    (sky)."""
    sensor = SENSOR_PRESETS[name]
    rng = np.random.default_rng(seed)
    el = np.repeat(beam_elevations(sensor), sensor.width)
    az = np.tile(column_azimuths(sensor), sensor.height)
    r = 30.0 + 25.0 * np.sin(3.0 * az + rng.uniform(0, 2 * np.pi)) * np.cos(el)
    keep = rng.random(len(el)) > dropout
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)[keep]
    return pts.astype(np.float32)


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_each_preset_is_recognised_and_fits_only_itself(name):
    points = rings_cloud(name)
    shape = cloud_shape(points)
    assert 0.9 * SENSOR_PRESETS[name].height <= shape.rings <= SENSOR_PRESETS[name].height  # a wedge may miss a ring
    assert closest_preset(shape) == name
    assert mismatch_message(points, SENSOR_PRESETS[name]) is None
    others = [o for o in SENSOR_PRESETS if o != name and fits(shape, SENSOR_PRESETS[o])]
    assert others == []  # no other preset's rows and field of view fit this cloud


def test_a_vlp16_cloud_against_the_hdl64_names_the_vlp16():
    message = mismatch_message(rings_cloud("vlp16"), SENSOR_PRESETS["hdl64"])
    assert message.startswith("the cloud does not fit the configured sensor hdl64 (64 rows, -25.0..+3.0 deg)")
    assert "~16 rings over -14.1..+14.1 deg" in message and "it looks like a vlp16" in message  # beam centres


def test_ring_counts_survive_per_laser_smear_and_tolerate_a_few_missing_rings():
    points = rings_cloud("hdl64").astype(np.float64)
    rng = np.random.default_rng(1)
    # Each laser's elevation off by up to +-0.05 deg (real calibration), points +-2 cm noisy.
    laser = np.arange(len(points)) % 64
    points[:, 2] += np.tan(np.radians(rng.uniform(-0.05, 0.05, 64)[laser])) * np.hypot(points[:, 0], points[:, 1])
    points += rng.normal(0, 0.01, points.shape)
    assert mismatch_message(points, SENSOR_PRESETS["hdl64"]) is None
    assert 56 <= cloud_shape(points).rings <= 72  # within the tolerance either way


def test_a_cloud_of_unknown_shape_and_a_tiny_cloud():
    rng = np.random.default_rng(2)
    blob = rng.uniform(-50, 50, (100_000, 3))  # no rings at all: uniform random points
    message = mismatch_message(blob, SENSOR_PRESETS["hdl64"])
    assert message is not None and "matches no known preset" in message
    assert cloud_shape(blob[:100]) is None and mismatch_message(blob[:100], SENSOR_PRESETS["hdl64"]) is None


def test_the_pipeline_flags_every_scan_of_a_mismatched_stream(tiny_model_path):
    from ros2_mos.core.config import SensorConfig
    from ros2_mos.core.pipeline import MosPipeline

    test32 = MosConfig(model=str(tiny_model_path)).sensor or None
    pipeline = MosPipeline(MosConfig(model=str(tiny_model_path)))
    assert test32 is None and pipeline.sensor.name == "test32"
    vlp = rings_cloud("vlp16")
    first = pipeline.process(vlp, None, 0.0)
    second = pipeline.process(vlp, None, 0.1)
    for result in (first, second):
        assert "does not fit the configured sensor test32" in result.sensor_mismatch and result.degraded
    assert "vlp16" in first.sensor_mismatch
    # A stream of the sensor's own shape is not flagged.
    own = SensorConfig("test32", 32, 512, 10.0, -20.0, 0.0, 100.0)
    el = np.repeat(np.linspace(np.radians(9.5), np.radians(-19.5), 32), 512)
    az = np.tile(np.linspace(np.pi, -np.pi, 512, endpoint=False), 32)
    r = 25.0 + 20.0 * np.sin(2.0 * az) * np.cos(el)  # a smooth surface
    cloud = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    own_pipeline = MosPipeline(MosConfig(model=str(tiny_model_path), sensor=own))
    assert own_pipeline.process(cloud, None, 0.0).sensor_mismatch == ""


# ----------------------------------------------------------------------------- a LiDAR scan at all? (issue 13)

def _range_image(points: np.ndarray, name: str) -> np.ndarray:
    return project(points, np.zeros(len(points), np.float32), SENSOR_PRESETS[name]).range


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_simulated_scans_of_every_preset_are_plausible_in_every_presets_image(name):
    points = SequenceSimulator(1, "benchmark", seed=4, sensor=name).scan(0).scan.points
    share, pairs = neighbour_agreement(_range_image(points, name))
    assert share > 0.9 and pairs > 10 * MIN_NEIGHBOUR_PAIRS, (share, pairs)
    # A cloud of another sensor is flagged as a mismatch (above), never refused as no scan.
    for other in SENSOR_PRESETS:
        assert implausible_message(_range_image(points, other)) is None, other


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_scattered_points_are_no_lidar_scan(name):
    rng = np.random.default_rng(0)
    cube = rng.uniform(-50, 50, (127_000, 3)).astype(np.float32)  # issue 13: KISS-ICP spent 9-18 s on it
    blob = rng.normal(scale=10.0, size=(127_000, 3)).astype(np.float32)
    for cloud in (cube, blob, cube * np.float32([1, 1, 0.05])):  # also flattened into the field of view
        share, pairs = neighbour_agreement(_range_image(cloud, name))
        assert share < MIN_AGREEING_NEIGHBOURS / 2 and pairs >= MIN_NEIGHBOUR_PAIRS, (share, pairs)
        assert implausible_message(_range_image(cloud, name)).startswith("not a plausible LiDAR scan: only ")
    # Too few scattered points to tell: no verdict (they are cheap for the odometry anyway).
    assert implausible_message(_range_image(cube[:3000], name)) is None


def test_the_reason_says_what_was_measured_and_what_a_scan_looks_like():
    cube = np.random.default_rng(0).uniform(-50, 50, (127_000, 3)).astype(np.float32)
    assert implausible_message(_range_image(cube, "hdl64")) == (
        "not a plausible LiDAR scan: only 13% of 4427 pairs of adjacent range-image pixels are within 5% in range "
        "(a scan of surfaces: over 35%; scattered points such as uniform random noise: ~10%)")
    assert neighbour_agreement(np.zeros((4, 8), np.float32)) == (1.0, 0)  # an empty image: nothing to judge
