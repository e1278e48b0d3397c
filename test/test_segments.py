"""Segment consistency by hand: a partly moving car fills, a wall with one moving pixel and the ground do not."""

import numpy as np
import pytest

from ros2_mos.config import PostprocessConfig
from ros2_mos.errors import ConfigError
from ros2_mos.segments import connected_regions, fill_segments


def scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = 8, 64
    rng = np.full((h, w), 30.0, np.float32)  # a wall at 30 m
    z = np.full((h, w), 1.0, np.float32)
    rng[6:], z[6:] = 8.0, -1.7  # two ground rows (low z)
    rng[2:6, 10:20] = 10.0  # a car at 10 m: 4 x 10 pixels, its own segment (range jump 20 m)
    z[2:6, 10:20] = -0.8
    prob = np.zeros((h, w), np.float32)
    prob[2:6, 10:13] = 0.9  # its front edge is moving: 12 of 40 pixels
    prob[0, 40] = 0.95  # one pixel of the wall
    prob[7, 50] = 0.9  # one ground pixel
    return prob, rng, z


def test_a_segment_mostly_enough_moving_is_filled_and_nothing_else_changes():
    prob, rng, z = scene()
    out = fill_segments(prob, rng, z, threshold=0.5, fill_fraction=0.25)
    assert (out[2:6, 10:20] >= 0.5).all()  # 30 % of the car moved: all of it is labelled moving
    np.testing.assert_array_equal(out[2:6, 10:13], prob[2:6, 10:13])  # probabilities above the threshold are kept
    changed = out != prob
    changed[2:6, 10:20] = False
    assert not changed.any()  # the wall (1 of ~400 pixels) and the ground pixel stay as they were
    assert not (fill_segments(prob, rng, z, 0.5, 0.35)[2:6, 13:20] >= 0.5).any()  # 30 % < 35 %: no fill
    assert fill_segments(np.zeros_like(prob), rng, z, 0.5, 0.25) is not None


def test_segments_join_across_the_azimuth_seam_and_split_at_range_jumps():
    rng = np.zeros((2, 8), np.float32)
    rng[0, [0, 7]] = 10.0
    rng[0, 3] = 10.0
    rng[1, 3] = 20.0
    lab = connected_regions(rng > 0, rng, rel=0.05)
    assert lab[0, 0] == lab[0, 7]  # column 0 and 7 are neighbours on a 360-degree image
    assert lab[0, 3] != lab[1, 3] and lab[0, 3] != lab[0, 0]


def test_segment_fill_is_checked():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ConfigError):
            PostprocessConfig(segment_fill=bad)
