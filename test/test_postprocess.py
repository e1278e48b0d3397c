"""kNN back-projection on hand-made range images, on the compiled kernels and on the numpy code."""

import numpy as np
import pytest

from ros2_mos.core.config import PostprocessConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.postprocess import backproject, knn_backproject, nearest_backproject
from ros2_mos.core.projection import PixelIndex


def pixels(rows, cols, ranges):
    n = len(rows)
    return PixelIndex(
        np.array(cols, np.int32), np.array(rows, np.int32), np.array(ranges, np.float32), np.ones(n, bool)
    )


def test_occluded_point_takes_the_label_of_neighbours_at_its_own_range(geometry_code):
    # A moving pedestrian (prob 1) at 5 m covers pixel (2, 2); behind it a wall at 20 m (prob 0).
    rows, cols = np.mgrid[0:5, 0:8]
    rng = (20.0 + 0.011 * cols + 0.029 * rows).astype(np.float32)  # distinct ranges: no ties in the top k
    prob = np.zeros((5, 8), np.float32)
    wall_range = float(rng[2, 2])
    rng[2, 2], prob[2, 2] = 5.0, 1.0
    # Point A is the pedestrian itself; point B is a wall point that lost pixel (2, 2) to it.
    pix = pixels([2, 2], [2, 2], [5.0, wall_range])
    cfg = PostprocessConfig(k=5, window=5, sigma=1.0, cutoff=1.0)
    np.testing.assert_allclose(nearest_backproject(prob, pix), [1.0, 1.0])
    # A: only its own pixel lies within 1 m -> 1.  B: its own pixel (distance 0) votes 1,
    # the 4 nearest wall pixels vote 0 -> mean 0.2.
    np.testing.assert_allclose(knn_backproject(prob, rng, pix, cfg), [1.0, 0.2])


def test_empty_pixels_and_far_neighbours_do_not_vote(geometry_code):
    rng = np.zeros((3, 6), np.float32)
    prob = np.ones((3, 6), np.float32)
    rng[1, 3], prob[1, 3] = 10.0, 0.0
    rng[1, 4], prob[1, 4] = 30.0, 1.0  # beyond the cut-off
    pix = pixels([1], [3], [10.0])
    assert knn_backproject(prob, rng, pix, PostprocessConfig(k=5, window=3))[0] == 0.0


def test_window_wraps_around_in_azimuth(geometry_code):
    rng = np.zeros((3, 6), np.float32)
    prob = np.zeros((3, 6), np.float32)
    rng[1, 0] = 10.0
    rng[1, 5], prob[1, 5] = 10.2, 1.0  # the left neighbour of column 0 is column 5
    pix = pixels([1], [0], [10.0])
    assert knn_backproject(prob, rng, pix, PostprocessConfig(k=2, window=3))[0] == pytest.approx(0.5)


def test_mode_nearest_uses_own_pixel():
    prob = np.arange(12, dtype=np.float32).reshape(3, 4)
    pix = pixels([0, 2], [1, 3], [1.0, 1.0])
    np.testing.assert_array_equal(backproject(prob, prob, pix, PostprocessConfig(mode="nearest")), [1, 11])


@pytest.mark.parametrize(
    "kwargs", [{"mode": "bilateral"}, {"window": 4}, {"k": 0}, {"k": 10, "window": 3}, {"cutoff": 0}]
)
def test_invalid_settings_are_rejected(kwargs):
    with pytest.raises(ConfigError):
        PostprocessConfig(**kwargs)


def test_thresholded_knn_gives_the_same_labels_as_the_full_vote(geometry_code):
    rng = np.random.default_rng(3)
    h, w, n = 16, 64, 4000
    range_image = rng.uniform(5, 30, (h, w)).astype(np.float32)
    range_image[rng.random((h, w)) < 0.1] = 0.0
    prob = np.zeros((h, w), np.float32)
    prob[4:9, 10:20] = rng.uniform(0.3, 1.0, (5, 10))
    pix = PixelIndex(rng.integers(0, w, n).astype(np.int32), rng.integers(0, h, n).astype(np.int32),
                     rng.uniform(5, 30, n).astype(np.float32), np.ones(n, bool))
    cfg = PostprocessConfig(cutoff=3.0)
    full = knn_backproject(prob, range_image, pix, cfg)
    fast = knn_backproject(prob, range_image, pix, cfg, threshold=0.5)
    np.testing.assert_array_equal(full >= 0.5, fast >= 0.5)
    assert 0 < (full >= 0.5).sum() < n


def test_a_window_with_one_label_keeps_the_own_pixel_and_a_mixed_one_votes(geometry_code):
    rng = np.full((3, 8), 10.0, np.float32)
    prob = np.full((3, 8), 0.9, np.float32)
    pix = pixels([1, 1], [2, 6], [10.0, 10.0])
    cfg = PostprocessConfig(k=3, window=3)
    # Every window pixel above 0.5: the point keeps its own 0.9 (a vote could not change its label).
    assert knn_backproject(prob, rng, pix, cfg, threshold=0.5)[0] == np.float32(0.9)
    prob[0, 7] = 0.0  # column 6's window now holds one value below: it votes (ties at 10 m: all kept)
    got = knn_backproject(prob, rng, pix, cfg, threshold=0.5)
    assert got[0] == np.float32(0.9) and got[1] == pytest.approx((8 * 0.9) / 9, abs=1e-6)
