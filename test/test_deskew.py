"""Deskewing a rotating LiDAR's sweep: the firing phase, the motion between poses, the correction by hand, and a
skewed sweep of the simulator's LiDAR made to match the sweep cast from the scan's pose."""

from __future__ import annotations

import numpy as np
import pytest

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.deskew import deskew, deskew_wanted, drive_motions, rotation_log, scan_motions, sweep_phase
from ros2_mos.core.errors import ConfigError
from ros2_mos.sim.geometry import TriangleSoup, box
from ros2_mos.sim.lidar import Lidar
from ros2_mos.sim.presets import SensorEffects
from ros2_mos.sim.raycast import SoupScene

SMALL = SensorConfig("small", 32, 512, 10.0, -25.0, 0.0, 120.0)
NO_NOISE = SensorEffects(range_sigma=0.0, dropout=0.0, grazing_dropout=0.0, far_dropout=0.0, remission_sigma=0.0,
                         ego_clearance=0.0)


def pose(x: float, y: float, yaw: float) -> np.ndarray:
    out = np.eye(4)
    out[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    out[:2, 3] = x, y
    return out


def test_the_sweep_starts_behind_and_turns_clockwise_through_the_front() -> None:
    points = np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, -5.0, 0.0], [-5.0, 1e-6, 0.0], [-5.0, -1e-6, 0.0]])
    assert sweep_phase(points) == pytest.approx([0.0, -0.25, 0.25, -0.5, 0.5], abs=1e-6)


def test_the_motion_of_a_scan_is_the_mean_step_between_the_poses_around_it() -> None:
    poses = np.stack([pose(0.0, 0.0, 0.0), pose(1.0, 0.0, 0.0), pose(3.0, 0.0, 0.0)])
    motions = scan_motions(poses)
    assert motions[0] == pytest.approx([0, 0, 0, 1, 0, 0])  # the first step only
    assert motions[1] == pytest.approx([0, 0, 0, 1.5, 0, 0])  # (1 + 2) / 2
    assert motions[2] == pytest.approx([0, 0, 0, 2, 0, 0])  # the last step only
    turning = scan_motions(np.stack([pose(0.0, 0.0, 0.0), pose(0.0, 0.0, 0.1)]))
    assert turning[0] == pytest.approx([0, 0, 0.1, 0, 0, 0])
    assert rotation_log(pose(0.0, 0.0, -0.3)[:3, :3]) == pytest.approx([0, 0, -0.3])
    assert scan_motions(np.eye(4)[None]) == pytest.approx(np.zeros((1, 6)))
    # a scan dropped between the 2nd and the 3rd (0.2 s): that step is one sweep's motion again (2 m in 0.2 s: 1 m)
    timed = scan_motions(np.stack([pose(0.0, 0.0, 0.0), pose(1.0, 0.0, 0.0), pose(3.0, 0.0, 0.0), pose(4.0, 0, 0)]),
                         np.array([0.0, 0.1, 0.3, 0.4]))
    assert timed == pytest.approx(np.tile([0, 0, 0, 1.0, 0, 0], (4, 1)))
    for bad in (np.array([0.0, 0.1, 0.1]), np.array([0.0, 0.1]), np.array([0.0, np.nan, 0.2])):
        with pytest.raises(ConfigError, match="stamps"):
            scan_motions(poses, bad)
    with pytest.raises(ConfigError, match="poses"):
        scan_motions(np.eye(4))


def test_a_drive_is_deskewed_where_the_mode_or_its_word_says_and_its_stamps_scale_what_they_can() -> None:
    assert [deskew_wanted(mode, said) for mode in ("on", "off", "auto") for said in (True, False, None)] == [
        True, True, True, False, False, False, True, False, False]
    poses = np.stack([pose(0.0, 0.0, 0.0), pose(1.0, 0.0, 0.0), pose(3.0, 0.0, 0.0), pose(4.0, 0, 0)])
    # stamps that increase scale the steps (the dropped scan: 1 m a sweep throughout); others, or none, do not
    assert drive_motions(poses, np.array([0.0, 0.1, 0.3, 0.4])) == pytest.approx(np.tile([0, 0, 0, 1.0, 0, 0], (4, 1)))
    for stamps in (None, np.array([0.0, 0.1, 0.1, 0.2]), np.array([0.0, 0.1, 0.2])):
        assert drive_motions(poses, stamps) == pytest.approx(scan_motions(poses))


def test_deskewing_by_hand() -> None:
    """Driving 1 m per sweep along x: a point on the left (phase -0.25) was measured from 0.25 m back, one on the
    right from 0.25 m ahead, one ahead from the scan's pose; turning 0.2 rad per sweep, the left one is turned by
    -0.05 rad."""
    points = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [2.0, 0.0, 0.5]], np.float32)
    moved = deskew(points, np.array([0, 0, 0, 1.0, 0, 0]))
    assert moved.dtype == np.float32 and moved.flags.c_contiguous  # rows: KISS-ICP copies other layouts slowly
    assert moved == pytest.approx(np.array([[-0.25, 1.0, 0.0], [0.25, -1.0, 0.0], [2.0, 0.0, 0.5]]), abs=1e-6)
    turned = deskew(points[:1], np.array([0, 0, 0.2, 0, 0, 0]))
    assert turned[0] == pytest.approx([np.sin(0.05), np.cos(0.05), 0.0], abs=1e-6)
    # rolling 0.4 rad per sweep (about x): the left point turned by -0.1 rad about x
    assert deskew(points[:1], np.array([0.4, 0, 0, 0, 0, 0]))[0] == pytest.approx(
        [0.0, np.cos(0.1), -np.sin(0.1)], abs=1e-6)
    # pitching 0.8 rad per sweep (about y): a point 45 degrees left of ahead (phase -0.125) turned by -0.1 rad about y
    assert deskew(np.array([[1.0, 1.0, 0.0]], np.float32), np.array([0, 0.8, 0, 0, 0, 0]))[0] == pytest.approx(
        [np.cos(0.1), 1.0, np.sin(0.1)], abs=1e-6)
    # any axis and a translation: each point turned by its phase's share of the rotation (the rotation matrix of the
    # axis-angle, by hand) and moved by its share of the translation
    rng = np.random.default_rng(7)
    cloud = rng.uniform(-20, 20, (50, 3)).astype(np.float32)
    motion = np.array([0.03, -0.05, 0.2, 1.2, -0.3, 0.05])
    angle = np.linalg.norm(motion[:3])
    k = motion[:3] / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    phase = -np.arctan2(cloud[:, 1].astype(np.float64), cloud[:, 0]) / (2 * np.pi)
    want = [(np.eye(3) * np.cos(s * angle) + np.sin(s * angle) * cross + (1 - np.cos(s * angle)) * np.outer(k, k)) @ p
            + s * motion[3:] for p, s in zip(cloud.astype(np.float64), phase)]
    assert deskew(cloud, motion) == pytest.approx(np.array(want), abs=1e-5)
    assert deskew(points, np.zeros(6)) == pytest.approx(points)
    for bad in (np.zeros(5), np.array([0, 0, 0, np.nan, 0, 0])):
        with pytest.raises(ConfigError, match="motion"):
            deskew(points, bad)


def test_a_skewed_sweep_deskewed_lies_on_the_yards_surfaces() -> None:
    """The simulator's LiDAR in a walled yard with a post, driving 1.2 m and turning 0.1 rad per sweep, each column
    cast from the pose of its firing time: its points lie up to 0.6 m off the walls and the post (seen from the
    scan's pose, the identity); deskewed by the motion between the poses a sweep before and after, within 5 cm
    (the wrong way round: worse than not at all)."""
    walls = [box((1.0, 60.0, 8.0), (25.0, 0.0, 4.0)), box((1.0, 60.0, 8.0), (-25.0, 0.0, 4.0)),
             box((60.0, 1.0, 8.0), (0.0, 20.0, 4.0)), box((60.0, 1.0, 8.0), (0.0, -20.0, 4.0))]
    post = box((0.4, 0.4, 3.0), (-8.0, 3.0, 1.5))
    scene = [SoupScene(TriangleSoup.labelled(np.concatenate([*walls, post]), 50), np.zeros(3))]
    lidar = Lidar(SMALL, NO_NOISE)

    def lidar_pose(phase: float) -> np.ndarray:  # 1.2 m and 0.1 rad per sweep, 1.7 m over the ground
        out = pose(1.2 * phase, 0.0, 0.1 * phase)
        out[2, 3] = 1.7
        return out

    skewed = lidar.scan(scene, np.stack([lidar_pose(s) for s in lidar.column_phase]), np.random.default_rng(0))
    motion = scan_motions(np.stack([lidar_pose(-1.0), lidar_pose(0.0), lidar_pose(1.0)]))[1]

    def off_surfaces(points: np.ndarray) -> float:
        x, y = points[:, 0].astype(np.float64), points[:, 1].astype(np.float64)
        to_wall = np.minimum.reduce([np.abs(x - 24.5), np.abs(x + 24.5), np.abs(y - 19.5), np.abs(y + 19.5)])
        outside = np.hypot(np.maximum(np.abs(x + 8.0) - 0.2, 0), np.maximum(np.abs(y - 3.0) - 0.2, 0))
        inside = np.minimum(0.2 - np.abs(x + 8.0), 0.2 - np.abs(y - 3.0))
        to_post = np.where(outside > 0, outside, np.maximum(inside, 0))
        return float(np.percentile(np.minimum(to_wall, to_post), 99))

    assert off_surfaces(skewed.points) > 0.3
    assert off_surfaces(deskew(skewed.points, motion)) < 0.05
    assert off_surfaces(deskew(skewed.points, -motion)) > off_surfaces(skewed.points)


def test_a_clouds_own_point_times_give_the_phases_and_deskew_takes_them() -> None:
    """An Ouster-like cloud with ``t`` in ns over one sweep (0 to 100 ms): phases -0.5 to 0.5, linear; a point with a
    NaN coordinate is not among them. No time field, equal times or a NaN time: no phases."""
    from ros2_mos.io.bags import empty_cloud, point_field
    from ros2_mos.io.pointcloud2 import decode_xyz_intensity, fill_from_records, sweep_phases

    def cloud(times: list[float], dtype: str = "<u4", x: tuple[float, ...] = (1.0, 2.0, float("nan"), 4.0, 5.0)):
        records = np.zeros(len(times), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                                                 ("t", dtype)]))
        records["x"], records["y"], records["t"] = x[: len(times)], 1.0, times
        return fill_from_records(empty_cloud(0, "os_sensor"), records, field_factory=point_field)

    msg = cloud([0, 25e6, 40e6, 50e6, 100e6])
    _, _, valid = decode_xyz_intensity(msg)
    assert valid.tolist() == [0, 1, 3, 4]
    assert sweep_phases(msg, valid) == pytest.approx([-0.5, -0.25, 0.0, 0.5])
    assert sweep_phases(cloud([7, 7, 7, 7, 7]), valid) is None
    assert sweep_phases(cloud([0.0, 0.05, 0.06, float("nan"), 0.1], "<f4"), valid) is None
    plain = fill_from_records(empty_cloud(0, "velodyne"), np.zeros(2, np.dtype([("x", "<f4"), ("y", "<f4"),
                                                                                 ("z", "<f4")])),
                              field_factory=point_field)
    assert sweep_phases(plain, np.arange(2)) is None
    points = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]], np.float32)  # the phases given win over the azimuth
    assert deskew(points, np.array([0, 0, 0, 1.0, 0, 0]), np.array([0.5, -0.5])) == pytest.approx(
        np.array([[0.5, 1.0, 0.0], [-0.5, -1.0, 0.0]]))
    with pytest.raises(ConfigError, match="phase"):
        deskew(points, np.zeros(6), np.array([0.0]))


def test_a_bag_whose_clouds_carry_point_times_is_deskewed_by_them_under_auto(tmp_path) -> None:
    """A bag of clouds with a ``time`` field (Velodyne's driver) says its sweeps are skewed, and each scan carries
    its points' phases (the zero-range point left out as autolabel leaves it out); a bag of x, y, z, intensity says
    nothing."""
    from ros2_mos.io.bags import BagWriter, empty_cloud, point_field, write_scans_bag
    from ros2_mos.io.pointcloud2 import fill_from_records
    from ros2_mos.offline.autolabel import AutoLabeler
    from ros2_mos.offline.drives import BagDrive

    records = np.zeros(4, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                                    ("time", "<f4")]))
    records["x"], records["y"], records["time"] = [3.0, 0.0, 4.0, 5.0], [1.0, 0.0, 1.0, 1.0], [0.0, 0.02, 0.06, 0.1]
    with BagWriter(tmp_path / "timed") as writer:
        for stamp in (0, 100_000_000):
            writer.write("/points", stamp, fill_from_records(empty_cloud(stamp, "velodyne"), records,
                                                             field_factory=point_field))
    timed = BagDrive(tmp_path / "timed")
    assert timed.skewed is True
    scan = next(iter(timed))
    assert scan.kept.tolist() == [0, 2, 3] and scan.phase == pytest.approx([-0.5, 0.1, 0.5])
    ones, dark = np.ones((3, 3), np.float32), np.zeros(3, np.float32)
    write_scans_bag(tmp_path / "plain", [(0, ones, dark), (100_000_000, ones, dark)])
    plain = BagDrive(tmp_path / "plain")
    assert plain.skewed is None and next(iter(plain)).phase is None
    assert AutoLabeler(SMALL).deskews(timed) and not AutoLabeler(SMALL).deskews(plain)
