"""The compiled geometry kernels give bit-identical results to the numpy code, and load (or not) cleanly.

test_projection.py and test_residuals.py run their hand-computed cases on both; here dense random scans of
every sensor preset, with the edge cases mixed in (points at the origin's axes, on the fov edges, outside
the range limits, several points on one pixel, exact range ties), are compared array by array.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from ros2_mos.core import kernels
from ros2_mos.core.config import SENSOR_PRESETS, PostprocessConfig, ResidualConfig, SensorConfig
from ros2_mos.core.postprocess import knn_backproject
from ros2_mos.core.projection import pixel_index, pixel_index_columns, project, project_range
from ros2_mos.core.residuals import free_space_image, free_space_images, past_range_image, residual_image
from ros2_mos.core.segments import connected_regions, grow_regions
from ros2_mos.offline.objects import attach_to_nearest, local_ground, voxel_clusters

WINDOW = ResidualConfig(2.0, 50.0)
SENSORS = list(SENSOR_PRESETS.values()) + [
    SensorConfig("narrow", height=10, width=8, fov_up_deg=5.0, fov_down_deg=-5.0, min_range=1.0, max_range=30.0)]


def scan(seed: int, n: int = 40000) -> np.ndarray:
    """A dense random scan with the awkward cases in it."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.5, 130.0, n)
    yaw = rng.uniform(-np.pi, np.pi, n)
    pitch = np.radians(rng.uniform(-50.0, 30.0, n))
    pts = np.stack([r * np.cos(pitch) * np.cos(yaw), r * np.cos(pitch) * np.sin(yaw), r * np.sin(pitch)], 1)
    edge = np.array([[5.0, 0.0, 0.0], [-5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, -5.0, 0.0], [-5.0, -0.0, 0.0],
                     [0.0, 0.0, 5.0], [0.0, 0.0, -5.0], [3.0, 3.0, 0.0], [-3.0, 3.0, -3.0], [1e-3, 0.0, 0.0]])
    ties = np.repeat(pts[:50], 3, axis=0)  # the same point three times: exact ties on one pixel
    return np.concatenate([pts, edge, ties, pts[:200] * 1.0001]).astype(np.float32)


def pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.3, 0.3)
    t = np.eye(4)
    t[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    t[:3, 3] = rng.uniform(-4.0, 4.0, 3)
    return t


def both(fn):
    """fn() on the compiled kernels and on the numpy code."""
    if not kernels.enabled():
        pytest.fail(f"the compiled kernels are not in use here: {kernels.status()} (make install builds them)")
    compiled = fn()
    with kernels.disabled():
        reference = fn()
    return compiled, reference


@pytest.mark.parametrize("sensor", SENSORS, ids=lambda s: s.name)
def test_pixels_and_projection_are_bit_identical(sensor):
    pts = scan(1)
    got, want = both(lambda: pixel_index(pts, sensor))
    for field in ("u", "v", "range", "in_image"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
    x, y, z = np.array(pts.T, order="C")
    got, want = both(lambda: pixel_index_columns(x, y, z, sensor))
    np.testing.assert_array_equal(got.u, want.u)
    np.testing.assert_array_equal(got.v, want.v)
    remission = np.linspace(0, 1, len(pts), dtype=np.float32)
    got, want = both(lambda: project(pts, remission, sensor))
    for field in ("range", "xyz", "remission", "point_index"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
    got, want = both(lambda: project_range(pts, sensor))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("signed", [True, False])
def test_residuals_and_free_space_are_bit_identical(signed):
    sensor = SENSOR_PRESETS["hdl64"]
    current_pose, past_pose = pose(4), pose(5)
    current = scan(2, n=120000)
    # The same surfaces seen from the past pose, half of them moved: residuals of all signs and sizes.
    moved = current.copy()
    moved[::2] *= np.float32(1.05)
    to_past = np.linalg.inv(past_pose) @ current_pose
    past = (moved @ to_past[:3, :3].T + to_past[:3, 3]).astype(np.float32)
    image = project(current, np.zeros(len(current), np.float32), sensor)
    got, want = both(lambda: past_range_image(past, past_pose, current_pose, sensor))
    np.testing.assert_array_equal(got, want)
    got, want = both(lambda: residual_image(image.range, past_range_image(past, past_pose, current_pose, sensor),
                                            WINDOW, signed))
    np.testing.assert_array_equal(got, want)
    assert np.count_nonzero(got) > 1000
    past_own = project_range(past, sensor)
    got, want = both(lambda: free_space_image(image.xyz, image.mask, past_own, to_past, sensor, WINDOW))
    np.testing.assert_array_equal(got, want)
    assert np.count_nonzero(got) > 1000
    buffered = [(past_own, past_pose), (project_range(current, sensor), current_pose)]
    got, want = both(lambda: free_space_images(image.xyz, image.mask, current_pose, buffered, (1, 2, 3), sensor,
                                               WINDOW))
    np.testing.assert_array_equal(got, want)
    assert not got[2].any()  # no third past scan: zero


@pytest.mark.parametrize("sensor", [SENSOR_PRESETS["hdl64"], SENSOR_PRESETS["vlp16"], SENSORS[-1]],
                         ids=lambda s: s.name)
def test_connected_regions_are_the_same_labels(sensor):
    image = project(scan(3), np.zeros(len(scan(3)), np.float32), sensor)
    valid = image.range > 0
    valid[:, ::7] = False  # gaps that split regions
    got, want = both(lambda: connected_regions(valid, image.range, rel=0.05))
    np.testing.assert_array_equal(got, want)
    assert len(np.unique(got[got >= 0])) > 10 and (got[~valid] == -1).all()
    # Pixels of one region carry its smallest pixel id.
    ids = np.arange(valid.size).reshape(valid.shape)
    assert (got[valid] <= ids[valid]).all() and (got[valid][got[valid] == ids[valid]]).size > 0
    seeds = np.random.default_rng(4).random(valid.shape) < 0.2
    for fraction in (0.0, 0.2, 0.5, 1.0):
        grown, reference = both(lambda: grow_regions(seeds, got, fraction))
        np.testing.assert_array_equal(grown, reference)
        assert grown.any() and not grown[~valid].any()


@pytest.mark.parametrize("voxel", [0.05, 0.2, 0.3])
def test_voxel_clusters_are_the_same_clusters(voxel):
    pts = scan(7)[:, :3] / 10.0  # dense enough near the centre for large clusters, sparse farther out
    groups = (np.arange(len(pts)) % 3).astype(np.int64)
    for grouped in (None, groups):
        got, want = both(lambda: voxel_clusters(pts, voxel, grouped))
        np.testing.assert_array_equal(got, want)
        sizes = np.bincount(got)
        assert 10 < len(sizes) < len(pts) and sizes.max() > 100  # many clusters, some large: a test that can fail
    # by hand: two cells touching at a corner are one cluster, a free cell apart is another; numbered by smallest
    cells = np.array([0, 5, 6, 20, 40], np.int64)
    np.testing.assert_array_equal(kernels.voxel_clusters(cells, np.array([1, 20], np.int64)), [0, 1, 1, 0, 0])
    with pytest.raises(ValueError, match="sorted and unique"):
        kernels.voxel_clusters(np.array([3, 1], np.int64), np.array([1], np.int64))
    with pytest.raises(ValueError, match="positive steps"):
        kernels.voxel_clusters(cells, np.array([0], np.int64))


@pytest.mark.parametrize("drop", [np.inf, 1.5, 0.1])
def test_local_ground_is_the_same_ground(drop):
    pts = scan(8)[:, :3] / 3.0  # cells of 1 m: sparse far out, crowded near the centre
    pts[::97, 2] -= 5.0  # returns under the road, for the outlier rule
    got, want = both(lambda: local_ground(pts, 1.0, 2, drop))
    np.testing.assert_array_equal(got, want)
    assert len(np.unique(got)) > 100
    if np.isfinite(drop):  # the rule drops points, so the ground differs from the plain lowest point's
        assert (got != local_ground(pts, 1.0, 2)).sum() > 100
    with pytest.raises(ValueError, match="outside"):
        kernels.local_ground(pts[:2], np.array([0, 9], np.int64), (3, 3), 1, 1.5)


@pytest.mark.parametrize("reach", [0.2, 0.45])
def test_attach_to_nearest_gives_the_same_objects(reach):
    pts = scan(9)[:, :3] / 2.0  # crowded near the centre: loose points within reach of several objects
    objects = (np.floor(pts[:, 0] / 0.7).astype(np.int64) % 7).astype(np.int32)
    objects[np.random.default_rng(3).random(len(pts)) < 0.6] = -1
    loose = np.flatnonzero(objects < 0)[::2]
    got_ids, want_ids = objects.copy(), objects.copy()
    got, want = both(lambda: attach_to_nearest(pts, loose, got_ids if kernels.enabled() else want_ids, reach))
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got_ids, want_ids)
    assert 100 < got.sum() < len(loose)  # some attached, some not: a test that can fail
    with pytest.raises(ValueError, match="outside the cloud"):
        kernels.attach_nearest(pts, np.array([len(pts)]), np.zeros(1, np.int64), reach, np.zeros(1, np.int64),
                               np.zeros(1, np.int32), 0.1, np.zeros((1, 2), np.int64), objects.copy())


@pytest.mark.parametrize("window,k", [(5, 5), (3, 9), (7, 4)])
def test_knn_vote_agrees(window, k):
    pts = scan(5)
    sensor = SENSOR_PRESETS["hdl64"]
    image = project(pts, np.zeros(len(pts), np.float32), sensor)
    prob = np.random.default_rng(6).random(image.range.shape).astype(np.float32) * image.mask
    config = PostprocessConfig(k=k, window=window, cutoff=2.0)
    for threshold in (None, 0.5):
        got, want = both(lambda: knn_backproject(prob, image.range, image.pixels, config, threshold))
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-7)  # float32 sums in another order
        np.testing.assert_array_equal(got >= 0.5, want >= 0.5)


def test_disabled_runs_the_numpy_code_and_status_says_which():
    assert kernels.enabled(), kernels.status()
    assert kernels.status() == "compiled kernels"
    with kernels.disabled():
        assert not kernels.enabled()
        assert kernels.status().startswith("numpy code")
    assert kernels.enabled()


def test_switched_off_in_the_environment_and_a_stale_build_fall_back_to_numpy(monkeypatch):
    env = dict(os.environ, ROS2_MOS_KERNELS="0")
    out = subprocess.run([sys.executable, "-c", "from ros2_mos.core import kernels; "
                          "print(kernels.enabled(), kernels.status())"], env=env, capture_output=True, text=True,
                         check=True).stdout
    assert out.startswith("False numpy code (compiled kernels off: ROS2_MOS_KERNELS=0)")
    monkeypatch.setattr(kernels, "ABI", kernels.ABI + 1)
    lib, status = kernels._load()
    assert lib is None and "stale" in status


def test_bad_shapes_raise():
    sensor = SENSOR_PRESETS["vlp16"]
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        kernels.project(np.zeros((4, 2), np.float32), sensor)
    with pytest.raises(ValueError, match="different lengths"):
        kernels.project((np.zeros(3, np.float32), np.zeros(3, np.float32), np.zeros(2, np.float32)), sensor)
    with pytest.raises(ValueError, match="pixels"):
        kernels.free_space(np.zeros((3, 10), np.float32), np.arange(3), np.eye(4), sensor,
                           np.zeros((16, 1024), np.float32), 2.0, 50.0)
    with pytest.raises(ValueError, match="shapes"):
        kernels.residual(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.float32), 2.0, 50.0, True)
    with pytest.raises(ValueError, match="kNN vote"):
        kernels.knn_vote(np.zeros((2, 3), np.float32), np.zeros((2, 3), np.float32), np.array([3]), np.array([0]),
                         np.ones(1), 3, 3, np.ones(9), 1.0, 0.5)
    with pytest.raises(ValueError, match="connected regions"):
        kernels.connected_regions(np.zeros((2, 3), bool), np.zeros((3, 2), np.float32), 0.05, 0.3)
