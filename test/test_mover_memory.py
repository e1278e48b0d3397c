"""The memory of movers by hand (core/mover_memory.py): a car seen moving keeps its label while it stands, until
max_age; a false positive is forgotten after max_age; what a mover passed is not labelled; reset forgets."""

import math

import numpy as np
import pytest

from ros2_mos.core.config import MosConfig, MoverMemoryConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.mover_memory import MoverMemory, voxel_keys
from ros2_mos.core.projection import PixelIndex, RangeImage

H, W = 8, 64
THRESHOLD = 0.5


class Scene:
    """A hand-made scan: a wall at 30 m all around (rows 0-5), two ground rows 8 m away (z = -1.7), and boxes
    (cars, poles) given by their pixels and world position; one point per pixel."""

    def __init__(self, ego_x: float = 0.0) -> None:
        self.world = np.zeros((H, W, 3), np.float64)
        az = math.pi * (1.0 - 2.0 * (np.arange(W) + 0.5) / W)
        self.world[:6, :, 0] = 30.0 * np.cos(az)
        self.world[:6, :, 1] = 30.0 * np.sin(az)
        self.world[:6, :, 2] = 1.0 + 0.5 * np.arange(6)[:, None]
        self.world[6:, :, 0] = 8.0 * np.cos(az)
        self.world[6:, :, 1] = 8.0 * np.sin(az)
        self.world[6:, :, 2] = -1.7
        self.prob = np.zeros((H, W), np.float32)
        self.ego = np.eye(4)
        self.ego[0, 3] = ego_x

    def box(self, rows: slice, cols: slice, x: float, y0: float = 0.25, prob: float = 0.0) -> "Scene":
        """A surface facing the sensor at world x, 0.5 m per column from y0 and 0.4 m per row (voxel centres)."""
        r = np.arange(rows.start, rows.stop)[:, None]
        c = np.arange(cols.start, cols.stop)[None, :]
        self.world[rows, cols, 0] = x
        self.world[rows, cols, 1] = y0 + 0.5 * (c - cols.start)
        self.world[rows, cols, 2] = -0.75 + 0.5 * (rows.stop - 1 - r)
        self.prob[rows, cols] = prob
        return self

    def image(self) -> RangeImage:
        xyz = (self.world - self.ego[:3, 3]).astype(np.float32)
        rng = np.linalg.norm(xyz, axis=-1).astype(np.float32)
        v, u = np.mgrid[:H, :W]
        pixels = PixelIndex(u.ravel().astype(np.int32), v.ravel().astype(np.int32), rng.ravel(),
                            np.ones(H * W, bool))
        return RangeImage(range=rng, xyz=xyz, remission=np.zeros((H, W), np.float32),
                          point_index=np.arange(H * W, dtype=np.int32).reshape(H, W), pixels=pixels)

    def run(self, memory: MoverMemory, t: float) -> np.ndarray:
        """The (H, W) labels after the memory, point by point (one point per pixel)."""
        image = self.image()
        prob_image, point_prob = memory.apply(self.prob, self.prob.ravel().copy(), image, self.ego, t, THRESHOLD)
        labels = (point_prob >= THRESHOLD).reshape(H, W)
        np.testing.assert_array_equal(labels, prob_image >= THRESHOLD)  # image and points agree
        return labels


def memory(max_age: float = 2.0, share: float = 0.5, min_scans: int = 2, **kw) -> MoverMemory:
    return MoverMemory(MoverMemoryConfig(enabled=True, max_age=max_age, share=share, min_scans=min_scans, **kw))


CAR_ROWS = slice(2, 6)


def drive_and_stop(mem: MoverMemory, ego_step: float = 0.0) -> None:
    """A car 10 m ahead moves 2 columns (1 m) a scan for 5 scans (t = 0 .. 0.4), labelled moving, and stops at
    columns 18-27, where it was last seen moving at t = 0.4."""
    for k in range(5):
        car = Scene(ego_step * k).box(CAR_ROWS, slice(10 + 2 * k, 20 + 2 * k), 10.25, 0.25 + k, 0.9)
        labels = car.run(mem, 0.1 * k)
        assert labels[CAR_ROWS, 10 + 2 * k:20 + 2 * k].all() and labels.sum() == 40


def standing(ego_x: float = 0.0) -> Scene:
    return Scene(ego_x).box(CAR_ROWS, slice(18, 28), 10.25, 4.25, 0.0)  # the network: static


def test_a_stopped_car_keeps_its_label_until_max_age_after_it_was_last_seen_moving():
    mem = memory(max_age=2.0)
    drive_and_stop(mem)
    for t in (0.5, 1.0, 2.0, 2.35):  # last seen moving at 0.4: remembered up to 2.4
        labels = standing().run(mem, t)
        assert labels[CAR_ROWS, 18:28].all(), t
        assert labels.sum() == 40, t  # only the car: not the wall, not the ground
    assert not standing().run(mem, 2.45).any()  # 2.05 s after: forgotten
    assert mem.size == 0


def test_the_memory_is_kept_in_the_world_frame_while_the_ego_vehicle_moves():
    mem = memory(max_age=2.0)
    drive_and_stop(mem, ego_step=0.5)  # the ego drives 0.5 m a scan towards the car
    labels = standing(ego_x=3.0).run(mem, 1.0)  # 3 m on: the car is 7 m away in the sensor frame
    assert labels[CAR_ROWS, 18:28].all() and labels.sum() == 40


def test_labels_of_the_memory_do_not_refresh_it():
    mem = memory(max_age=1.0)
    drive_and_stop(mem)
    for k in range(1, 10):  # labelled moving by the memory every 0.1 s: no refresh
        standing().run(mem, 0.4 + 0.1 * k)
    assert standing().run(mem, 1.35).any()
    assert not standing().run(mem, 1.45).any()


def test_a_false_positive_blob_is_forgotten_after_max_age():
    """A pole labelled moving in two scans (the network's mistake) is labelled moving for max_age seconds at most;
    labelled moving in one scan only (min_scans 2), it is not remembered at all."""
    pole = slice(40, 42)
    once = memory(max_age=3.0)
    Scene().box(slice(0, 6), pole, 5.25, 0.25, 0.9).run(once, 10.0)
    assert not Scene().box(slice(0, 6), pole, 5.25, 0.25, 0.0).run(once, 10.1).any()
    mem = memory(max_age=3.0)
    for t in (9.9, 10.0):  # the false positive, last at t = 10 s
        Scene().box(slice(0, 6), pole, 5.25, 0.25, 0.9).run(mem, t)
    survived = []
    for k in range(1, 51):  # then static in the network's output for 5 s
        t = 10.0 + 0.1 * k
        if Scene().box(slice(0, 6), pole, 5.25, 0.25, 0.0).run(mem, t).any():
            survived.append(t)
    assert survived and max(survived) <= 10.0 + 3.0 + 1e-9 and max(survived) > 12.85


def test_no_trail_static_things_next_to_where_a_mover_passed_stay_static():
    """A mover passes in front of a parked car: its last points (t = 0.4) coincide with the parked car's front
    columns 30-31 (8 of the parked car's 40 pixels: 20 % < share 50 %); the wall behind and the ground are not
    labelled either, and neither is the parked car when only its remembered part is tested alone."""
    mem = memory(max_age=5.0, share=0.5)
    for k in range(4):
        Scene().box(CAR_ROWS, slice(10 + 4 * k, 20 + 4 * k), 10.25, 0.25 + 2 * k, 0.9).run(mem, 0.1 * k)
    for t in (0.35, 0.4):  # the mover's tail where the car stands, in two scans
        Scene().box(CAR_ROWS, slice(30, 32), 12.25, 0.25, 0.9).run(mem, t)
    parked = Scene().box(CAR_ROWS, slice(30, 40), 12.25, 0.25, 0.0)
    labels = parked.run(mem, 0.5)
    assert not labels.any()  # the wall where the mover was, the ground, the parked car: all static
    # The same parked car with its front columns alone in view (occluded behind): 8 of 8 pixels remembered.
    occluded = Scene().box(CAR_ROWS, slice(30, 32), 12.25, 0.25, 0.0).box(CAR_ROWS, slice(32, 40), 4.25, 0.25, 0.0)
    assert occluded.run(mem, 0.6)[CAR_ROWS, 30:32].all()
    # A lower share: the parked car (20 %) is labelled.
    mem_low = memory(max_age=5.0, share=0.2)
    for t in (0.35, 0.4):
        Scene().box(CAR_ROWS, slice(30, 32), 12.25, 0.25, 0.9).run(mem_low, t)
    assert parked.run(mem_low, 0.5)[CAR_ROWS, 30:40].all()


def test_moving_ground_is_not_remembered():
    mem = memory()
    scene = Scene()
    scene.prob[6:, 20:30] = 0.9  # the network labels ground moving (under a car)
    scene.run(mem, 0.0)
    assert mem.size == 0
    assert not Scene().run(mem, 0.1).any()


def test_reset_forgets():
    mem = memory(max_age=2.0)
    drive_and_stop(mem)
    assert mem.size > 0
    mem.reset()
    assert mem.size == 0
    assert not standing().run(mem, 0.5).any()


def test_a_voxel_counts_once_it_was_moving_in_min_scans_scans():
    mem = memory(max_age=2.0, min_scans=5)
    drive_and_stop(mem)  # the last columns were moving in fewer than 5 scans: too little of the car is remembered
    assert not standing().run(mem, 0.5).any()
    for k in range(5):  # a car seen moving in place 5 times (creeping within its voxels)
        Scene().box(CAR_ROWS, slice(40, 50), 15.25, 0.25, 0.9).run(mem, 1.0 + 0.1 * k)
    assert Scene().box(CAR_ROWS, slice(40, 50), 15.25, 0.25, 0.0).run(mem, 1.5)[CAR_ROWS, 40:50].all()


def test_disabled_changes_nothing():
    mem = MoverMemory(MoverMemoryConfig(enabled=False))
    drive_and_stop_scene = Scene().box(CAR_ROWS, slice(10, 20), 10.25, 0.25, 0.9)
    image = drive_and_stop_scene.image()
    prob = drive_and_stop_scene.prob
    point_prob = prob.ravel().copy()
    out = mem.apply(prob, point_prob, image, np.eye(4), 0.0, THRESHOLD)
    assert out[0] is prob and out[1] is point_prob and mem.size == 0


def test_the_voxel_count_is_capped_keeping_the_newest():
    mem = MoverMemory(MoverMemoryConfig(enabled=True, max_age=100.0, min_scans=1), max_voxels=50)
    Scene().box(CAR_ROWS, slice(10, 20), 10.25, 0.25, 0.9).run(mem, 0.0)  # 40 voxels
    Scene().box(CAR_ROWS, slice(30, 40), 20.25, 0.25, 0.9).run(mem, 0.1)  # 40 more: 30 of the old ones dropped
    assert mem.size == 50
    new = voxel_keys(Scene().box(CAR_ROWS, slice(30, 40), 20.25, 0.25).world[CAR_ROWS, 30:40].reshape(-1, 3), 0.5)
    assert mem.remembered(new, 0.1).all()


@pytest.mark.parametrize("field,bad", [
    ("max_age", float("nan")), ("max_age", float("inf")), ("max_age", -1.0), ("max_age", 0.0), ("max_age", 1e4),
    ("voxel_size", float("nan")), ("voxel_size", float("inf")), ("voxel_size", -0.5), ("voxel_size", 0.0),
    ("share", float("nan")), ("share", -0.1), ("share", 0.0), ("share", 1.5), ("enabled", "yes"),
    ("min_scans", 0), ("min_scans", 2.5), ("min_scans", float("nan")),
])
def test_parameters_are_checked(field, bad):
    with pytest.raises(ConfigError, match=f"movers {field}"):
        MoverMemoryConfig(**{field: bad})


def test_the_pipeline_config_and_node_parameters_carry_it():
    from ros2_mos.ros.params import SPECS, defaults, mos_config

    assert MosConfig().movers == MoverMemoryConfig()
    values = {**defaults(), "movers.enabled": True, "movers.max_age": 4.0, "movers.share": 0.6}
    assert mos_config(values).movers == MoverMemoryConfig(enabled=True, max_age=4.0, share=0.6)
    assert SPECS["movers.max_age"].min == 0.0 and SPECS["movers.max_age"].knob.above
    with pytest.raises(ConfigError):
        mos_config({**defaults(), "movers.max_age": float("nan")})
