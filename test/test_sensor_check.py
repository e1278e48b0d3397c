"""Which sensor a cloud comes from, from its rings and field of view (ros2_mos.sensor_check)."""

import numpy as np
import pytest

from ros2_mos.config import SENSOR_PRESETS, MosConfig
from ros2_mos.sensor_check import closest_preset, cloud_shape, fits, mismatch_message
from ros2_mos.sim.lidar import beam_elevations, column_azimuths


def rings_cloud(name: str, seed: int = 0, dropout: float = 0.3) -> np.ndarray:
    """One sweep of preset ``name``: every beam at every column, random ranges 3-60 m, some rays lost (sky)."""
    sensor = SENSOR_PRESETS[name]
    rng = np.random.default_rng(seed)
    el = np.repeat(beam_elevations(sensor), sensor.width)
    az = np.tile(column_azimuths(sensor), sensor.height)
    r = rng.uniform(3.0, 60.0, len(el))
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
    from ros2_mos.config import SensorConfig
    from ros2_mos.pipeline import MosPipeline

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
    r = np.random.default_rng(3).uniform(3, 50, len(el))
    cloud = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    own_pipeline = MosPipeline(MosConfig(model=str(tiny_model_path), sensor=own))
    assert own_pipeline.process(cloud, None, 0.0).sensor_mismatch == ""
