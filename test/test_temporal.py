"""Temporal fusion (ros2_mos.core.temporal): the Bayes filter's arithmetic on hand-made range images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros2_mos.core.config import PostprocessConfig, SensorConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.projection import project
from ros2_mos.core.temporal import MAX_BELIEF, BeliefFilter, logit, sigmoid

# 8 beams over +-4 deg, 16 columns: a wall 10 m ahead fills the middle rows of a few columns.
SENSOR = SensorConfig(name="tiny", height=8, width=16, fov_up_deg=4.0, fov_down_deg=-4.0, min_range=0.5,
                      max_range=100.0)


def wall(distance: float) -> np.ndarray:
    """Points on a plane x = distance, one per row in the column straight ahead (azimuth 0)."""
    elevations = np.radians(np.linspace(-3.5, 3.5, 8))
    return np.stack([np.full(8, distance), np.zeros(8), distance * np.tan(elevations)], axis=1).astype(np.float32)


def image_of(points: np.ndarray):
    return project(points, np.zeros(len(points), np.float32), SENSOR)


def probability_image(image, p: float) -> np.ndarray:
    return np.where(image.mask, np.float32(p), np.float32(0.0))


def test_logit_and_sigmoid_are_inverse_and_clipped():
    assert logit(np.array([0.5], np.float32))[0] == pytest.approx(0.0, abs=1e-6)
    assert logit(np.array([0.8], np.float32))[0] == pytest.approx(math.log(4.0), rel=1e-5)
    assert logit(np.array([0.0, 1.0], np.float32)).tolist() == [-MAX_BELIEF, MAX_BELIEF]
    assert sigmoid(np.array([math.log(3.0)], np.float32))[0] == pytest.approx(0.75, rel=1e-5)


def test_a_surface_long_called_static_damps_one_scan_of_moving():
    fusion = BeliefFilter(SENSOR, weight=0.5)
    identity = np.eye(4)
    first = image_of(wall(10.0))
    fusion.fuse(probability_image(first, 0.001), first, identity)  # belief clipped to -4 when looked up
    second = image_of(wall(10.05))  # the same wall, 5 cm off (an odometry error)
    fused = fusion.fuse(probability_image(second, 0.6), second, identity)
    # logit(0.6) + 0.5 * (-4) = 0.405 - 2 = -1.595 -> p = 0.1687
    expected = 1.0 / (1.0 + math.exp(-(math.log(0.6 / 0.4) - 2.0)))
    assert fused[second.mask] == pytest.approx(expected, rel=1e-4)
    assert (fused[~second.mask] == 0).all()


def test_space_that_was_free_a_scan_ago_keeps_the_networks_word():
    fusion = BeliefFilter(SENSOR, weight=0.5)
    identity = np.eye(4)
    before = image_of(wall(20.0))  # the ray went 20 m: that space was free
    fusion.fuse(probability_image(before, 0.001), before, identity)
    now = image_of(wall(10.0))  # something now stands 10 m ahead
    fused = fusion.fuse(probability_image(now, 0.6), now, identity)
    assert fused[now.mask] == pytest.approx(0.6, rel=1e-4)


def test_the_previous_scan_is_looked_up_through_the_relative_pose():
    fusion = BeliefFilter(SENSOR, weight=1.0)
    before = image_of(wall(10.0))
    fusion.fuse(probability_image(before, 0.8), before, np.eye(4))  # belief log(4) = 1.386
    moved = np.eye(4)
    moved[0, 3] = 2.0  # the sensor drove 2 m towards the wall
    now = image_of(wall(8.0))  # the same wall, seen from 2 m closer
    fused = fusion.fuse(probability_image(now, 0.5), now, moved)
    # logit(0.5) + 1.0 * log(4) -> p = 0.8, wherever the moved point lands on a pixel of the old wall
    inside = now.mask
    assert np.count_nonzero(np.isclose(fused[inside], 0.8, rtol=1e-4)) >= 6
    # Without the pose, the 8 m points would be compared with 10 m ranges: no match, no prior.
    fusion.reset()
    fusion.fuse(probability_image(before, 0.8), before, np.eye(4))
    unmoved = fusion.fuse(probability_image(now, 0.5), now, np.eye(4))
    assert unmoved[inside] == pytest.approx(0.5, rel=1e-4)


def test_weight_zero_is_the_identity_and_keeps_no_state():
    fusion = BeliefFilter(SENSOR, weight=0.0)
    image = image_of(wall(10.0))
    p = probability_image(image, 0.6)
    assert fusion.fuse(p, image, np.eye(4)) is p
    assert fusion._probability is None


def test_a_reset_forgets_the_previous_scan():
    fusion = BeliefFilter(SENSOR, weight=0.5)
    image = image_of(wall(10.0))
    fusion.fuse(probability_image(image, 0.001), image, np.eye(4))
    fusion.reset()
    fused = fusion.fuse(probability_image(image, 0.6), image, np.eye(4))
    assert fused[image.mask] == pytest.approx(0.6, rel=1e-4)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), float("inf")])
def test_temporal_weight_is_checked(bad):
    with pytest.raises(ConfigError, match="temporal_weight"):
        PostprocessConfig(temporal_weight=bad)
