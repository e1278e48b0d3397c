"""Scans far apart registered to each other for autolabel's visibility (``ros2_mos.offline.viewpoints``): the math
on hand-made scenes with known poses, and a drive whose poses drift."""

from __future__ import annotations

import math

import numpy as np
import pytest
from drive_scenes import SENSOR, Mover, write_drive

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.errors import ConfigError, WorkerError
from ros2_mos.io.labels import instance_ids
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, write_poses
from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, scan_labels
from ros2_mos.offline.drives import FolderDrive
from ros2_mos.offline.viewpoints import PairRegistration, PairRegistrationConfig, PairRegistrationProcess, pose_change

#: A street with walls of different lengths on both sides and a few posts: every direction of motion is held.
STREET = [(-40, 80, 12, 13), (-40, 30, -13, -12), (35, 80, -14, -13), (10, 11, 6, 7), (25, 26, -8, -7),
          (45, 46, 5, 6)]


def pitched(angle_deg: float, z: float = 0.0) -> np.ndarray:
    """A pose turned about y by ``angle_deg`` and raised by ``z``."""
    a = math.radians(angle_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]
    pose[2, 3] = z
    return pose


#: A sensor as dense as an HDL-64E: its registered scans are thinned at 1.5 m, the scenes' 32-row sensor's at 1 m
DENSE = SensorConfig("scene64", 64, 2048, 3.0, -25.0, 0.0, 60.0)


@pytest.fixture(scope="module", params=[SENSOR, DENSE], ids=lambda sensor: sensor.name)
def street(request, tmp_path_factory) -> tuple[list[np.ndarray], np.ndarray, int]:
    """Two scans of a static street 10 m apart: their points, true poses and the sensor's rows."""
    folder = write_drive(tmp_path_factory.mktemp("street"), 11, lambda k: 1.0 * k, [], STREET, sensor=request.param)
    drive = list(FolderDrive(folder))
    return [drive[0].points, drive[10].points], np.asarray(FolderDrive(folder).poses)[[0, 10]], request.param.height


def test_config_is_checked():
    for bad in ({"voxel": 0.0}, {"voxel": float("nan")}, {"max_correspondence": float("inf")}, {"kernel": -1.0},
                {"max_turn": float("nan")}, {"from_offset": -1}, {"iterations": 0}, {"min_points": 2.5},
                {"map_points": 0}, {"source_voxel": 0.0}, {"source_voxel": float("inf")}):
        with pytest.raises(ConfigError):
            PairRegistrationConfig(**bad)
    PairRegistrationConfig(from_offset=0)  # 0: no pair is registered


def test_a_dense_sensor_s_registered_scan_is_thinned_more():
    config = PairRegistrationConfig(voxel=1.0, source_voxel=1.5, dense_rows=64)
    assert (config.source_voxel_for(128), config.source_voxel_for(64), config.source_voxel_for(32)) == (1.5, 1.5, 1.0)
    with pytest.raises(ConfigError):
        PairRegistrationConfig(dense_rows=2.5)


def test_pose_change_in_metres_and_degrees():
    assert pose_change(np.eye(4), pitched(3.0, 0.4)) == pytest.approx((0.4, 3.0))


def test_a_drifted_relative_pose_is_registered_back_and_serves_the_pair_both_ways(street):
    (points_a, points_b), (pose_a, pose_b), rows = street
    drift = pitched(1.5, 0.4)  # what KISS-ICP's pitch and height drift does over a few seconds
    pairs = PairRegistration(rows=rows)
    assert pairs.source_voxel == (1.5 if rows == 64 else 1.0)
    pairs.register(0, points_a, pose_a, [(10, points_b, pose_b @ drift)])
    assert (pairs.registered, pairs.refused) == (1, 0)
    seen_from_a = pairs.viewpoint_pose(0, pose_a, 10)
    # Point-to-point ICP between two single scans keeps ~0.1 m along this street even from the true pose (the
    # ground's rings are sampled at other places from 10 m on): far inside visibility's 0.5 m margin.
    shift, turn = pose_change(pose_b, seen_from_a)
    assert shift < 0.15 and turn < 0.3
    # scan 0 seen from scan 10 (at its drifted pose): the same relative pose, inverted
    seen_from_b = pairs.viewpoint_pose(10, pose_b @ drift, 0)
    np.testing.assert_allclose(np.linalg.inv(seen_from_b) @ (pose_b @ drift),
                               np.linalg.inv(pose_a) @ seen_from_a, atol=1e-9)
    assert pairs.viewpoint_pose(0, pose_a, 5) is None  # a pair never registered
    pairs.forget_before(1)
    assert pairs.viewpoint_pose(0, pose_a, 10) is None


def test_a_refinement_beyond_its_bounds_or_without_points_keeps_kiss_icp_s_pose(street):
    (points_a, points_b), (pose_a, pose_b), _ = street
    drifted = pose_b @ pitched(1.5, 0.4)
    tight = PairRegistration(PairRegistrationConfig(max_shift=0.1))
    tight.register(0, points_a, pose_a, [(10, points_b, drifted)])
    few = PairRegistration(PairRegistrationConfig(min_points=10**6))
    few.register(0, points_a, pose_a, [(10, points_b, drifted)])
    for pairs in (tight, few):
        assert (pairs.registered, pairs.refused) == (0, 1)
        np.testing.assert_allclose(pairs.viewpoint_pose(0, pose_a, 10), drifted, atol=1e-12)
    assert PairRegistration().wants(-5) and not PairRegistration().wants(2)
    assert not PairRegistration(PairRegistrationConfig(from_offset=0)).wants(40)
    with pytest.raises(ConfigError):
        PairRegistration().register(10, points_b, pose_b, [(0, points_a, pose_a)])


def test_a_parked_car_stays_static_though_the_drive_s_poses_drift_in_pitch_and_height(tmp_path):
    # The sensor passes a parked car 2.4 m beside its path; the drive's poses drift as KISS-ICP's did on a
    # simulated VLP-32C drive (pitch and height: 0.8 m and 1.6 deg over 40 scans). Scans 20-40 away then "see
    # through" the car where it stands; registered to each other, they see it where it is.
    parked = Mover((4.5, 1.8, 1.5), lambda k: (20.0, 2.4), 5)
    folder = write_drive(tmp_path, 40, lambda k: 1.0 * k, [parked], STREET)
    true = np.asarray(FolderDrive(folder).poses)
    write_poses(folder / "poses.txt", np.stack([p @ pitched(0.04 * k, 0.02 * k) for k, p in enumerate(true)]))
    seq = SemanticKittiSequence(folder)

    def moving_on_car(from_offset: int) -> int:
        labeler = AutoLabeler(SENSOR, AutolabelConfig(use_poses=True, online_cue=False,
                                                      pairs=PairRegistrationConfig(from_offset=from_offset)))
        work = tmp_path / f"work{from_offset}"
        work.mkdir()
        result = labeler.label(FolderDrive(folder), work)
        return sum(int(scan_labels(labeler, result, work, k, "semantickitti")[instance_ids(seq[k].labels) == 5].sum())
                   for k in range(len(seq)))

    assert moving_on_car(0) > 100  # the drifted poses alone: the parked car moves
    assert moving_on_car(5) == 0


@pytest.fixture(scope="module")
def drift_drive(tmp_path_factory) -> tuple[list[np.ndarray], np.ndarray]:
    """Twelve scans of the street 1 m apart, their poses drifting in pitch and height as KISS-ICP's did."""
    folder = write_drive(tmp_path_factory.mktemp("drift"), 12, lambda k: 1.0 * k, [], STREET)
    poses = np.stack([p @ pitched(0.1 * k, 0.03 * k) for k, p in enumerate(FolderDrive(folder).poses)])
    return [scan.points for scan in FolderDrive(folder)], poses


OFFSETS = (-10, -5, -2, 2, 5, 10)


def test_pairs_are_registered_as_the_scans_arrive(drift_drive):
    """Scan a is registered against a + 5 and a + 10 once a + 10 has arrived (the last scan: against what there is),
    with the relative poses the pairs registered one by one get."""
    scans, poses = drift_drive
    pairs = PairRegistration(PairRegistrationConfig(), OFFSETS, 12)
    done = [pairs.add(k, scans[k], poses[k]) for k in range(12)]
    assert done == [[]] * 10 + [[0], [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]]
    with pytest.raises(ConfigError, match="out of order"):
        pairs.add(3, scans[3], poses[3])
    one_by_one = PairRegistration()
    for a in (0, 6):
        one_by_one.register(a, scans[a], poses[a], [(b, scans[b], poses[b]) for b in (a + 5, a + 10) if b < 12])
    for a, b in ((0, 5), (0, 10), (6, 11)):
        pairs.wait_for(a)
        np.testing.assert_allclose(pairs.viewpoint_pose(a, poses[a], b), one_by_one.viewpoint_pose(a, poses[a], b),
                                   atol=1e-9)
    assert pairs.viewpoint_pose(6, poses[6], 16) is None
    early = PairRegistration(PairRegistrationConfig(), OFFSETS, 12)
    early.add(0, scans[0], poses[0])
    with pytest.raises(ConfigError, match="have not all arrived"):
        early.wait_for(0)


def test_pairs_registered_in_a_process_of_their_own_are_the_pairs_registered_here(drift_drive):
    scans, poses = drift_drive
    config = PairRegistrationConfig()
    assert type(PairRegistration.for_drive(config, OFFSETS, 12, SENSOR.height, own_process=False)) is PairRegistration
    no_pairs = PairRegistration.for_drive(config, (-2, 2), 12, SENSOR.height, own_process=True)
    assert type(no_pairs) is PairRegistration
    # the scenes' 32 rows, not the default 64: the process thins the scans as this one does
    here = PairRegistration(config, OFFSETS, 12, SENSOR.height)
    there = PairRegistration.for_drive(config, OFFSETS, 12, SENSOR.height, own_process=True)
    try:
        assert isinstance(there, PairRegistrationProcess)
        for k in range(10):
            there.add(k, scans[k], poses[k])
        with pytest.raises(ConfigError, match="have not all arrived"):  # scan 10 is not there: it would wait for ever
            there.wait_for(0)
        for k in range(10, 12):
            there.add(k, scans[k], poses[k])
        for k in range(12):
            assert here.add(k, scans[k], poses[k]) is not None
        for a in range(12):
            there.wait_for(a)
            for b in (a + 5, a + 10):
                if b < 12:
                    np.testing.assert_allclose(there.viewpoint_pose(a, poses[a], b),
                                               here.viewpoint_pose(a, poses[a], b), atol=1e-6)
        assert (there.registered, there.refused) == (here.registered, here.refused) and here.registered > 0
    finally:
        there.close()
    assert there._worker.returncode == 0


def test_the_registration_process_s_failure_is_one_error_here(drift_drive):
    scans, poses = drift_drive
    config = PairRegistrationConfig()
    broken = PairRegistration.for_drive(config, OFFSETS, 12, SENSOR.height, own_process=True)
    try:
        for k in range(12):  # one scan's points are no (N, 3) array: the process fails and says how
            broken.add(k, scans[k][:, :2] if k == 11 else scans[k], poses[k])
        with pytest.raises(WorkerError, match="pair registration failed at request 11: RuntimeError"):
            broken.wait_for(11)
    finally:
        broken.close()
    killed = PairRegistration.for_drive(config, OFFSETS, 12, SENSOR.height, own_process=True)
    try:
        killed.add(0, scans[0], poses[0])
        killed._worker._process.kill()  # as the kernel's OOM killer would
        for k in range(1, 12):
            killed.add(k, scans[k], poses[k])
        with pytest.raises(WorkerError, match="ended without its result"):
            killed.wait_for(0)
    finally:
        killed.close()
    for pairs in (broken, killed):
        assert pairs._worker.returncode is not None
