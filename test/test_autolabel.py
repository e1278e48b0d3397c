"""The offline labeller (``ros2-mos autolabel``) on hand-made drives with hand-known answers, its stages' math, and
its command end to end on a simulated drive."""

from __future__ import annotations

import dataclasses
import importlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from drive_scenes import SENSOR, WALL, Mover, write_drive
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.core.config import SensorConfig, sensor_preset
from ros2_mos.core.errors import ConfigError, DatasetError
from ros2_mos.core.projection import pixel_index
from ros2_mos.io.labels import instance_ids, semantic_ids
from ros2_mos.io.semantic_kitti import KITTI_TR, SemanticKittiSequence, read_poses, read_scan, write_scan
from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, box_shift, label_objects, scan_labels
from ros2_mos.offline.drives import FolderDrive, _scan
from ros2_mos.offline.objects import (
    ObjectConfig,
    ScanObjects,
    VehicleReturns,
    attach_below,
    attach_over,
    attach_to_nearest,
    blind_floor,
    find_objects,
    local_ground,
    moving_clusters,
    on_vehicle,
    split_long_clusters,
    voxel_clusters,
)
from ros2_mos.offline.visibility import neighbourhood_min

runner = CliRunner()
WALLS = [(-40, 80, 12, 13), (-40, 80, -13, -12)]


def label_scene(tmp_path: Path, n: int, ego, movers, walls=WALLS, **settings):
    folder = write_drive(tmp_path, n, ego, movers, walls)
    labeler = AutoLabeler(SENSOR, AutolabelConfig(use_poses=True, **settings))
    work = tmp_path / "work"
    work.mkdir()
    result = labeler.label(FolderDrive(folder), work)
    seq = SemanticKittiSequence(folder)

    def share(k: int, inst: int, convention: str) -> float:
        """The share of the object's points in scan k labelled moving."""
        mine = instance_ids(seq[k].labels) == inst
        return float(scan_labels(labeler, result, work, k, convention)[mine].mean())

    def others(k: int, inst: int, convention: str) -> int:
        """Points of scan k not on the object and labelled moving."""
        mine = instance_ids(seq[k].labels) == inst
        return int(scan_labels(labeler, result, work, k, convention)[~mine].sum())

    return seq, share, others, (labeler, result, work)


# -- stages -----------------------------------------------------------------------------------------------------
def test_local_ground_is_the_lowest_point_nearby(geometry_code):
    pts = np.array([[0.2, 0.2, 0.0], [0.7, 0.3, 1.5], [5.5, 0.5, 0.3], [5.2, 0.4, 2.0]], np.float32)
    ground = local_ground(pts, cell=1.0, radius=1)
    assert ground.tolist() == pytest.approx([0.0, 0.0, 0.3, 0.3])  # cells 0 and 5 are 5 apart: separate


def test_local_ground_leaves_out_spurious_returns_under_the_road(geometry_code):
    # A flat road at z -1.7 over 7 x 7 one-metre cells, nine spurious returns 4.5 m under it in cell (3, 3) (as on the
    # real 08a under the car ahead), a car body 1 m above the road in cell (4, 3).
    xs, ys = np.meshgrid(np.arange(7) + 0.5, np.arange(7) + 0.5)
    road = np.column_stack([xs.ravel(), ys.ravel(), np.full(49, -1.7)])
    spurious = np.column_stack([np.full(9, 3.5), np.linspace(3.1, 3.9, 9), np.full(9, -6.2)])
    body = np.array([[4.5, 3.5, -0.7]])
    pts = np.vstack([road, spurious, body]).astype(np.float32)
    plain = local_ground(pts, cell=1.0, radius=2)
    assert plain[-1] == pytest.approx(-6.2)  # the car body would stand 5.5 m above "the ground"
    robust = local_ground(pts, cell=1.0, radius=2, outlier_drop=1.5)
    # The neighbourhood's median lowest point is the road (-1.7); the returns 4.5 m under it are left out.
    assert robust.tolist() == pytest.approx([-1.7] * len(pts))
    # A step down of 1 m (a kerb, a slope) is not an outlier: the lower side stays the ground beside it.
    pts[:21, 2] = -2.7  # cells with y < 3
    step = local_ground(pts[:49], cell=1.0, radius=2, outlier_drop=1.5)
    assert step[21:28].tolist() == pytest.approx([-2.7] * 7)  # y 3-4, within two cells of the lower side


def test_voxel_clusters_link_26_neighbours_and_split_at_a_free_voxel(geometry_code):
    a = np.array([[0.1, 0.1, 0.1], [0.5, 0.5, 0.5], [0.9, 0.1, 0.9]])  # diagonal neighbours of 0.4 m voxels
    b = np.array([[2.1, 0.1, 0.1], [2.5, 0.1, 0.1]])  # one free voxel (x 1.2-1.6... 2.0) away
    ids = voxel_clusters(np.vstack([a, b]), 0.4)
    assert len(set(ids[:3])) == 1 and len(set(ids[3:])) == 1 and ids[0] != ids[3]


def test_voxel_clusters_in_groups_never_join_across_groups(geometry_code):
    # Two touching pairs of points; as one set the four make one cluster, in groups (0, 0, 1, 1) two; within a group
    # a free voxel still splits.
    pts = np.array([[0.0, 0, 0], [0.5, 0, 0], [0.2, 0.1, 0], [0.7, 0.1, 0], [5.0, 0, 0]], np.float32)
    assert len(set(voxel_clusters(pts[:4], 0.4).tolist())) == 1
    grouped = voxel_clusters(pts, 0.4, groups=np.array([0, 0, 1, 1, 1]))
    assert grouped[0] == grouped[1] and grouped[2] == grouped[3] and grouped[0] != grouped[2]
    assert grouped[4] not in (grouped[0], grouped[2])


def test_a_cluster_too_long_is_cut_with_half_size_voxels_and_the_ids_stay_compact(geometry_code):
    # Two cars 4.5 m long, 0.4 m apart bumper to bumper: one cluster with 0.4 m voxels (x 4.4-4.8 and 4.8-5.2 touch),
    # 9.4 m long; cut with 0.2 m voxels (x 4.6-4.8 is free). A pedestrian stands apart, its cluster short.
    x = np.arange(0.0, 4.55, 0.1)
    car = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    pedestrian = np.array([[20.0, 0.0, 0.0], [20.0, 0.0, 0.3]])
    pts = np.vstack([car, car + [4.9, 0.0, 0.0], pedestrian]).astype(np.float32)
    n = len(car)
    cluster = np.array([0] * (2 * n) + [1, 1])
    assert voxel_clusters(pts[: 2 * n], 0.4).max() == 0  # the two cars are one cluster at 0.4 m
    ids = split_long_clusters(pts, cluster, ObjectConfig(voxel=0.4, max_length=8.0))
    # the pedestrian keeps the first id, the two cars are the next two, in the order of their voxels
    assert ids.tolist() == [1] * n + [2] * n + [0, 0]
    assert split_long_clusters(pts, cluster, ObjectConfig(voxel=0.4, max_length=10.0)).tolist() == cluster.tolist()


def test_loose_points_go_to_the_nearest_object_within_reach_seen_from_above(geometry_code):
    # Two objects (ids 0 and 1) whose nearest points lie at x = 0 and x = 2; low points beside them.
    points = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [2.0, 0.0, 1.0], [3.0, 0.0, 1.0],
                       [0.55, 0.0, 0.2],   # 0.55 m from object 0, 1.45 m from object 1: object 0
                       [1.45, 0.0, 0.2],   # 0.55 m from object 1: object 1
                       [0.0, 0.95, 0.2],   # 0.95 m from object 0: too far
                       [0.0, -0.45, 0.05],  # close, but 0.05 m above the ground: ground
                       [-1.0, 0.6, 0.25]], np.float32)  # 0.6 m beside object 0's other point
    low = np.flatnonzero((points[:, 2] > 0.08) & (points[:, 2] <= 0.3))  # as find_objects picks them
    point_object = np.array([0, 0, 1, 1, -1, -1, -1, -1, -1], np.int32)
    attached = attach_to_nearest(points, low, point_object, 0.7)
    assert point_object.tolist() == [0, 0, 1, 1, 0, 1, -1, -1, 0]
    assert attached.tolist() == [False] * 4 + [True, True, False, False, True]
    # With a 0.4 m reach, none is close enough.
    point_object = np.array([0, 0, 1, 1, -1, -1, -1, -1, -1], np.int32)
    attach_to_nearest(points, low, point_object, 0.4)
    assert point_object.tolist() == [0, 0, 1, 1, -1, -1, -1, -1, -1]


def test_a_ring_piece_beside_an_object_joins_it_and_one_apart_does_not():
    rng = np.random.default_rng(1)
    ground = np.column_stack([rng.uniform(-30, 30, 4000), rng.uniform(-30, 30, 4000), np.zeros(4000)])
    car = np.column_stack([rng.uniform(5, 9.5, 800), rng.uniform(2, 3.8, 800), rng.uniform(0.3, 1.5, 800)])
    # 5 returns (under min_points), 0.15 m beside the car seen from above and 0.8 m over its top: no voxel joins them
    beside = np.column_stack([np.linspace(6, 7, 5), np.full(5, 3.95), np.full(5, 2.3)])
    apart = np.column_stack([np.linspace(6, 7, 5), np.full(5, 6.0), np.full(5, 1.0)])  # 2.2 m away
    pts = np.vstack([ground, car, beside, apart]).astype(np.float32)
    found = find_objects(pts)
    car_id = found.point_object[4000]
    assert car_id >= 0 and (found.point_object[4800:4805] == car_id).all() and found.attached[4800:4805].all()
    assert (found.point_object[4805:] == -1).all()
    alone = find_objects(pts, ObjectConfig(attach_fragments=False))
    assert (alone.point_object[4800:] == -1).all()
    assert found.counts[car_id] == alone.counts[car_id] == 800  # joined by label, not counted as the object's own


def test_a_column_under_an_object_joins_it_ring_by_ring_and_the_road_at_its_foot_does_not(geometry_code):
    sensor = SensorConfig("column8", 8, 360, 3.0, -25.0, 0.0, 80.0)  # rows 3.5 degrees apart, row v centred at
    pitch = np.radians(3.0 - 3.5 * (np.arange(8) + 0.5))  # 3 - 3.5 (v + 0.5) degrees

    def at(row: int, x: float) -> list[float]:
        return [x, 0.0, x * np.tan(pitch[row])]

    def ground(row: int) -> list[float]:
        return at(row, 1.73 / np.tan(-pitch[row]))

    # A car's side 5 m ahead: its ring in row 3 is on the object; rows 4 and 5 lie under it (in a sparse sensor's
    # blind spot, the local ground); the road meets it in row 6 (4.81 m, 0.27 m below row 5 and 0.19 m nearer:
    # 55 degrees) and row 7 (4.03 m).
    points = np.array([at(3, 5.0), at(4, 5.0), at(5, 5.0), ground(6), ground(7)], np.float32)
    assert pixel_index(points, sensor).v.tolist() == [3, 4, 5, 6, 7]

    def joined(steep: float, which: np.ndarray) -> list[int]:
        point_object = np.array([0] + [-1] * (len(which) - 1), np.int32)
        attach_below(which, np.arange(1, len(which)), point_object, sensor, steep)
        return point_object.tolist()

    assert joined(70.0, points) == [0, 0, 0, -1, -1]  # the side ring by ring; 55 degrees is not steep enough
    # At 45 degrees the road in row 6 would be steep enough, but it continues the road below it (row 7): not joined.
    assert joined(45.0, points) == [0, 0, 0, -1, -1]
    assert joined(45.0, points[:4]) == [0, 0, 0, 0]  # nothing below it: it joins


def test_a_far_cars_lowest_ring_joins_it_however_far_below_the_road_ring_lies(geometry_code):
    # A sparse sensor: 16 rows 1.875 degrees apart, 1.73 m over a flat road. A car 29.1 m ahead: its face in row 8
    # (1.25 m up), its lowest ring in row 9 (0.30 m up); row 10 meets the road 21.1 m out, 8 m nearer. The lowest
    # ring rises 0.30 m over that road ring: more than the ground step (0.15 m), so it is the car's, not the road
    # continued (a step that grew by 3 % of the 8 m between them, 0.39 m, left it to the ground).
    sensor = SensorConfig("column16", 16, 360, 15.0, -15.0, 0.0, 80.0)
    pitch = np.radians(15.0 - 1.875 * (np.arange(16) + 0.5))

    def at(row: int, x: float) -> list[float]:
        return [x, 0.0, x * np.tan(pitch[row])]

    road = 1.73 / np.tan(-pitch[10])
    car = 1.43 / np.tan(-pitch[9])
    points = np.array([at(8, car), at(9, car), at(10, road)], np.float32)
    assert pixel_index(points, sensor).v.tolist() == [8, 9, 10]
    assert road == pytest.approx(21.1, abs=0.05) and car == pytest.approx(29.1, abs=0.05)
    point_object = np.array([0, -1, -1], np.int32)
    attach_below(points, np.arange(1, 3), point_object, sensor, 70.0)
    assert point_object.tolist() == [0, 0, -1]
    # On a road that rises 0.1 m over those 8 m the ring is the road continued: not joined.
    points[1, 2] = points[2, 2] + 0.1
    point_object = np.array([0, -1, -1], np.int32)
    attach_below(points, np.arange(1, 3), point_object, sensor, 70.0)
    assert point_object.tolist() == [0, -1, -1]


def test_a_ring_under_an_objects_face_joins_it_and_the_road_in_front_does_not(geometry_code):
    sensor = SensorConfig("column8", 8, 360, 3.0, -25.0, 0.0, 80.0)  # rows 3.5 degrees apart, as above
    pitch = np.radians(3.0 - 3.5 * (np.arange(8) + 0.5))

    def at(row: int, x: float) -> list[float]:
        return [x, 0.0, x * np.tan(pitch[row])]

    # A car's face 5 m ahead in rows 3 and 4; row 5 passes under it and meets its recessed wheels 0.3 m behind the
    # face (0.41 m lower: 54 degrees, not steep), 0.19 m above the road it meets in row 6 (4.81 m, 0.49 m nearer: too
    # steep to continue the road); row 7 the road (4.03 m).
    points = np.array([at(3, 5.0), at(4, 5.0), at(5, 5.3), at(6, 1.73 / np.tan(-pitch[6])),
                       at(7, 1.73 / np.tan(-pitch[7]))], np.float32)
    assert pixel_index(points, sensor).v.tolist() == [3, 4, 5, 6, 7]

    def joined(under: float, under_ok: np.ndarray | None = None) -> list[int]:
        point_object = np.array([0, -1, -1, -1, -1], np.int32)
        attached = attach_below(points, np.arange(1, 5), point_object, sensor, 70.0, under=under, under_ok=under_ok)
        assert attached.tolist() == [False] + [o >= 0 for o in point_object[1:]]
        return point_object.tolist()

    assert joined(0.0) == [0, 0, -1, -1, -1]  # the face ring by ring; the wheels' ring is not steep under it
    assert joined(0.6) == [0, 0, 0, -1, -1]  # 0.3 m behind the face: under it; the road in front is nearer
    assert joined(0.2) == [0, 0, -1, -1, -1]  # farther behind than allowed
    # Only the points allowed to (find_objects: those clear of the local ground by attach_under_lift)
    assert joined(0.6, np.array([True, True, False, True, True])) == [0, 0, -1, -1, -1]
    assert joined(0.6, np.array([False, False, True, False, False])) == [0, 0, 0, -1, -1]


def test_a_stack_of_rings_over_an_object_joins_it_and_a_crown_far_above_it_does_not(geometry_code):
    sensor = SensorConfig("column8", 8, 360, 3.0, -25.0, 0.0, 80.0)  # rows 3.5 degrees apart, as above
    pitch = np.radians(3.0 - 3.5 * (np.arange(8) + 0.5))

    def at(row: int, x: float) -> list[float]:
        return [x, 0.0, x * np.tan(pitch[row])]

    # A van's side 10 m ahead: its ring in row 5 is on the object, rows 4 and 3 above it on the same face (0.65 and
    # 0.63 m higher; two rows' spacing at 10 m is 2 tan 3.5 * 10 = 1.22 m); a crown in row 0, 1.85 m over
    # row 3 (rows 1 and 2 empty); a ring in row 4 but 2 m farther (0.2 m up over 2 m: no face).
    van = np.array([at(5, 10.0), at(4, 10.0), at(3, 10.0), at(0, 10.0)], np.float32)
    assert pixel_index(van, sensor).v.tolist() == [5, 4, 3, 0]

    def joined(points: np.ndarray, rows: float) -> list[int]:
        point_object = np.array([0] + [-1] * (len(points) - 1), np.int32)
        attached = attach_over(points, np.arange(1, len(points)), point_object, sensor, 70.0, rows)
        assert attached.tolist() == [False] + [o >= 0 for o in point_object[1:]]
        return point_object.tolist()

    assert joined(van, 2.0) == [0, 0, 0, -1]  # ring by ring from the bottom; the crown rises too far
    assert joined(van, 4.0) == [0, 0, 0, 0]  # (with four rows' spacing allowed, 2.44 m, it would join)
    assert joined(np.array([at(5, 10.0), at(4, 12.0)], np.float32), 2.0) == [0, -1]


def test_a_cars_lowest_ring_joins_it_where_only_the_ground_farther_around_shows_it_clear_of_the_road():
    # A sensor of 64 rows 0.47 degrees apart, 1.73 m over a flat road. A car 24.3 m ahead: its face in rows 34-38
    # (0.44-1.23 m up); row 39 passes under its bumper and meets it 0.44 m behind the face, 0.21 m over the road
    # (27 degrees under row 38: not steep). The road shows up to 19.9 m: the car hides it behind, and row 39 is the
    # lowest return within two cells of it, its own local ground. Five cells around, the road is found.
    sensor = SensorConfig("column64", 64, 1024, 15.0, -15.0, 0.0, 100.0)
    pitch = np.radians(15.0 - 30.0 / 64 * (np.arange(64) + 0.5))
    y = np.arange(-0.8, 0.81, 0.15)

    def ring(row: int, x: float) -> np.ndarray:
        return np.column_stack([np.full(len(y), x), y, np.hypot(x, y) * np.tan(pitch[row])])

    face = np.vstack([ring(row, 24.3) for row in range(34, 39)])
    lowest = ring(39, 24.74)
    gx, gy = np.meshgrid(np.arange(4.0, 20.0, 0.5), np.arange(-8.0, 8.0, 0.5))
    road = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)])
    points = np.vstack([face, lowest, road]).astype(np.float32)
    f, n = len(face), len(lowest)
    assert pixel_index(points[f:f + n], sensor).v.tolist() == [39] * n
    assert np.allclose(points[f:f + n, 2] + 1.73, 0.21, atol=0.01)

    def lowest_ring(config: ObjectConfig) -> np.ndarray:
        found = find_objects(points, config, sensor=sensor)
        assert (found.point_object[:f] == found.point_object[0]).all() and found.point_object[0] >= 0
        assert (found.point_object[f + n:] == -1).all()  # the road stays the road
        assert (found.height_above_ground[f:f + n] < 0.01).all()  # its own local ground
        return found.point_object[f:f + n] == found.point_object[0]

    assert lowest_ring(ObjectConfig()).all()
    assert not lowest_ring(ObjectConfig(attach_under_radius=0)).any()  # the local ground alone: on no object
    assert not lowest_ring(ObjectConfig(attach_under_radius=2)).any()  # no wider than the local ground's window
    assert not lowest_ring(ObjectConfig(attach_under_wide_lift=0.25)).any()  # 0.21 m up: not clear of that


def test_a_sidewalk_ring_at_a_walkers_feet_stays_ground_and_his_foot_joins_him():
    # A sensor of 64 rows 0.47 degrees apart, 1.73 m over a road; a sidewalk 0.15 m higher where y <= 1 (the road's
    # within the local ground's 5 m: the sidewalk is 0.15 m over the local ground, clear of it). A walker stands on
    # it 8 m ahead (a front 0.3 m wide at x 7.8, 0.35-1.7 m up); every row meets the ground as a ring, round him.
    sensor = SensorConfig("column64", 64, 1024, 15.0, -15.0, 0.0, 100.0)
    pitch = np.radians(15.0 - 30.0 / 64 * (np.arange(64) + 0.5))
    yaw = np.radians(np.arange(-30.0, 30.0, 360 / 1024))
    rings = []
    for row in np.flatnonzero(pitch < np.radians(-3.0)):
        for drop, side in ((1.58, lambda y: y <= 1.0), (1.73, lambda y: y > 1.0)):
            r = drop / np.tan(-pitch[row])
            x, y = r * np.cos(yaw), r * np.sin(yaw)
            keep = side(y) & ((x - 8.0) ** 2 + y**2 > 0.2**2) & (r < 30.0)
            rings.append(np.column_stack([x[keep], y[keep], np.full(keep.sum(), -drop)]))
    ground = np.vstack(rings)
    front = np.array([[7.8, y, 7.8 * np.tan(p)] for p in pitch for y in np.arange(-0.15, 0.16, 0.06)
                      if 0.35 <= 7.8 * np.tan(p) + 1.73 <= 1.7])
    # His foot: 0.08 m over the sidewalk, 7.85 m out, in the row that meets the sidewalk 0.44 m behind it
    row = int(np.argmin(np.abs(7.85 * np.tan(pitch) + 1.58 - 0.08)))
    foot = np.array([[7.85, y, 7.85 * np.tan(pitch[row])] for y in (-0.05, 0.0, 0.05)])
    points = np.vstack([front, foot, ground]).astype(np.float32)
    f, n = len(front), len(foot)
    sidewalk_ring = np.flatnonzero((np.abs(points[:, 2] + 1.58) < 1e-3)
                                   & (np.hypot(points[:, 0] - 8.0, points[:, 1]) < 0.45))
    sidewalk_ring = sidewalk_ring[sidewalk_ring >= f + n]
    assert len(sidewalk_ring) >= 3

    def walker(config: ObjectConfig) -> tuple[np.ndarray, np.ndarray]:
        found = find_objects(points, config, sensor=sensor)
        him = found.point_object[0]
        assert him >= 0 and (found.point_object[:f] == him).all()
        return found.point_object[f:f + n] == him, found.point_object[sidewalk_ring] == him

    foot_joined, ring_joined = walker(ObjectConfig())
    assert foot_joined.all() and not ring_joined.any()
    foot_joined, ring_joined = walker(ObjectConfig(ring_ground=0.0))  # without the rule the ring joins him too
    assert foot_joined.all() and ring_joined.any()


def test_object_settings_that_count_cells_or_points_are_whole_numbers():
    for name in ("ground_radius", "attach_under_radius", "min_points", "ego_scans"):
        with pytest.raises(ConfigError, match=f"{name} must be a whole number"):
            ObjectConfig(**{name: 2.5})
    for name in ("attach_under_wide_lift", "ring_ground_range", "ring_ground_height"):
        for bad in (float("nan"), float("inf"), -0.1, 0.0):
            with pytest.raises(ConfigError, match=name):
                ObjectConfig(**{name: bad})
    for bad in (float("nan"), float("inf"), -0.1):
        with pytest.raises(ConfigError, match="ring_ground"):
            ObjectConfig(ring_ground=bad)
    with pytest.raises(ConfigError, match="attach_under_radius"):
        ObjectConfig(attach_under_radius=-1)


def test_find_objects_joins_a_vans_upper_ring_that_is_a_cluster_of_its_own():
    # A VLP-16 1.73 m up, a van's side 30 m ahead (1.9 m wide): rows 7 and 8 meet it 2.22 and 1.24 m above the road,
    # 0.98 m apart: two clusters of 0.4 m voxels. The lower ring is an object; the upper one stands 2.22 m off the
    # ground (max_bottom 1.5) and is none: it joins the object under it in its columns, by label.
    sensor = SensorConfig("vlp16", 16, 1024, 15.0, -15.0, 0.0, 100.0)
    elevation = np.radians(15.0 - 30.0 / 16 * (np.array([7, 8]) + 0.5))
    azimuth = np.radians(np.arange(-1.8, 1.85, 360 / 1024))
    y = 30.0 * np.tan(azimuth)
    van = np.vstack([np.column_stack([np.full(len(y), 30.0), y, np.hypot(30.0, y) * np.tan(e)]) for e in elevation])
    gx, gy = np.meshgrid(np.arange(4.0, 29.0, 0.5), np.arange(-8.0, 8.0, 0.5))
    road = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)])
    points = np.vstack([van, road]).astype(np.float32)
    n = len(y)
    assert pixel_index(points[:2 * n], sensor).v.tolist() == [7] * n + [8] * n
    found = find_objects(points, sensor=sensor)
    upper, lower = found.point_object[:n], found.point_object[n:2 * n]
    assert (lower >= 0).all() and (upper == lower).all() and found.attached[:n].all()
    assert not found.attached[n:2 * n].any() and found.counts.sum() == n  # by label: not the object's own points
    alone = find_objects(points, ObjectConfig(attach_raised=False), sensor=sensor)
    assert (alone.point_object[:n] == -1).all() and (alone.point_object[n:2 * n] >= 0).all()


def test_in_the_blind_spot_the_ground_is_the_plane_fitted_beyond_it():
    # A VLP-16 1.73 m up on a road rising 5 % along x: its lowest beam (-15 degrees) meets the road 6.5 m out; a car
    # 3 m to its side shows it a band 0.8-0.95 m up, and nothing lower nearby: its lowest ring is the local ground.
    sensor = SensorConfig("vlp16", 16, 1024, 15.0, -15.0, 0.0, 100.0)
    rng = np.random.default_rng(2)
    r, a = rng.uniform(6.6, 25.0, 6000), rng.uniform(-np.pi, np.pi, 6000)
    x, y = r * np.cos(a), r * np.sin(a)
    road = np.column_stack([x, y, -1.73 + 0.05 * x])
    cx, cy = rng.uniform(-1.0, 1.0, 400), rng.uniform(3.0, 3.4, 400)
    car = np.column_stack([cx, cy, -1.73 + 0.05 * cx + rng.uniform(0.8, 0.95, 400)])
    points = np.vstack([road, car]).astype(np.float32)
    ground = local_ground(points, 1.0, 2, 1.5)
    assert (points[6000:, 2] - ground[6000:]).min() < 0.05  # without the plane: the car's lowest ring is ground
    floor = blind_floor(points, ground, sensor, 6.0, 0.3)
    # The road's plane, rising with x, as low as the local ground is on a slope (its 5 m window's lowest point)
    off = floor[6000:] - (-1.73 + 0.05 * cx)
    assert off.max() < 0.02 and off.min() > -0.2
    beyond = r > 7.5  # beyond the blind radius (6.5-7 m, from the local ground's median): as it was
    assert (floor[:6000][beyond] == ground[:6000][beyond]).all()
    config = ObjectConfig(ego_radius=0.0, attach_steep=0.0)
    with_plane = find_objects(points, config, sensor=sensor)  # blind_floor on by default
    without = find_objects(points, dataclasses.replace(config, blind_floor=False), sensor=sensor)
    assert (with_plane.point_object[6000:] >= 0).mean() > 0.9 and (with_plane.point_object[:6000] < 0).mean() > 0.99
    assert (without.point_object[6000:] >= 0).mean() < 0.5


def test_the_online_model_s_moving_points_on_no_object_and_apart_from_objects_make_objects_unless_on_the_road():
    # A sensor of 64 rows 0.47 degrees apart, 1.73 m over a flat road (the road a grid of returns, static).
    sensor = SensorConfig("column64", 64, 1024, 15.0, -15.0, 0.0, 100.0)
    y = np.linspace(-0.8, 0.8, 11)

    def grid(x0: float, y0: float) -> np.ndarray:  # the road around (x0, y0), 0.5 m apart, between its rings
        gx, gy = np.meshgrid(np.arange(x0 - 2.25, x0 + 2.5, 0.5), np.arange(y0 - 2.25, y0 + 2.5, 0.5))
        return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)])

    parts = {
        "object": np.column_stack([np.full(20, 10.0), np.linspace(-1, 1, 20), np.linspace(-1.2, -0.3, 20)]),
        "far car ring": np.column_stack([np.full(11, 35.0), y, np.full(11, -1.33)]),  # 0.4 m over the road
        "road around it": grid(35.0, 0.0),
        "road ring": np.column_stack([np.full(11, 15.0), y + 6.0, np.full(11, -1.73)]),  # a piece of the road
        "road around that": grid(15.0, 6.0),
        "beside the object": np.column_stack([np.full(8, 11.5), np.linspace(-0.5, 0.5, 8), np.full(8, -0.8)]),
        "too few": np.column_stack([np.full(5, 50.0), np.linspace(9.8, 10.2, 5), np.full(5, -1.0)]),
        "static": np.column_stack([np.full(10, 40.0), np.linspace(-10.5, -9.5, 10), np.full(10, -1.0)]),
    }
    points = np.vstack(list(parts.values())).astype(np.float32)
    at = np.cumsum([0] + [len(p) for p in parts.values()])
    part = {name: slice(at[i], at[i + 1]) for i, name in enumerate(parts)}
    rows = pixel_index(points, sensor).v
    assert not np.isin(rows[part["road around it"]], rows[part["far car ring"]]).all()  # other rings around
    moving = np.zeros(len(points), bool)
    for name in ("far car ring", "road ring", "beside the object", "too few"):
        moving[part[name]] = True
    point_object = np.full(len(points), -1, np.int32)
    point_object[part["object"]] = 0
    n = len(points)
    found = ScanObjects(point_object, np.array([20]), np.zeros(n, bool), np.zeros(n, np.float32), np.zeros(n, bool))

    out = moving_clusters(points, found, moving, ObjectConfig(), lift=0.15, apart=2.0, sensor=sensor)
    assert out.n_objects == 2 and out.counts.tolist() == [20, 11]
    assert (out.point_object[part["far car ring"]] == 1).all()  # an object of its own, to be tracked
    for name in ("road around it", "road ring", "road around that", "beside the object", "too few", "static"):
        assert (out.point_object[part[name]] == -1).all(), name
    assert (out.point_object[part["object"]] == 0).all() and found.point_object[part["far car ring"]].max() == -1
    # The road ring's neighbours in other rings lie at its height: with them taken away it stands alone, an object
    alone = np.ones(n, bool)
    alone[part["road around that"]] = False
    m = int(alone.sum())
    kept = ScanObjects(point_object[alone], np.array([20]), np.zeros(m, bool), np.zeros(m, np.float32),
                       np.zeros(m, bool))
    lonely = moving_clusters(points[alone], kept, moving[alone], ObjectConfig(), lift=0.15, apart=2.0, sensor=sensor)
    assert lonely.n_objects == 3
    # 0.4 m over the road around it: not with a lift of 0.5 m; beside the object: with no distance asked for
    assert moving_clusters(points, found, moving, ObjectConfig(), lift=0.5, apart=2.0, sensor=sensor).n_objects == 1
    near = moving_clusters(points, found, moving, ObjectConfig(), lift=0.15, apart=0.0, sensor=sensor)
    assert near.n_objects == 3 and (near.point_object[part["beside the object"]] >= 1).all()
    assert moving_clusters(points, found, np.zeros(n, bool), ObjectConfig(), 0.15, 2.0, sensor) is found
    # Only where the sensor's rows lie far enough apart: 0.47 degrees, 0.25 m at 30.6 m, 0.5 m at 61 m
    assert moving_clusters(points, found, moving, ObjectConfig(), 0.15, 2.0, sensor, spacing=0.25).n_objects == 2
    assert moving_clusters(points, found, moving, ObjectConfig(), 0.15, 2.0, sensor, spacing=0.5) is found


def test_points_on_no_object_that_the_online_model_labels_moving_take_the_nearest_object_s_label_within_reach():
    points = np.array([
        [10.05, 0.05, 0.5], [10.05, 1.05, 0.5],  # object 0
        [20.05, 0.05, 0.5],  # object 1
        [11.55, 0.05, -1.5],  # moving, 1.5 m from object 0 seen from above (1.5 m lower): object 0
        [11.55, 1.05, 0.0],  # as close, labelled static: none
        [13.05, 0.05, 0.0],  # moving, 3.0 m from object 0 and 7.0 m from object 1: none
        [18.55, 0.05, 0.0],  # moving, 1.5 m from object 1, 8.5 m from object 0: object 1
        [15.05, 0.05, 0.0],  # moving, 5.0 m from both: none
    ], np.float32)
    point_object = np.array([0, 0, 1, -1, -1, -1, -1, -1], np.int32)
    moving = np.array([False, True, True, True, False, True, True, True])
    out = label_objects(points, point_object, moving, 2.0)
    assert out.tolist() == [0, 0, 1, 0, -1, -1, 1, -1]
    assert point_object.tolist() == [0, 0, 1, -1, -1, -1, -1, -1]  # the objects themselves stay as they were
    assert label_objects(points, point_object, moving, 4.0).tolist() == [0, 0, 1, 0, -1, 0, 1, -1]  # 3.0 m, not 5.0
    assert label_objects(points, point_object, np.zeros(8, bool), 2.0).tolist() == point_object.tolist()
    with pytest.raises(ValueError, match="reach"):
        label_objects(points, point_object, moving, float("nan"))


def test_neighbourhood_min_takes_rows_pm1_and_columns_pm2_with_wrap():
    img = np.full((3, 8), 10.0, np.float32)
    img[1, 0] = 2.0
    out = neighbourhood_min(img, columns=2)
    assert out[0, 7] == 2.0 and out[2, 2] == 2.0 and out[1, 3] == 10.0 and out[1, 6] == 2.0


def test_objects_keep_a_car_and_drop_a_building_and_the_ground():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-30, 30, 4000), rng.uniform(-30, 30, 4000), np.zeros(4000)])
    car = np.column_stack([rng.uniform(5, 9.5, 800), rng.uniform(2, 3.8, 800), rng.uniform(0.3, 1.5, 800)])
    wheels = np.column_stack([rng.uniform(5, 9.5, 50), rng.uniform(2, 3.8, 50), np.full(50, 0.15)])
    building = np.column_stack([rng.uniform(-25, 25, 20000), np.full(20000, -20.0), rng.uniform(0, 12, 20000)])
    pts = np.vstack([ground, car, wheels, building]).astype(np.float32)
    found = find_objects(pts)
    car_ids = set(found.point_object[4000:4800].tolist())
    assert len(car_ids) == 1 and car_ids != {-1}
    assert (found.point_object[:4000] == -1).mean() > 0.99  # ground
    assert (found.point_object[4800:4850] == next(iter(car_ids))).mean() > 0.9  # wheels attached under the car
    assert found.attached[4800:4850].mean() > 0.9 and not found.attached[4000:4800].any()
    assert (found.point_object[4850:] == -1).all()  # 12 m high: not an object ...
    wall = pts[4850:, 2] > 1.0  # (its foot lies in the ground and in pieces of its own)
    assert found.structure[4850:][wall].all() and not found.structure[:4850].any()  # ... but a structure (a wall)
    # A stray return 50 km away (a reflection, a bad driver) changes nothing and is ground: the ground grid covers
    # only what lies within max_range of the sensor (with the stray in it, the grid would be 50 km long).
    stray = find_objects(np.vstack([pts, [[50_000.0, 0.0, 3.0]]]).astype(np.float32))
    assert (stray.point_object[:-1] == found.point_object).all() and stray.point_object[-1] == -1
    assert stray.height_above_ground[-1] == 0.0


def test_a_far_car_seen_as_six_returns_is_an_object_and_five_returns_are_not():
    # A sparse sensor sees a car 40 m away as two short ring pieces (benchmarks/autolabel.md, round 44: min_points 6)
    rng = np.random.default_rng(1)
    ground = np.column_stack([rng.uniform(30, 50, 3000), rng.uniform(-10, 10, 3000), np.zeros(3000)])
    car = np.array([[40.0, y, z] for z in (0.6, 1.0) for y in (0.0, 0.3, 0.6)])
    for returns, object_expected in ((6, True), (5, False)):
        found = find_objects(np.vstack([ground, car[:returns]]).astype(np.float32))
        ids = set(found.point_object[3000:].tolist())
        assert (len(ids) == 1 and ids != {-1}) if object_expected else ids == {-1}
        assert (found.point_object[:3000] == -1).all()


def test_a_car_90_m_away_is_an_object_within_max_range_and_none_beyond_it():
    # A 64-beam sensor sees a car 60-100 m away as a few rings (HDL-64E validation drives: movers beyond 60 m were
    # missed while the object finder stopped there; benchmarks/autolabel.md, round 50)
    rng = np.random.default_rng(2)
    ground = np.column_stack([rng.uniform(80, 100, 3000), rng.uniform(-10, 10, 3000), np.full(3000, -1.73)])
    car = np.array([[90.0, y, z - 1.73] for z in (0.5, 0.8, 1.1) for y in np.linspace(-0.9, 0.9, 8)])
    pts = np.vstack([ground, car]).astype(np.float32)
    ids = set(find_objects(pts).point_object[3000:].tolist())
    assert len(ids) == 1 and ids != {-1}
    assert set(find_objects(pts, ObjectConfig(max_range=85.0)).point_object[3000:].tolist()) == {-1}


def test_kerbs_flat_rings_low_down_and_the_sensor_s_own_vehicle_are_no_objects_but_a_van_beside_it_is():
    rng = np.random.default_rng(1)
    ground = np.column_stack([rng.uniform(-30, 30, 4000), rng.uniform(-30, 30, 4000), np.zeros(4000)])
    car = np.column_stack([rng.uniform(5, 9.5, 800), rng.uniform(2, 3.8, 800), rng.uniform(0.35, 1.5, 800)])
    kerb = np.column_stack([rng.uniform(-10, 25, 700), rng.uniform(3.9, 4.2, 700), np.full(700, 0.25)])
    ring = np.column_stack([np.linspace(12, 16, 60), np.full(60, -6.0), np.linspace(0.4, 0.45, 60)])  # one beam
    # one beam across a car's body 0.9 m up, all a 16-beam sensor sees of a car 20 m away
    body = np.column_stack([np.linspace(-20, -16, 40), np.full(40, 10.0), np.linspace(0.9, 0.95, 40)])
    # returns from the sensor's own vehicle, 1.4 m away and 0.5 m below the sensor
    own = np.column_stack([np.linspace(-0.8, -0.4, 30), np.full(30, -1.3), np.linspace(1.0, 1.15, 30)])
    pts = np.vstack([ground, car, kerb, ring, body, own]).astype(np.float32)
    # a van passing 1.8 m beside the sensor, in 2 of the drive's 10 scans
    van = np.column_stack([rng.uniform(-2, 2, 300), rng.uniform(1.8, 1.9, 300), rng.uniform(0.4, 2.0, 300)])
    vehicle = VehicleReturns(ObjectConfig())
    for k in range(10):
        jitter = rng.normal(0, 0.02, own.shape)
        vehicle.add(np.vstack([ground, own + jitter] + ([van] if k < 2 else [])).astype(np.float32), _at(k))
    pts = np.vstack([ground, car, kerb, ring, body, own, van]).astype(np.float32)
    found = find_objects(pts, vehicle=vehicle.cells())
    car_ids = set(found.point_object[4000:4800].tolist())
    assert len(car_ids) == 1 and car_ids != {-1}
    kerb_ids = found.point_object[4800:5500]
    assert (kerb_ids[np.abs(pts[4800:5500, 0] - 7.25) > 3] == -1).all()  # the kerb along the street is no object
    assert (found.point_object[5500:5560] == -1).all()  # a cluster flatter than min_height, low, is no object
    assert len(set(found.point_object[5560:5600].tolist()) - {-1}) == 1  # up on a body it is one
    assert (found.point_object[5600:5630] == -1).all()  # the sensor's own vehicle is none ...
    assert len(set(found.point_object[5630:].tolist()) - {-1}) == 1  # ... what passes beside it is one
    assert (find_objects(pts).point_object[5600:5630] >= 0).all()  # (without the drive's vehicle cells: one)


def _at(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def test_vehicle_returns_are_the_cells_near_the_sensor_held_in_most_scans_while_it_travels():
    config = ObjectConfig(ego_radius=3.0, ego_cell=0.25, ego_share=0.5, ego_travel=0.5, ego_scans=8)
    vehicle = VehicleReturns(config)
    mirror = np.array([[1.1, -1.3, 1.05]], np.float32)  # cell (4, -6, 4)
    for k in range(20):
        passing = [[1.6, 0.1, 0.3]] if k < 8 else []  # 4 of the 10 scans counted: under ego_share
        far = [[3.1, 0.0, 0.0]]  # beyond ego_radius (seen from above), in every scan
        vehicle.add(np.array([*mirror.tolist(), *passing, *far], np.float32), _at(0.3 * k))  # every 2nd counted
    assert vehicle.scans == 10
    cells = vehicle.cells()
    assert len(cells) == 27  # the mirror's cell and its 26 neighbours
    probe = np.array([[1.1, -1.3, 1.05], [1.3, -1.3, 1.05], [1.1, -1.05, 0.8], [1.6, -1.3, 1.05],
                      [1.6, 0.1, 0.3], [3.1, 0.0, 0.0]], np.float32)
    # its cell, one cell up in x (5, -6, 4), one diagonal (4, -5, 3); two cells away (6, -6, 4); the passer-by; far
    assert on_vehicle(probe, cells, ObjectConfig()).tolist() == [True, True, True, False, False, False]
    off = VehicleReturns(ObjectConfig(ego_radius=0.0))
    off.add(mirror, _at(0.0))
    assert len(off.cells()) == 0
    # standing (a jam): the car beside the sensor holds its cell in every scan, but no scan after the first counts
    standing = VehicleReturns(config)
    for k in range(50):
        standing.add(np.array([[0.5, 2.0, 0.0], *mirror.tolist()], np.float32), _at(0.01 * k))
    assert standing.scans == 1 and len(standing.cells()) == 0  # 0.49 m in all


def test_config_is_checked():
    from ros2_mos.offline.tracks import TrackConfig

    for bad in ({"near_offsets": (0,)}, {"instant_seen_through": 0.0}, {"instant_seen_through": float("nan")},
                {"instant_seen_through": 1.5}, {"instant_speed": float("inf")}, {"support_margin": -0.1},
                {"odometry_margin": float("nan")}, {"odometry_margin_share": -0.01}, {"odometry_prefer": "b"},
                {"instant_motion": "speed"}, {"cue_attach": -1.0}, {"cue_attach": float("nan")},
                {"cue_attach": float("inf")}, {"deskew": "yes"}, {"deskew": True}, {"processes_from": -1},
                {"process_lead": float("nan")}):
        with pytest.raises(ConfigError):
            AutolabelConfig(**bad)
    for bad in ({"processes_from": 2.5}, {"process_lead": True}):
        with pytest.raises(ConfigError, match="must be a whole number"):
            AutolabelConfig(**bad)
    assert AutolabelConfig().in_processes(50) and not AutolabelConfig().in_processes(49)
    assert not AutolabelConfig(processes_from=0).in_processes(10**6)
    for cls, bad in ((ObjectConfig, {"voxel": 0.0}), (ObjectConfig, {"max_range": float("nan")}),
                     (ObjectConfig, {"ego_share": 1.5}), (ObjectConfig, {"ego_cell": 0.0}),
                     (ObjectConfig, {"attach_distance": 0.0}), (ObjectConfig, {"attach_steep": 95.0}),
                     (ObjectConfig, {"attach_steep": float("nan")}), (ObjectConfig, {"blind_ring": -1.0}),
                     (TrackConfig, {"gate": -1.0}), (TrackConfig, {"seen_through": 2.0})):
        with pytest.raises(ConfigError):
            cls(**bad)
    # zero where zero means something
    AutolabelConfig(support_margin=0.0, cue_attach=0.0, processes_from=0, process_lead=0,
                    objects=ObjectConfig(attach_above=0.0, ego_radius=0.0, attach_steep=0.0))


def test_box_shift_counts_only_what_both_edges_agree_on():
    lo, hi = np.array([[0.0, 0.0]]), np.array([[4.0, 2.0]])
    cases = [  # (lo1, hi1, expected): rigid move; grown on one side; moved and grown; grown both ways; shrunk
        ((1.0, 0.5), (5.0, 2.5), (1.0, 0.5)),
        ((0.0, 0.0), (5.0, 2.0), (0.0, 0.0)),
        ((1.0, -0.2), (6.0, -0.5), (1.0, -0.2)),
        ((-0.5, -0.3), (4.5, 2.3), (0.0, 0.0)),
        ((0.5, 0.0), (4.0, 1.0), (0.0, 0.0)),
    ]
    for lo1, hi1, expected in cases:
        got = box_shift(lo, hi, np.array([lo1]), np.array([hi1]))
        np.testing.assert_allclose(got, [expected])


def test_an_edge_the_vehicles_shadow_cut_does_not_count_in_a_boxs_shift():
    # the rear half of a bus alongside in a jam: its front edge pinned at the shadow (x -1.1 -> -1.1) while its rear
    # edge comes on 0.6 m (-9.9 -> -9.3)
    lo0, hi0 = np.array([[-9.9, 2.3]]), np.array([[-1.1, 2.3]])
    lo1, hi1 = np.array([[-9.3, 2.3]]), np.array([[-1.1, 2.3]])
    np.testing.assert_allclose(box_shift(lo0, hi0, lo1, hi1), [[0.0, 0.0]])  # one edge moved: nothing
    cut_lo, cut_hi = np.array([[False, False]]), np.array([[True, False]])
    np.testing.assert_allclose(box_shift(lo0, hi0, lo1, hi1, cut_lo, cut_hi), [[0.6, 0.0]])  # the rear edge's move
    both = np.array([[True, False]])  # both x edges cut: nothing along x; y as before
    np.testing.assert_allclose(box_shift(lo0, hi0, lo1 + 1.0, hi1 + 1.0, both, both), [[0.0, 1.0]])


def test_the_edge_where_the_vehicles_shadow_cuts_an_object_lies_at_the_blind_radius():
    from ros2_mos.offline.autolabel import SHADOW_MARGIN, blind_radius, edge_reach

    # the sensor at the origin; 30 returns 2.55 m out behind it (the blind radius: the 21st nearest, on no object)
    angle = np.radians(np.linspace(-170.0, -100.0, 30))
    ring = np.column_stack([2.55 * np.cos(angle), 2.55 * np.sin(angle), np.zeros(30)])
    # object 0: the rear half of a bus 2.3 m to the left, x -9.9 .. -1.1, cut by the shadow at x -1.1 (range 2.56)
    xs = np.round(np.arange(-9.9, -1.05, 0.1), 6)
    bus = np.column_stack([xs, np.full(len(xs), 2.3), np.zeros(len(xs))])
    # object 1: a parked car's side 2.6 m to the right, x -2 .. 2: its nearest point (2.6 m) lies in its middle
    xs = np.round(np.arange(-2.0, 2.05, 0.1), 6)
    car = np.column_stack([xs, np.full(len(xs), -2.6), np.zeros(len(xs))])
    points = np.vstack([ring, bus, car])
    ranges = np.linalg.norm(points, axis=1)
    assert blind_radius(ranges) == pytest.approx(2.55)
    assert blind_radius(ranges[:20]) == np.inf
    world = points[30:] + [100.0, 50.0, 0.0]  # the world frame: only the ranges come from the sensor's
    obj = np.r_[np.zeros(len(bus), np.int64), np.ones(len(car), np.int64)]
    lo = np.array([world[obj == j].min(axis=0) for j in (0, 1)])
    hi = np.array([world[obj == j].max(axis=0) for j in (0, 1)])
    reach = edge_reach(ranges[30:], world, obj, lo, hi)
    # by hand: the bus's upper x edge: its 2 points x -1.2, -1.1 (within 0.15 m); 90 % of 2: the 2nd nearest,
    # hypot(1.2, 2.3) = 2.594; its side (y 2.3, both y edges): 90 % of its 89 points, the 81st nearest (x -9.1); the
    # car's side (y -2.6): 90 % of its 41 points, the 37th nearest, hypot(1.8, 2.6) = 3.162
    assert reach[0, 1, 0] == pytest.approx(np.hypot(1.2, 2.3), abs=1e-6)
    assert reach[0, 0, 1] == reach[0, 1, 1] == pytest.approx(np.hypot(9.1, 2.3), abs=1e-6)
    assert reach[1, 1, 1] == pytest.approx(np.hypot(1.8, 2.6), abs=1e-6)
    cut = reach <= blind_radius(ranges) + SHADOW_MARGIN  # within 2.65 m
    assert cut.tolist() == [[[False, False], [True, False]], [[False, False], [False, False]]]


def test_a_track_does_not_jump_onto_an_object_many_times_its_size():
    from ros2_mos.offline.tracks import Observation, TrackConfig, Tracker

    def obs(scan: int, x: float, size: tuple[float, float]) -> Observation:
        centre = np.array([x, 3.0, 0.8])
        half = np.array([size[0] / 2, size[1] / 2, 0.7])
        return Observation(scan, 0, centre, 100, centre - half, centre + half, 0.0, 0.0)

    # a 2 x 0.8 m mover at 5 m/s, then, where it would be next, a 16 x 9 m hedge (area ratio 90)
    scans = [[obs(0, 0.0, (2.0, 0.8))], [obs(1, 0.5, (2.0, 0.8))], [obs(2, 1.2, (16.0, 9.0))]]
    for ratio, tracks in ((4.0, 2), (1e9, 1)):
        tracker = Tracker(TrackConfig(max_area_ratio=ratio))
        for k, observations in enumerate(scans):
            tracker.add_scan(k, 0.1 * k, 0.1 * (k - 1) if k else None, observations)
        assert len(tracker.tracks) == tracks
    # a car coming into view, its box growing 2.5x in a scan, stays one track
    tracker = Tracker(TrackConfig())
    for k, length in enumerate((1.0, 2.5, 4.5)):
        tracker.add_scan(k, 0.1 * k, 0.1 * (k - 1) if k else None, [obs(k, 0.3 * k, (length, 1.8))])
    assert len(tracker.tracks) == 1
    with pytest.raises(ConfigError, match="max_area_ratio"):
        TrackConfig(max_area_ratio=0.5)


def test_a_car_that_moved_near_then_waited_far_away_is_a_mover_by_what_it_did_near():
    from ros2_mos.offline.tracks import Observation, Track, TrackConfig, Tracker

    # HDL-64E suite easy-9301: a car drives away behind the sensor, seen through in its first 5 observations 33-39 m
    # away (1 m of box travel: too little to count on its own), then waits 56-98 m away for 60 scans, where no scan
    # can see through where it was. Within 60 m the share of seen-through observations holds (5 of 20); counting the
    # far observations as well, it does not (5 of 80).
    def obs(k: int, seen: bool) -> Observation:
        centre = np.array([-33.0 - 0.25 * min(k, 4), 3.5, 0.8])
        distance = 33.0 + 1.5 * k if k < 20 else 56.0 + 0.7 * (k - 20)
        share = 0.4 if seen else 0.0
        return Observation(k, 0, centre, 60, centre - [0.5, 0.8, 0.8], centre + [0.5, 0.8, 0.8], share, share,
                           distance=distance)

    def track(seen: set[int]) -> Track:
        return Track(0, [obs(k, k in seen) for k in range(80)])

    def mover(seen: set[int], config: TrackConfig = TrackConfig()) -> bool:
        tracker = Tracker(config)
        tracker.tracks = [track(seen)]
        return tracker.seen_moving(tracker.tracks[0])

    assert mover({0, 1, 2, 3, 4}) and not mover({0, 1, 2, 3, 4}, TrackConfig(evidence_range=1000.0))
    # A far observation that is evidence counts: 2 of the 20 near ones seen through and 4 of the far ones, 6 of 24
    assert mover({0, 4, 20, 30, 40, 50}) and not mover({0, 4})
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="evidence_range"):
            TrackConfig(evidence_range=bad)


def box_observation(scan: int, lo: tuple[float, float], hi: tuple[float, float], far: float, top: float = 1.6):
    """An observation of 100 points whose world box stands on z 0 up to ``top``, seen through by ``far``."""
    from ros2_mos.offline.tracks import Observation

    lo3, hi3 = np.array([*lo, 0.0]), np.array([*hi, top])
    return Observation(scan, 0, (lo3 + hi3) / 2, 100, lo3, hi3, far, far)


def follow_scans(observations: list, config=None):
    """A tracker fed every scan up to the last observation's (10 a second), also those where the track was missed."""
    from ros2_mos.offline.tracks import TrackConfig, Tracker

    tracker = Tracker(config or TrackConfig())
    for k in range(observations[-1].scan + 1):
        tracker.add_scan(k, 0.1 * k, 0.1 * (k - 1) if k else None, [o for o in observations if o.scan == k])
    return tracker


def test_a_track_is_cut_where_it_jumps_from_a_pedestrian_onto_the_parked_car_he_walked_past():
    from ros2_mos.offline.tracks import TrackConfig

    obs, follow = box_observation, follow_scans

    # VLP-16 unseen6 narrow_street-10211: a pedestrian walks along y -2.0..-1.5 at 3 m/s, seen through, and is hidden
    # for scans 11 and 12; at scan 13 the tracker takes on the first glimpse of the parked car he walks past, 0.3 m
    # beside his last box (y -2.6..-2.3), and follows the car, never seen through, as it comes into view (its box
    # grows 0.5 m a scan) and for the rest of the drive.
    walker = [obs(k, (-5.5 + 0.3 * k, -2.0), (-5.0 + 0.3 * k, -1.5), 0.9) for k in range(11)]
    car = [obs(k, (-2.0, max(-2.6 - 0.3 * (k - 13), -3.7)), (min(-1.6 + 0.5 * (k - 13), 2.6), -2.3), 0.0)
           for k in range(13, 40)]
    tracker = follow(walker + car)
    assert len(tracker.tracks) == 1  # the gate (1.5 m around the prediction) and the size ratio let the jump through
    assert tracker.cut_jumps() == 1
    assert [len(t.observations) for t in tracker.tracks] == [11, 27]
    assert tracker.track_of[(13, 0)] == tracker.track_of[(39, 0)] == 1 and tracker.track_of[(10, 0)] == 0
    assert tracker.movers() == {0: "seen through"}  # the car is no mover, and so not moving in any scan
    # Not cut by the gap rule: the same jump without a missed scan (the car's glimpse at scan 11; the halt rule, tested
    # below, off), or onto a box that overlaps the last one (grown by jump_margin: 0.35 m instead of 0.2), or with
    # jump_gap 0
    glimpse = [obs(k, c.lo[:2], c.hi[:2], 0.0) for k, c in zip(range(11, 40), car)]
    assert follow(walker + glimpse, TrackConfig(jump_speed=0.0)).cut_jumps() == 0
    assert follow(walker + car, TrackConfig(jump_margin=0.35, jump_speed=0.0)).cut_jumps() == 0
    assert follow(walker + car, TrackConfig(jump_gap=0, jump_speed=0.0)).cut_jumps() == 0
    # (the halt rule cuts each of them: he walked 3 m/s until scan 10, the car stood from scan 13 on, 2 times his size)
    assert follow(walker + glimpse).cut_jumps() == 1 and follow(walker + car, TrackConfig(jump_gap=0)).cut_jumps() == 1
    # Not cut: a pedestrian who stops where he was hidden (his box overlaps his last one), or whose evidence goes on
    stops = walker + [obs(k, (-2.5, -2.0), (-2.0, -1.5), 0.0) for k in range(13, 40)]
    assert follow(stops).cut_jumps() == 0
    assert follow(walker + [obs(k, c.lo[:2], c.hi[:2], 0.9 if k < 15 else 0.0) for k, c in zip(range(13, 40), car)]
                  ).cut_jumps() == 0
    # ... and the other way round: a parked car's track, down to a stub as the sensor passes it, that takes on a
    # pedestrian who walks off from beside its end; but not a post's that takes him on (the same size as he)
    parked = [obs(k, (-2.0 + 0.8 * max(k - 14, 0), -3.7), (2.6, -2.1), 0.0) for k in range(20)]
    walks_off = [obs(k, (2.9 + 0.3 * (k - 22), -2.0), (3.4 + 0.3 * (k - 22), -1.5), 0.9) for k in range(22, 30)]
    tracker = follow(parked + walks_off)
    assert len(tracker.tracks) == 1 and tracker.cut_jumps() == 1
    post = [obs(k, (2.6, -2.0), (2.9, -1.7), 0.0) for k in range(20)]
    tracker = follow(post + walks_off)
    assert len(tracker.tracks) == 1 and tracker.cut_jumps() == 0
    # ... nor a pedestrian who waited, then walked off while hidden (0.4 m on from where he stood): one size
    waits = [obs(k, (0.0, -2.0), (0.5, -1.5), 0.0) for k in range(20)]
    walks = [obs(k, (0.9 + 0.15 * (k - 22), -2.0), (1.4 + 0.15 * (k - 22), -1.5), 0.9) for k in range(22, 40)]
    tracker = follow(waits + walks)
    assert len(tracker.tracks) == 1 and tracker.cut_jumps() == 0 and tracker.movers() == {0: "seen through"}
    tracker = follow(parked + walks_off)
    tracker.cut_jumps()
    assert tracker.movers() == {1: "seen through"}
    for bad in (-1, float("nan")):
        with pytest.raises(ConfigError, match="jump_gap"):
            TrackConfig(jump_gap=bad)
    with pytest.raises(ConfigError, match="jump_margin"):
        TrackConfig(jump_margin=float("inf"))


def test_a_track_is_cut_where_a_cyclist_seen_through_halts_within_a_scan_onto_the_parked_car_he_rides_past():
    from ros2_mos.offline.tracks import TrackConfig

    obs, follow = box_observation, follow_scans

    # VLP-32C unseen4 narrow_street-10013: a cyclist rides along y -1.9..-1.5 at 5.5 m/s, seen through (1.0 x 0.4 m;
    # footprint 1.0 x 0.5, each side at least 0.5 m), and merges with the parked car he passes; from scan 20 the track
    # follows the car, never seen through, as it comes into view: its box grows 0.5 m a scan along x and 0.2 m across,
    # one edge at a time (it stands: 0 m/s by both edges). The cyclist's last three boxes moved 1.1 m in 0.2 s: 5.5
    # m/s, the car's first three 0; the car's median footprint over its first five (1.0, 1.8, 2.8, 4.0, 5.4 m^2) is
    # 2.8, 5.6 times the cyclist's 0.5.
    rides = [obs(k, (32.0 + 0.55 * k, -1.9), (33.0 + 0.55 * k, -1.5), 0.9) for k in range(20)]
    car = [obs(k, (44.5, max(-2.6 - 0.2 * (k - 20), -3.9)), (min(45.5 + 0.5 * (k - 20), 49.5), -1.6), 0.0)
           for k in range(20, 40)]
    tracker = follow(rides + car)
    assert len(tracker.tracks) == 1  # no scan missed, the gate and the size ratio let it through
    steady = np.stack([0.5 * np.arange(40.0), np.zeros(40)], axis=1)  # the sensor drives on at 5 m/s
    assert tracker.cut_jumps(0.1 * np.arange(40), steady) == 1
    assert [len(t.observations) for t in tracker.tracks] == [20, 20]
    assert tracker.movers() == {0: "seen through"}  # the car is no mover
    # Not cut where the poses say the sensor halted with it (5 m/s, then standing from scan 20: the odometry slipped)
    slipped = steady.copy()
    slipped[20:] = slipped[19]
    assert follow(rides + car).cut_jumps(0.1 * np.arange(40), slipped) == 0
    assert follow(rides + car, TrackConfig(jump_sensor=6.0)).cut_jumps(0.1 * np.arange(40), slipped) == 1
    # Not cut: slower than jump_speed (5.5 < 6), standing faster than jump_still (the car's box carried 0.1 m a scan:
    # 1.0 m/s), what stands under jump_area times what moved (2.8 < 6 x 0.5), or with jump_speed 0
    assert follow(rides + car, TrackConfig(jump_speed=6.0)).cut_jumps() == 0
    creeps = [obs(o.scan, tuple(o.lo[:2] + [0.1 * (o.scan - 20), 0.0]), tuple(o.hi[:2] + [0.1 * (o.scan - 20), 0.0]),
                  0.0) for o in car]
    assert follow(rides + creeps).cut_jumps() == 0
    assert follow(rides + car, TrackConfig(jump_area=6.0)).cut_jumps() == 0
    assert follow(rides + car, TrackConfig(jump_speed=0.0)).cut_jumps() == 0
    # ... nor a cyclist who stops where he is (his own box stands: one size), though no scan sees through him then
    stops = [obs(k, (43.0, -1.9), (44.0, -1.5), 0.0) for k in range(20, 40)]
    assert follow(rides + stops).cut_jumps() == 0
    # Not the other way round: a standing track that goes on as a cyclist riding off at 5.5 m/s is also what a mover
    # merged with the static points around it makes as it drives out of them (real r1: an oncoming car's first 5
    # scans, most of whose points were the car's)
    backwards = [obs(39 - o.scan, tuple(o.lo[:2]), tuple(o.hi[:2]), o.far) for o in reversed(rides + car)]
    tracker = follow(backwards)
    assert len(tracker.tracks) == 1 and tracker.cut_jumps() == 0
    for name, bad in (("jump_speed", -1.0), ("jump_still", float("nan")), ("jump_area", 0.5), ("jump_window", 1),
                      ("jump_sensor", float("inf"))):
        with pytest.raises(ConfigError, match=name):
            TrackConfig(**{name: bad})


def test_an_object_of_a_handful_of_returns_moves_with_its_track_but_its_own_seen_through_share_is_no_evidence():
    from ros2_mos.offline.tracks import SEEN_THROUGH, Observation, Track, TrackConfig, Tracker

    def track(tid: int, points: int) -> Track:  # ten observations, all half seen through, standing still
        c = np.array([30.0, 3.0, 0.8])
        return Track(tid, [Observation(k, 0, c, points, c - 1, c + 1, 0.5, 0.5) for k in range(10)])

    tracker = Tracker(TrackConfig(evidence_points=8))
    tracker.tracks = [track(0, 8), track(1, 7), track(2, 6)]
    assert tracker.movers() == {0: SEEN_THROUGH}
    tracker.tracks[1].observations[4].points = 12  # one observation of 12 points and another: two are evidence
    tracker.tracks[1].observations[7].points = 9
    assert tracker.movers() == {0: SEEN_THROUGH, 1: SEEN_THROUGH}
    with pytest.raises(ConfigError):
        TrackConfig(evidence_points=0)


def test_a_track_never_seen_through_is_a_mover_when_the_online_model_labels_it_moving_often_enough():
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.tracks import ONLINE_MODEL, SEEN_THROUGH, Observation, Track, TrackConfig, Tracker

    def track(tid: int, online: list[float], far: float = 0.0, step: float = 0.2, distance: float = 12.0) -> Track:
        """Observations ``step`` m apart along x (a queue creeping on, 1.8 m over 10 observations), ``distance`` m
        from the sensor."""
        centre = np.array([10.0, 3.0, 0.8])
        at = [centre + [step * k, 0.0, 0.0] for k in range(len(online))]
        return Track(tid, [Observation(k, 0, c, 100, c - 1, c + 1, far, far, share, distance=distance)
                           for k, (c, share) in enumerate(zip(at, online))])

    tracker = Tracker(TrackConfig(cue_share=0.6, cue_observations=5, cue_track_share=0.5, cue_travel=1.5))
    tracker.tracks = [
        track(0, [0.7] * 5 + [0.0] * 5),  # 5 of 10 at 0.7: a queueing car the online model sees moving
        track(1, [0.7] * 4 + [0.0] * 2),  # 4 hits: too few
        track(2, [0.7] * 5 + [0.0] * 6),  # 5 of 11: under half its observations (a pole flickering)
        track(3, [0.59] * 10),  # under cue_share
        track(4, [0.0] * 10, far=0.5),  # seen through: a mover without the model
        track(5, [0.9] * 10, step=0.0),  # a parked car beside a narrow street that the model labels moving: it stands
        # a parked car the sensor passes 2.9 m away: the model labels it moving, and its visible box slides
        track(6, [0.7] * 5 + [0.0] * 5, distance=2.9),
        track(7, [0.7] * 5 + [0.0] * 5, distance=4.0),  # a queueing car 4 m away: far enough
    ]
    assert tracker.movers() == {0: ONLINE_MODEL, 4: SEEN_THROUGH, 7: ONLINE_MODEL}
    anywhere = Tracker(dataclasses.replace(tracker.config, cue_travel=0.0, cue_min_distance=0.0))
    anywhere.tracks = tracker.tracks
    # without the travel and distance checks also track 2: its 5 labelled observations are a run (``cue_run``)
    assert anywhere.movers() == {0: ONLINE_MODEL, 2: ONLINE_MODEL, 4: SEEN_THROUGH, 5: ONLINE_MODEL, 6: ONLINE_MODEL,
                                 7: ONLINE_MODEL}
    # the cue's model: the one shipped for the sensor, none for a sensor without one or with the cue off
    assert AutoLabeler(sensor_preset("hdl64")).cue_model.name == "default.onnx"
    assert AutoLabeler(sensor_preset("vlp16")).cue_model.name == "vlp16.onnx"
    assert AutoLabeler(SENSOR).cue_model is None
    assert AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(online_cue=False)).cue_model is None
    with pytest.raises(ConfigError, match="cue_share"):
        TrackConfig(cue_share=1.5)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="cue_min_distance"):
            TrackConfig(cue_min_distance=bad)


def test_a_car_the_online_model_saw_drive_up_then_wait_long_is_a_mover_by_its_run_of_moving_labels():
    from ros2_mos.offline.tracks import ONLINE_MODEL, Observation, Track, TrackConfig, Tracker

    def track(tid: int, online: list[float], steps: list[float], distance: float = 30.0) -> Track:
        """Observations ``steps[k]`` m along x after the one before (a car 4 m long, seen from above)."""
        x = np.cumsum([0.0, *steps[1:]]) if steps else np.zeros(0)
        return Track(tid, [Observation(k, 0, np.array([40.0 - xk, 3.0, 0.8]), 100, np.array([38.0 - xk, 2.1, 0.0]),
                                       np.array([42.0 - xk, 3.9, 1.5]), 0.0, 0.0, share, distance=distance)
                           for k, (xk, share) in enumerate(zip(x, online))])

    drove = [0.4] * 6  # 6 observations driving up at 0.4 m per scan (2.0 m between the first and the last) ...
    config = TrackConfig(cue_share=0.6, cue_observations=5, cue_track_share=0.5, cue_travel=1.5)
    tracker = Tracker(dataclasses.replace(config, cue_run=True))
    tracker.tracks = [
        track(0, [0.9] * 6 + [0.0] * 30, drove + [0.0] * 30),  # ... then waiting 30, the model calling it static
        track(1, [0.9, 0.0] * 6 + [0.0] * 24, [0.4] * 12 + [0.0] * 24),  # labelled moving every other scan: no run
        track(2, [0.9] * 6 + [0.0] * 30, [0.2] * 6 + [0.0] * 30),  # a run of 6 that crept 1.0 m: too little
        track(3, [0.9] * 6 + [0.0] * 30, drove + [0.0] * 30, distance=2.9),  # a car passed at arm's length
        track(4, [0.0] * 30 + [0.9] * 6, [0.0] * 30 + drove),  # waited, then drove off under the model's eye
    ]
    # by hand: track 0's run spans boxes 38.0 -> 36.0 (both edges 2.0 m the same way) >= 1.5 m, at 30 m >= 4 m
    assert tracker.movers() == {0: ONLINE_MODEL, 4: ONLINE_MODEL}
    without = Tracker(dataclasses.replace(config, cue_run=False))  # off: 6 of 36 observations is under half of them
    without.tracks = tracker.tracks
    assert without.movers() == {}


def test_a_car_the_online_model_saw_pull_away_as_the_drive_ended_is_a_mover_on_its_word():
    from ros2_mos.offline.tracks import PULLED_AWAY, SEEN_THROUGH, Observation, Track, TrackConfig, Tracker

    def track(tid: int, online: list[float], steps: list[float], distance: float = 5.3, first: int = 0) -> Track:
        """A car 3.7 m long ahead of the sensor, seen from scan ``first`` on, ``steps[k]`` m on along x after the
        observation before."""
        x = np.cumsum([0.0, *steps[1:]])
        return Track(tid, [Observation(first + k, 0, np.array([10.4 + xk, -0.6, 0.8]), 400,
                                       np.array([8.6 + xk, -1.5, 0.0]), np.array([12.3 + xk, 0.3, 1.5]), 0.0, 0.0,
                                       share, distance=distance)
                           for k, (xk, share) in enumerate(zip(x, online))])

    waited = [0.0] * 95
    pulled = [0.0, 0.05, 0.07, 0.08, 0.1]  # 0.3 m on over 5 observations, the model calling them moving
    labelled = [0.0] * 95 + [0.9] * 5
    config = TrackConfig(cue_share=0.6, cue_observations=5, cue_travel=1.5, cue_end_travel=0.25, max_missed=5)
    tracker = Tracker(config)
    tracker.last_scan = 99  # a drive of 100 scans
    tracker.tracks = [
        track(0, labelled, waited + pulled),  # VLP-16 unseen8 narrow_street-10412's car, pulling away at scans 95-99
        track(1, labelled, waited + [0.0, 0.02, 0.02, 0.03, 0.03]),  # 0.1 m: the model's error on a standing car
        track(2, labelled, waited + pulled, distance=2.9),  # a parked car passed at arm's length
        track(3, labelled[1:-1], waited[1:] + pulled[:4], first=1),  # 4 labelled observations: too few
        track(4, [*labelled[1:], 0.0], waited[1:] + pulled + [0.0], first=0),  # the run does not end the track
        track(5, labelled, waited + pulled, first=-3),  # its last observation at scan 96: missed, within max_missed
        track(6, labelled, waited + pulled, first=-7),  # its last at scan 92, 7 scans before the end: it went on
    ]
    # VLP-32C unseen7 narrow_street-10313: a parked car 24 m away seen as 10-20 points, its box jittering, that the
    # model calls moving at the end: between two of its boxes both edges moved 0.3 m the same way, but its last box
    # is not on from its first (by hand: x edges +1.9 / -0.2, opposite ways: nothing)
    jitter = [(8.1, 11.16), (8.78, 10.51), (10.15, 10.83), (9.89, 10.35), (10.27, 10.38), (10.02, 10.98)]
    tracker.tracks.append(Track(7, [Observation(94 + k, 0, np.array([(lo + hi) / 2, 6.0, 0.8]), 15,
                                                np.array([lo, 5.2, 0.0]), np.array([hi, 6.8, 1.5]), 0.0, 0.0, 1.0,
                                                distance=24.0) for k, (lo, hi) in enumerate(jitter)]))
    assert tracker.movers() == {}  # none travelled 1.5 m (``cue_travel``), none was seen through
    # by hand: track 0's last 5 boxes, both edges 0.3 m along x (0.05 + 0.07 + 0.08 + 0.1), >= 0.25 m, 5.3 m >= 4 m
    still = np.zeros((100, 2))  # the sensor waits behind it
    assert tracker.pulling_away({}, still) == {0: PULLED_AWAY, 5: PULLED_AWAY}
    # HDL-64E unseen8 easy-10431: the same boxes while the sensor drives on 0.5 m a scan (from scan 90: 2.5 m over
    # track 0's last 5 observations, over 1 m): a parked car's box slides as the view of it changes
    driving = np.c_[0.5 * np.maximum(np.arange(100) - 90, 0), np.zeros(100)]
    assert tracker.pulling_away({}, driving) == {}
    assert [o.scan for o in tracker._final_run(tracker.tracks[0])] == [95, 96, 97, 98, 99]
    assert tracker._final_run(tracker.tracks[4]) == []
    # a track that is a mover by other evidence (here: a resumption's, or seen through) keeps it
    assert tracker.pulling_away({0: SEEN_THROUGH}, still) == {5: PULLED_AWAY}
    off = Tracker(dataclasses.replace(config, cue_end_travel=0.0))
    off.tracks, off.last_scan = tracker.tracks, 99
    assert off.pulling_away({}, still) == {}
    # SemanticKITTI's convention: moving in every scan it was seen (it moved while observed); the instant one: by the
    # rules for every mover, not the model's word (it calls a bus waiting in a jam moving: VLP-32C unseen8
    # traffic_jam-10404). By hand, its box over 5 observations either side (fewer at the end): scan 97, 92 -> 99,
    # 0.3 m in 0.7 s = 0.43 m/s >= 0.4 m/s (``instant_speed``); scan 96, 0.3 m in 0.8 s = 0.375: not
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult

    tracker.tracks = tracker.tracks[:1]
    result = AutolabelResult("pulling away", 100, np.repeat(np.eye(4)[None], 100, 0), np.arange(100) * 0.1, tracker,
                             {0: PULLED_AWAY}, [400] * 100)
    labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(tracks=config))
    assert labeler._moving_ever(result) == {(k, 0) for k in range(100)}
    assert labeler._moving_now(result) == {(97, 0), (98, 0), (99, 0)}
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="cue_end_travel"):
            TrackConfig(cue_end_travel=bad)
        with pytest.raises(ConfigError, match="cue_end_still"):
            TrackConfig(cue_end_still=bad)


def test_a_track_seen_through_as_it_left_is_a_mover():
    from ros2_mos.offline.tracks import (
        ONLINE_MODEL,
        SEEN_LEAVING,
        SEEN_THROUGH,
        Observation,
        Track,
        TrackConfig,
        Tracker,
    )

    def track(tid: int, far: list[float], steps: list[float]) -> Track:
        """A car 4.4 m long behind the waiting sensor, ``steps[k]`` m on along x after the observation before; ``far``:
        the share of its points seen through."""
        x = np.cumsum([0.0, *steps[1:]])
        return Track(tid, [Observation(k, 0, np.array([-9.2 + xk, 0.1, 0.8]), 300, np.array([-11.4 + xk, -0.8, 0.0]),
                                       np.array([-7.0 + xk, 1.0, 1.5]), share, share, distance=9.2)
                           for k, (xk, share) in enumerate(zip(x, far))])

    # like VLP-32C unseen8 benchmark-10421's: a car waits 73 scans, then drives off, seen through in its last 8
    # observations, 0.85 m on before its track ends: 8 of 81 seen through (< moving_share 0.2), 0.85 m (< 1.5 m)
    waited, leaving = [0.0] * 73, [0.0, 0.05, 0.05, 0.1, 0.1, 0.15, 0.2, 0.2]
    seen = [0.0] * 73 + [0.8] * 8
    config = TrackConfig(cue_observations=5, leave_travel=0.25, seen_through=0.3, min_moving_observations=2)
    tracker = Tracker(config)
    tracker.tracks = [
        track(0, seen, waited + leaving),
        track(1, seen, waited + [0.0, 0.02, 0.02, 0.02, 0.02, 0.0, 0.0, 0.02]),  # 0.1 m: foliage seen into, standing
        track(2, [0.0] * 77 + [0.8] * 4, waited + [0.0, 0.0, 0.0, 0.0, 0.1, 0.15, 0.2, 0.2]),  # 4 seen through: too few
        track(3, [*seen[1:], 0.0], waited[1:] + leaving + [0.0]),  # the seen-through run does not end the track
        track(4, [*seen[:-8], *[0.8, 0.8, 0.8, 0.2, 0.8, 0.8, 0.8, 0.8]], waited + leaving),  # one not seen through
    ]
    # HDL-64E suite benchmark-9102: a pole 0.2 m across, seen through at its edges as the sensor nears it, its box 0.5
    # m on: no vehicle (its longer side under leave_min_length, 1 m)
    pole = track(5, seen, waited + leaving)
    for o in pole.observations:
        o.lo[:2], o.hi[:2] = o.centroid[:2] - 0.1, o.centroid[:2] + 0.1
    # the same car made of parts cut off for being seen through (2 x 41 > 81): no leaving car (seen_leaving takes
    # none such); a mover where its seen-through boxes travelled cut_travel (0.85 m >= 0.5 m by default)
    parts = track(6, seen, waited + leaving)
    for o in parts.observations[:41]:
        o.cut = True
    tracker.tracks += [pole, parts]
    assert tracker.movers() == {6: SEEN_THROUGH}
    tracker.config = config = dataclasses.replace(config, cut_travel=0.9)
    assert tracker.movers() == {}
    assert [o.scan for o in tracker._final_run(tracker.tracks[0], seen_through=True)] == list(range(73, 81))
    # by hand: track 0's last 8 boxes, both edges 0.85 m along x (0.05 + 0.05 + 0.1 + 0.1 + 0.15 + 0.2 + 0.2) >= 0.25;
    # track 4's last 4 (0.65 m) are too few; track 1's 0.1 m is too little; tracks 5 and 6 as above
    assert tracker.seen_leaving({}) == {0: SEEN_LEAVING}
    assert tracker.seen_leaving({0: ONLINE_MODEL}) == {}  # a mover by other evidence keeps it
    far_enough = Tracker(dataclasses.replace(config, leave_travel=0.9))
    far_enough.tracks = tracker.tracks
    assert far_enough.seen_leaving({}) == {}  # 0.85 m < 0.9 m
    off = Tracker(dataclasses.replace(config, leave_travel=0.0))
    off.tracks = tracker.tracks
    assert off.seen_leaving({}) == {}
    # SemanticKITTI's convention: every observation overlapping, from above, its seen-through boxes, so the scans it
    # waited in too (it moved while observed); the instant convention: by the rules for every mover. By hand: scans
    # 73-80 seen through by a near scan (0.8 >= instant_seen_through); scan 72, its box over 5 observations either side
    # (67 -> 77) 0.3 m on in 1.0 s < 0.4 m/s (``instant_speed``): standing, as are those before
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult

    tracker.tracks = tracker.tracks[:1]
    result = AutolabelResult("leaving", 81, np.repeat(np.eye(4)[None], 81, 0), np.arange(81) * 0.1, tracker,
                             {0: SEEN_LEAVING}, [300] * 81)
    labeler = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(tracks=config))
    assert labeler._moving_ever(result) == {(k, 0) for k in range(81)}
    assert labeler._moving_now(result) >= {(k, 0) for k in range(73, 81)}
    assert not labeler._moving_now(result) & {(k, 0) for k in range(73)}
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="leave_travel"):
            TrackConfig(leave_travel=bad)
        with pytest.raises(ConfigError, match="leave_min_length"):
            TrackConfig(leave_min_length=bad)


def test_observations_too_small_to_judge_neither_end_nor_join_a_run_seen_through():
    from ros2_mos.offline.tracks import SEEN_LEAVING, Observation, Track, TrackConfig, Tracker

    def cyclist(tid: int, points: list[int], far: list[float], x: list[float]) -> Track:
        """A cyclist 1.6 m long 15 m ahead, ``x[k]`` m along x in observation k; ``far``: its share seen through."""
        return Track(tid, [Observation(k, 0, np.array([15.0 + xk, -2.4, -1.0]), n, np.array([14.2 + xk, -2.7, -1.7]),
                                       np.array([15.8 + xk, -2.2, 0.0]), share, share, distance=15.0)
                           for k, (n, share, xk) in enumerate(zip(points, far, x))])

    # like VLP-16 validation easy-9612-100's: waits 60 scans, rides off, seen through in 6 observations of 10-17
    # returns, 0.6 m on; the drive's last scan sees 7 returns of it (under evidence_points, 8), not seen through
    x = [0.0] * 60 + [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    points = [300] * 60 + [17, 16, 14, 7, 12, 10, 7]
    far = [0.0] * 60 + [0.5, 0.6, 0.6, 0.0, 0.7, 0.9, 0.0]
    config = TrackConfig(cue_observations=5, leave_travel=0.25, seen_through=0.3, evidence_points=8,
                         min_moving_observations=2)
    tracker = Tracker(config)
    tracker.tracks = [cyclist(0, points, far, x),
                      cyclist(1, points[:-1] + [8], far, x)]  # 8 returns in the last scan, not seen through: judged
    # by hand: track 0's run passes over scans 66 and 63 (7 returns each): 60, 61, 62, 64, 65; from scan 60's box to
    # scan 65's, both edges 0.5 m on >= 0.25. Track 1's last observation (8 returns, 0.0 seen through) ends its run
    assert [o.scan for o in tracker._final_run(tracker.tracks[0], seen_through=True)] == [60, 61, 62, 64, 65]
    assert tracker._final_run(tracker.tracks[1], seen_through=True) == []
    assert tracker.movers() == {}  # 5 of 67 seen through (< moving_share 0.2), 0.5 m (< min_evidence_travel 1.5)
    assert tracker.seen_leaving({}) == {0: SEEN_LEAVING}
    # the same for a track seen moving as it ended, which a mover beginning where it ended takes over
    assert tracker._moving_as_it_ended(tracker.tracks[0]) and not tracker._moving_as_it_ended(tracker.tracks[1])



def test_a_scan_the_online_model_refuses_goes_without_the_cue(jam, tmp_path, monkeypatch):
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.core.errors import ImplausibleScanError
    from ros2_mos.core.pipeline import MosPipeline

    process = MosPipeline.process
    calls = []

    def refuse_the_third(self, points, intensity, timestamp, pose=None):
        calls.append(timestamp)
        if len(calls) == 3:
            raise ImplausibleScanError("scattered points, no scan of surfaces")
        return process(self, points, intensity, timestamp, pose)

    monkeypatch.setattr(MosPipeline, "process", refuse_the_third)
    labeler = AutoLabeler(sensor_preset("vlp32c"))
    result = labeler.label(FolderDrive(jam / "sequences" / "00"), tmp_path)
    assert len(calls) == 30 and result.cue_skipped == 1 and result.cue_model == "vlp32c.onnx"
    third = [o for t in result.tracker.tracks for o in t.observations if o.scan == 2]
    assert third and all(o.online == 0.0 for o in third)  # the refused scan: no cue
    assert any(o.online > 0 for t in result.tracker.tracks for o in t.observations)  # the cue ran elsewhere
    for o in (o for t in result.tracker.tracks for o in t.observations):  # the cue's distance check: from the sensor
        sensor = result.poses[o.scan][:2, 3]
        assert o.distance == pytest.approx(float(np.hypot(*(o.centroid[:2] - sensor))))


def test_seen_through_observations_lie_apart_only_when_their_boxes_travel():
    from ros2_mos.offline.tracks import Observation, Track, TrackConfig, Tracker, evidence_travel

    def obs(scan: int, lo: tuple[float, float], hi: tuple[float, float], far: float) -> Observation:
        lo3, hi3 = np.array([*lo, 0.0]), np.array([*hi, 1.5])
        return Observation(scan, 0, (lo3 + hi3) / 2, 100, lo3, hi3, far, far)

    # a parked car (x 50-54.8) that a passer-by merges with for three scans: the merged cluster grows forward
    # (x 50-56, 50-58, 50-60) and is seen through where the passer-by was. Centroid extent 2.0 m; the boxes' rear
    # edges stay, so they did not travel.
    parked = [obs(k, (50.0, -5.0), (54.8, -3.0), 0.0) for k in range(20)]
    merged = [obs(20 + i, (50.0, -5.0), (56.0 + 2 * i, -3.0), 0.35) for i in range(3)]
    parked += merged + [obs(k, (50.0, -5.0), (54.8, -3.0), 0.0) for k in range(23, 40)]
    assert evidence_travel(merged, "centroid") == pytest.approx(2.0)
    assert evidence_travel(merged) == pytest.approx(0.0)
    # a car that waited (x 10-14.5) and then left, seen through once while it waited and twice as it left,
    # 2 and then 3 m on: both edges travelled 3 m
    left = [obs(k, (10.0, 0.0), (14.5, 1.8), 0.4 if k == 5 else 0.0) for k in range(30)]
    left += [obs(30, (12.0, 0.0), (16.5, 1.8), 0.4), obs(31, (13.0, 0.0), (17.5, 1.8), 0.4)]
    assert evidence_travel([o for o in left if o.far > 0]) == pytest.approx(3.0)
    # a track thousands of observations long is measured on an even spread of them (and its last): a car that
    # waited 2,999 scans and left 2 m in the last one still travelled 2 m; the parked car still did not
    long_wait = [obs(k, (10.0, 0.0), (14.5, 1.8), 0.4) for k in range(2999)]
    long_wait.append(obs(2999, (12.0, 0.0), (16.5, 1.8), 0.4))
    assert evidence_travel(long_wait) == pytest.approx(2.0)
    assert evidence_travel(parked * 100) == pytest.approx(0.0)

    config = TrackConfig(min_evidence_travel=1.5, moving_share=0.2)
    tracker = Tracker(config)
    assert not tracker.seen_moving(Track(0, parked))  # 3 of 40 seen through, boxes 0 m apart
    assert tracker.seen_moving(Track(1, left))  # 3 of 32 seen through, boxes 3 m apart
    assert Tracker(TrackConfig(evidence_travel="centroid")).seen_moving(Track(0, parked))  # the old rule's error
    with pytest.raises(ConfigError, match="evidence_travel"):
        TrackConfig(evidence_travel="median")


def test_a_box_that_stood_jumped_once_and_stood_again_did_not_travel():
    from ros2_mos.offline.tracks import Observation, Track, TrackConfig, Tracker

    def obs(scan: int, x: float, far: float) -> Observation:  # one ring across a car's roof: a flat sliver
        lo, hi = np.array([x, 7.0, 2.1]), np.array([x + 0.1, 8.8, 2.1])
        return Observation(scan, 0, (lo + hi) / 2, 10, lo, hi, 0.0, far)

    # A parked car's roof seen by one ring as the sensor nears: the ring stands at x 74.5 for nine scans, then at
    # 76.0 (1.5 m on in one scan) for five; far scans see through it now and then (5 of 14)
    seen = {50: 0.7, 52: 0.3, 53: 0.4, 57: 0.4, 62: 0.54}
    roof = Track(0, [obs(k, 74.5 if k < 54 else 76.0, seen.get(k, 0.0)) for k in [*range(45, 58), 62]])
    # A car seen by one ring as it drives off, 0.4 m a scan, seen through as often
    driving = Track(1, [obs(k, 74.5 + 0.4 * (k - 45), seen.get(k, 0.0)) for k in [*range(45, 58), 62]])
    # A car that waited, then left in two steps (2 m, then 1 m), seen through as it left
    left = Track(2, [obs(k, 10.0 + (2.0 if k == 30 else 3.0 if k > 30 else 0.0), 0.4 if k >= 29 else 0.0)
                     for k in range(32)])
    config = TrackConfig(min_evidence_travel=1.5, moving_share=0.4)  # by travel only: none is seen through that often
    tracker = Tracker(config)
    assert not tracker.seen_moving(Track(0, roof.observations))
    assert tracker.seen_moving(driving) and tracker.seen_moving(left)
    assert Tracker(TrackConfig(min_evidence_travel=1.5, moving_share=0.4, travel_jump=0.0)).seen_moving(roof)
    # a car hidden for three scans while it moved 1.5 m, standing before and after, moved
    hidden = Track(4, [o for o in roof.observations if not 51 <= o.scan <= 53])
    assert Tracker(config).seen_moving(hidden)
    # the jump needs two observations after it: a car that left in one step as its track ended travelled
    assert Tracker(config).seen_moving(Track(3, [*roof.observations[:9], obs(54, 76.0, 0.5)]))
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ConfigError, match="travel_jump"):
            TrackConfig(travel_jump=bad)


def test_parts_cut_off_for_being_seen_through_make_a_mover_only_if_they_travel():
    from ros2_mos.offline.tracks import Observation, Track, TrackConfig, Tracker

    def part(scan: int, x: float, cut: bool = True) -> Observation:
        lo, hi = np.array([x, -6.2, -0.2]), np.array([x + 0.3, -5.9, 0.2])
        return Observation(scan, 0, (lo + hi) / 2, 150, lo, hi, 0.4, 0.4, 0.0, cut)

    tracker = Tracker(TrackConfig(min_evidence_travel=1.5))
    pole = Track(0, [part(25 + 3 * i, -3.1) for i in range(4)])  # a thin pole cut off a hedge, seen round its edges
    cyclist = Track(1, [part(25 + i, -3.1 + 0.5 * i) for i in range(4)])  # the cyclist cut off a parked car
    assert not tracker.seen_moving(pole) and tracker.seen_moving(cyclist)
    # cut parts need cut_travel (0.5 m), not min_evidence_travel: a cyclist seen 0.2 m on a scan for 4 scans (0.6 m)
    slower = Track(3, [part(25 + i, -3.1 + 0.2 * i) for i in range(4)])
    assert tracker.seen_moving(slower)
    assert not Tracker(TrackConfig(cut_travel=0.7)).seen_moving(slower)
    assert not Tracker(TrackConfig(cut_travel=0.5)).seen_moving(Track(4, [part(25 + i, -3.1 + 0.1 * i)
                                                                          for i in range(4)]))  # 0.3 m: no
    assert tracker.seen_moving(Track(2, [part(25 + 3 * i, -3.1, cut=False) for i in range(4)]))  # uncut: as before



def test_the_online_model_vetoes_a_mover_by_share_alone_that_it_calls_static():
    from ros2_mos.offline.tracks import SEEN_THROUGH, Observation, Track, TrackConfig, Tracker

    def obs(scan: int, x: float, far: float, online: float) -> Observation:
        lo, hi = np.array([x, 2.0, 0.0]), np.array([x + 1.0, 5.0, 1.5])
        return Observation(scan, 0, (lo + hi) / 2, 80, lo, hi, far, far, online)

    # A hedge (1 x 3 m) seen through in 4 of its 10 observations (0.4 >= moving_share), standing: a mover by share.
    hedge = [obs(k, 30.0, 0.5 if k % 3 == 0 else 0.0, 0.0) for k in range(10)]
    # A pedestrian whose seen-through boxes lie 2.7 m apart: a mover by travel, whatever the model says.
    walker = [obs(k, 40.0 + 0.3 * k, 0.5, 0.0) for k in range(10)]
    tracker = Tracker(TrackConfig(cue_veto=True, cue_veto_share=0.05, cue_veto_near=1.0))  # whatever near scans saw
    tracker.tracks = [Track(0, hedge), Track(1, walker),
                      Track(2, [dataclasses.replace(o, online=0.1) for o in hedge])]  # the model: 10 % moving
    assert tracker.movers(cue=True) == {1: SEEN_THROUGH, 2: SEEN_THROUGH}
    assert tracker.movers(cue=False) == {0: SEEN_THROUGH, 1: SEEN_THROUGH, 2: SEEN_THROUGH}  # no model, no veto
    tracker.config = TrackConfig(cue_veto=False)
    assert 0 in tracker.movers(cue=True)
    with pytest.raises(ConfigError, match="cue_veto_share"):
        TrackConfig(cue_veto_share=float("inf"))
    # With cue_veto_near 0 (the default) the veto spares a track that a near scan saw through (the hedge above: near
    # = far), and takes the same hedge seen through by far scans only.
    tracker.config = TrackConfig()
    far_only = [dataclasses.replace(o, near=0.0) for o in hedge]
    tracker.tracks = [Track(0, hedge), Track(1, walker), Track(3, far_only)]
    assert tracker.movers(cue=True) == {0: SEEN_THROUGH, 1: SEEN_THROUGH}
    for bad in (float("nan"), -0.1, 1.5):
        with pytest.raises(ConfigError, match="cue_veto_near"):
            TrackConfig(cue_veto_near=bad)


def test_a_track_that_ends_where_a_mover_s_track_begins_is_that_mover_waiting():
    from ros2_mos.offline.tracks import SEEN_THROUGH, WAITED, Observation, Track, TrackConfig, Tracker

    def obs(scan: int, x: float, far: float = 0.0, size: tuple[float, float] = (4.5, 1.8)) -> Observation:
        lo, hi = np.array([x, 2.0, 0.0]), np.array([x + size[0], 2.0 + size[1], 1.5])
        return Observation(scan, 0, (lo + hi) / 2, 100, lo, hi, far, far)

    tracker = Tracker(TrackConfig(handover_scans=3, handover_margin=0.3, handover_larger=5.0, handover_smaller=0.5,
                                  handover_max_area=9.0))
    tracker.tracks = [
        Track(0, [obs(k, 10.0) for k in range(22, 34)]),  # waits at x 10-14.5 from scan 22 through 33 ...
        Track(1, [obs(33 + k, 10.5 + 0.3 * k, far=0.5) for k in range(20)]),  # ... and leaves as another track
        Track(2, [obs(k, 10.0) for k in range(16)]),  # stood there before, left at scan 15 (7 scans before 22)
        Track(3, [obs(k, 15.7) for k in range(34)]),  # ends then too, 0.7 m ahead of it (> 2 x 0.3 m): parked
        Track(4, [obs(k, 40.0) for k in range(20)]),  # stood where track 5 began, which it handed over to ...
        Track(5, [obs(19 + k, 40.1) for k in range(10)]),  # ... and which ended where the mover 6 began
        Track(6, [obs(30 + k, 40.2 + 0.4 * k, far=0.5) for k in range(10)]),
        Track(7, [obs(34, 10.2)]),  # a fragment of the car as it moves off, where it waited: its place is still empty
        # a parked car at x 70 that a passer-by merged with ends where the passer-by's track begins (scan 50) and
        # goes on as another track: its place was not left empty
        Track(8, [obs(k, 70.0) for k in range(51)]),
        Track(9, [obs(50 + k, 70.3 + 0.5 * k, far=0.5) for k in range(10)]),
        Track(10, [obs(51 + k, 70.0) for k in range(20)]),
        # a pole (0.3 x 0.3 m) whose track ends where a passer-by's begins (1.5 x 1.2 m, 20 times larger): not it
        Track(11, [obs(k, 100.0, size=(0.3, 0.3)) for k in range(60)]),
        Track(12, [obs(60 + k, 99.5 + 0.1 * k, far=0.5, size=(1.5, 1.2)) for k in range(20)]),
        # a car that waited (4.5 x 1.8 m) and is first seen moving off as a glimpse of 2.0 x 0.9 m (4.5 times smaller)
        Track(13, [obs(k, 130.0) for k in range(60)]),
        Track(14, [obs(60 + k, 133.5 + 0.5 * k, far=0.5, size=(2.0, 0.9)) for k in range(20)]),
        # a cluster of 6 x 2 m (12 m2, larger than a car) that a passer-by (4 x 1.8 m) leaves
        Track(15, [obs(k, 160.0, size=(6.0, 2.0)) for k in range(60)]),
        Track(16, [obs(60 + k, 165.5 + 0.5 * k, far=0.5) for k in range(20)]),
        # a car that waited (x 190-194.5) and moved off bit by bit: its track ends as a stub 0.6 m long
        Track(17, [obs(k, 190.0) for k in range(31)] + [obs(31 + i, 190.0, size=(side, 1.8))
                                                        for i, side in enumerate((2.0, 1.0, 0.6))]),
        Track(18, [obs(33 + k, 190.8 + 0.5 * k, far=0.5) for k in range(20)]),
        # a sign post (0.4 x 0.3 m) whose track ends where a pedestrian's (0.5 x 0.5 m) begins: not a car
        Track(19, [obs(k, 220.0, size=(0.4, 0.3)) for k in range(40)]),
        Track(20, [obs(40 + k, 220.2 + 0.15 * k, far=0.5, size=(0.5, 0.5)) for k in range(20)]),
        # a car (x 250-254.5) whose points move over to the mover's track scan by scan: its last box, a 0.6 m stub,
        # lies 2.9 m behind the mover's first box; the boxes of its last 4 observations reach it
        Track(21, [obs(k, 250.0) for k in range(30)] + [
            dataclasses.replace(obs(30 + i, 250.0, size=(side, 1.8)), points=points)
            for i, (side, points) in enumerate(((3.0, 80), (2.0, 60), (1.0, 40), (0.6, 20)))]),
        Track(22, [obs(33 + k, 253.5 + 0.5 * k, far=0.5, size=(2.0, 1.8)) for k in range(20)]),
        # a parked car (x 280-284.5) whose track ends where a hedge (1 x 3 m) begins that is seen through in every
        # scan and stands still: a mover by its share of seen-through observations, but it never left anywhere
        Track(23, [obs(k, 280.0) for k in range(61)]),
        Track(24, [obs(60 + k, 283.5, far=0.5, size=(1.0, 3.0)) for k in range(20)]),
        # a car that queued behind the sensor (x 310-314.5, 8.1 m2) pulls away seen end-on: its first glimpse is three
        # slivers (0.3 x 1.8 m, 0.9 m2 each: 9 times smaller), three tracks; together 3.3 x 1.8 m (1.4 times smaller)
        Track(25, [obs(k, 310.0) for k in range(60)]),
        *[Track(26 + i, [obs(60 + k, 310.0 + 1.5 * i + 0.5 * k, far=0.5, size=(0.3, 1.8)) for k in range(20)])
          for i in range(3)],
        # a car that waited (x 340-344.5) whose mover's boxes travel only 1.33 m (< handover_travel), but it ends
        # apart from where the car waited: it left
        Track(29, [obs(k, 340.0) for k in range(60)]),
        Track(30, [obs(60 + k, 344.0 + 0.07 * k, far=0.5, size=(1.0, 1.8)) for k in range(20)]),
        # a car that waited (x 370-374.5) and, as it moves off, a sliver of it (0.2 x 1.7 m) becomes a track of its own
        # for six scans where it stood: not a car taking its place (track 10 is one)
        Track(31, [obs(k, 370.0) for k in range(60)]),
        Track(32, [obs(57 + k, 372.0, size=(0.2, 1.7)) for k in range(6)]),
        Track(33, [obs(60 + k, 370.5 + 0.5 * k, far=0.5, size=(2.0, 1.8)) for k in range(20)]),
        # a cyclist (1.8 x 0.6 m) who waited at x 400 for 50 scans, then rode off, seen through in his track's last
        # 3 scans (0.6 m: too few, too close, to make it a mover) before it broke; a parked car's track begins where
        # he ended as he ended, and his mover's first glimpse (0.3 x 0.5 m) is a quarter of him
        Track(34, [obs(k, 400.0, size=(1.8, 0.6)) for k in range(50)]
              + [obs(50 + k, 400.3 + 0.3 * k, far=0.5, size=(1.8, 0.6)) for k in range(3)]),
        Track(35, [obs(53 + k, 401.3 + 0.3 * k, far=0.5, size=(0.3, 0.5)) for k in range(20)]),
        Track(36, [obs(52 + k, 401.5) for k in range(20)]),
        # a car and a cyclist that waited side by side (one cluster, 6 x 1.8 m: 10.8 m2, over handover_max_area)
        # and left together, two tracks that begin in the same scan: together 6 x 1.5 m (9 m2)
        Track(37, [obs(k, 430.0, size=(6.0, 1.8)) for k in range(60)]),
        Track(38, [obs(60 + k, 430.0 - 0.5 * k, far=0.5, size=(3.0, 1.5)) for k in range(20)]),
        Track(39, [obs(60 + k, 434.5 + 0.5 * k, far=0.5, size=(1.5, 0.6)) for k in range(20)]),
    ]
    movers = tracker.movers()
    assert movers == {1: SEEN_THROUGH, 6: SEEN_THROUGH, 9: SEEN_THROUGH, 12: SEEN_THROUGH, 14: SEEN_THROUGH,
                      16: SEEN_THROUGH, 18: SEEN_THROUGH, 20: SEEN_THROUGH, 22: SEEN_THROUGH, 24: SEEN_THROUGH,
                      26: SEEN_THROUGH, 27: SEEN_THROUGH, 28: SEEN_THROUGH, 30: SEEN_THROUGH, 33: SEEN_THROUGH,
                      35: SEEN_THROUGH, 38: SEEN_THROUGH, 39: SEEN_THROUGH}
    assert tracker.handovers(movers) == {0: WAITED, 5: WAITED, 4: WAITED, 13: WAITED, 17: WAITED, 21: WAITED,
                                         25: WAITED, 29: WAITED, 31: WAITED, 34: WAITED, 37: WAITED}
    unseen = Tracker(dataclasses.replace(tracker.config, handover_seen_moving=False))
    unseen.tracks = tracker.tracks
    assert 34 not in unseen.handovers(movers)  # without: the parked car began where he ended, and took his place
    unfilled = Tracker(dataclasses.replace(tracker.config, handover_filled=False))
    unfilled.tracks = tracker.tracks
    assert 37 not in unfilled.handovers(movers)  # without: larger than a car
    assert 37 not in tracker.handovers({38: SEEN_THROUGH})  # the car alone (4.5 m2) does not fill half of it
    assert 25 not in tracker.handovers({26: SEEN_THROUGH})  # one sliver alone is 9 times smaller than the car
    stay_anywhere = Tracker(dataclasses.replace(tracker.config, handover_travel=0.0))
    stay_anywhere.tracks = tracker.tracks
    assert 23 in stay_anywhere.handovers(movers)  # without the travel, the parked car would be the hedge waiting
    for glimpse, handed in ((1.0, False), (2.0, True)):  # 9 times smaller: not it; 4.5 times: it
        tracker.tracks[14] = Track(14, [obs(60 + k, 133.5 + 0.5 * k, far=0.5, size=(glimpse, 0.9)) for k in range(20)])
        assert (13 in tracker.handovers(movers)) == handed
    anything = Tracker(dataclasses.replace(tracker.config, handover_min_area=0.0))
    anything.tracks = tracker.tracks
    assert 19 in anything.handovers(movers)  # without the least area, the post would be the pedestrian waiting
    assert Tracker(TrackConfig(handover_scans=0)).handovers(movers) == {}
    with pytest.raises(ConfigError, match="handover_margin"):
        TrackConfig(handover_margin=float("nan"))



def test_a_car_queued_behind_the_sensor_hands_over_to_the_sliver_of_its_front_moving_off():
    from ros2_mos.offline.tracks import SEEN_THROUGH, WAITED, Observation, Track, TrackConfig, Tracker

    def obs(scan: int, x0: float, x1: float, far: float = 0.0) -> Observation:
        lo, hi = np.array([x0, -1.1, -1.5]), np.array([x1, 0.8, -0.7])
        return Observation(scan, 0, (lo + hi) / 2, 200, lo, hi, far, far)

    # A car waits behind the sensor, its last box 2.8 x 1.9 m (5.32 m²); it moves off as the sliver of its front
    # seen end-on, 0.5 x 1.9 m (0.95 m², the footprint's least side): 5.6 times larger, within handover_larger (7)
    waited = Track(0, [obs(k, -8.9, -6.1) for k in range(62)])
    mover = Track(1, [obs(62 + k, -6.5 + 0.25 * k, -6.1 + 0.25 * k, far=0.8) for k in range(30)])
    tracker = Tracker(TrackConfig())
    tracker.tracks = [waited, mover]
    assert TrackConfig().handover_larger == 7.0
    assert tracker.handovers({1: SEEN_THROUGH}) == {0: WAITED}
    tracker.config = TrackConfig(handover_larger=5.0)  # round 54's bound
    assert tracker.handovers({1: SEEN_THROUGH}) == {}


def test_a_track_that_begins_where_a_mover_stood_hidden_is_that_mover_seen_again():
    from ros2_mos.offline.tracks import (
        ONLINE_MODEL,
        RESUMED,
        SEEN_THROUGH,
        WAITED,
        Observation,
        Track,
        TrackConfig,
        Tracker,
    )

    def obs(scan: int, x0: float, x1: float, points: int = 100, far: float = 0.0, y: float = 5.7) -> Observation:
        lo, hi = np.array([x0, y, 0.0]), np.array([x1, y + 0.2, 3.0])
        return Observation(scan, 0, (lo + hi) / 2, points, lo, hi, far, far)

    def bus(tid: int, x: float, first: int = 0) -> list[Track]:
        """A bus (10 m) drives up, seen through (scans 0-9), stops at x..x+10 (10-16), is hidden bit by bit as a
        truck passes between (17-21: the box's rear edge creeps forward, fewer points), and is seen again where it
        stood from scan 30 on, revealed from the rear (30-34), as a new track."""
        return [Track(tid, [obs(first + k, x + 10 - k, x + 20 - k, far=0.5) for k in range(10)]
                      + [obs(first + k, x, x + 10) for k in range(10, 17)]
                      + [obs(first + 17 + i, x + 2 * (i + 1), x + 10, points=90 - 20 * i) for i in range(5)]),
                Track(tid + 1, [obs(first + 30 + i, x, x + 2 * (i + 1), points=20 + 20 * i) for i in range(5)]
                      + [obs(first + 35 + k, x, x + 10) for k in range(20)])]

    config = TrackConfig(resume_scans=20, resume_stood=0.3, resume_travel=1.0, resume_stood_observations=5,
                         resume_observations=3, handover_margin=0.3)
    tracker = Tracker(config)
    tracker.tracks = [
        # by hand: it drove 10 m, stood at x 0-10 (scans 12-16: no travel); hidden, its boxes reach x 2-10 ... 10-10
        *bus(0, 0.0),
        # the same, but it drove on at 0.2 m per scan while it was hidden (0.8 m over its last 5 full views): a
        # parked car's track begins 5 scans after its end within where it was as it ended
        Track(2, [obs(k, 50.0 - 0.2 * k, 60.0 - 0.2 * k, far=0.5) for k in range(17)]),
        Track(3, [obs(21 + k, 48.0, 52.0) for k in range(20)]),
        bus(4, 100.0)[0],  # a bus again, but the track that begins 9 scans after its end lies 1 m beyond where it
        Track(5, [obs(30 + k, 109.0, 111.0) for k in range(20)]),  # stood (x 100-110, grown by 0.3 m)
        Track(6, [obs(30 + k, 95.0, 99.0) for k in range(20)]),  # ... and a parked car behind it, 1 m apart
        *bus(7, 200.0),  # a bus again, but the new track begins 21 scans after its end: too late
        # a car that waited and left (a track handed over to its mover, 10): nothing ends standing there
        Track(9, [obs(k, 300.0, 304.5) for k in range(20)]),
        Track(10, [obs(20 + k, 300.5 + 0.5 * k, 305.0 + 0.5 * k, far=0.5) for k in range(20)]),
        Track(11, [obs(25 + k, 300.0, 301.0) for k in range(20)]),
        # a parked car seen through in every scan (a mover by share) that never moved: its boxes travel 0 m (< 1 m)
        Track(12, [obs(k, 400.0, 404.5, far=0.5) for k in range(20)]),
        Track(13, [obs(25 + k, 400.0, 404.5) for k in range(20)]),
        # seen again twice: the track that begins where the first bus's second track ended is it too
        Track(14, [obs(60 + k, 0.0, 10.0) for k in range(10)]),
        # a bus again, but a mover on the online model's word only (its word on a parked car must not spread)
        *[Track(t.id, [dataclasses.replace(o, near=0.0, far=0.0) for o in t.observations]) for t in bus(15, 500.0)],
        # a bus again; where it stood (z 0-3 m) the sensor, passing on, reveals a sign over it (z 3.5-5 m: beyond the
        # 0.3 m margin) and the bus itself, each a new track
        bus(17, 600.0)[0],
        Track(18, [dataclasses.replace(obs(30 + k, 601.0, 605.0), lo=np.array([601.0, 5.7, 3.5]),
                                       hi=np.array([605.0, 5.9, 5.0])) for k in range(20)]),
        Track(19, [obs(30 + k, 606.0, 609.0) for k in range(20)]),
    ]
    tracker.tracks[8].observations = [dataclasses.replace(o, scan=o.scan + 12) for o in tracker.tracks[8].observations]
    movers = tracker.movers()
    assert movers == {0: SEEN_THROUGH, 2: SEEN_THROUGH, 4: SEEN_THROUGH, 7: SEEN_THROUGH, 10: SEEN_THROUGH,
                      12: SEEN_THROUGH, 17: SEEN_THROUGH}
    movers.update(tracker.handovers(movers))
    assert movers[9] == WAITED
    movers[15] = ONLINE_MODEL
    assert tracker.resumptions(movers) == {1: RESUMED, 14: RESUMED, 19: RESUMED}  # not the sign (18)
    assert tracker.resumptions({**movers, 15: SEEN_THROUGH})[16] == RESUMED  # the same bus, by visibility
    still = Tracker(dataclasses.replace(config, resume_travel=0.0))
    still.tracks = tracker.tracks
    assert 13 in still.resumptions(movers)  # without the travel, the parked car would be seen again where it stood
    assert Tracker(dataclasses.replace(config, resume_scans=0)).resumptions(movers) == {}
    assert Tracker(dataclasses.replace(config, resume_scans=20)).resumptions({}) == {}
    with pytest.raises(ConfigError, match="resume_stood"):
        TrackConfig(resume_stood=float("inf"))

    # Seen again, it is moving in every scan under SemanticKITTI's convention (each box overlaps its first one), and
    # standing under the instant one: revealed from the rear, its front edge grows while its rear edge stays.
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutoLabeler, AutolabelResult

    seen_again = Tracker(config)
    seen_again.tracks = [Track(0, tracker.tracks[1].observations)]
    result = AutolabelResult("bus", 55, np.repeat(np.eye(4)[None], 55, 0), np.arange(55) * 0.1, seen_again,
                             {0: RESUMED}, [100] * 55)
    labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(shadow_edges=False))
    assert labeler._moving_ever(result) == {(k, 0) for k in range(30, 55)}
    assert labeler._moving_now(result) == set()


def test_a_track_that_waited_is_moving_where_it_stood_as_it_ended_and_where_it_was_seen_through():
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult
    from ros2_mos.offline.tracks import WAITED, Observation, Track, Tracker

    def obs(scan: int, x: float, far: float = 0.0) -> Observation:
        lo, hi = np.array([x, 2.0, 0.0]), np.array([x + 1.8, 2.6, 1.5])
        return Observation(scan, 0, (lo + hi) / 2, 50, lo, hi, far, far)

    # A cyclist waits at x 10-11.8 (scans 0-9), then rides off (x 10.6, 11.2, 13.5: scans 10-12), seen through as he
    # rides; his track breaks and is handed over to the mover that goes on. It is moving where it was seen through,
    # and where he waited, which those boxes overlap.
    tracker = Tracker()
    tracker.tracks = [Track(0, [obs(k, 10.0) for k in range(10)] + [obs(10, 10.6, 0.5), obs(11, 11.2, 0.5),
                                                                   obs(12, 13.5, 0.5)])]
    labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(support_margin=0.3))
    result = AutolabelResult("cyclist", 13, np.repeat(np.eye(4)[None], 13, 0), np.arange(13) * 0.1, tracker,
                             {0: WAITED}, [50] * 13)
    assert labeler._moving_ever(result) == {(k, 0) for k in range(13)}
    # Under the instant convention it moves as it rides off: box speed over +-5 observations (instant_span) at least
    # 0.4 m/s from scan 5 on (x 10 -> 10.6 between scans 0 and 10: 0.6 m/s), not while it waited before that.
    assert labeler._moving_now(result) == {(k, 0) for k in range(5, 13)}
    # Seen through in no scan but where it ended (x 13.5-15.3): moving there and within 2 x 0.3 m of it (x 11.2-13,
    # 0.5 m away), not where it waited (1.7 m away) nor at x 10.6-12.4 (1.1 m).
    tracker.tracks = [Track(0, [obs(k, 10.0) for k in range(10)] + [obs(10 + k, 10.6 + 0.6 * k)
                                                                   for k in range(2)] + [obs(12, 13.5)])]
    assert labeler._moving_ever(result) == {(11, 0), (12, 0)}


def test_a_mover_whose_box_changes_shape_moves_now_where_the_online_model_says_so():
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult, reshaped
    from ros2_mos.offline.tracks import SEEN_THROUGH, Observation, Track, Tracker

    # by hand: x edges -0.3 / +0.3 (opposite, both over 0.2): reshaped; -0.3 / +0.1, or both +0.3 (moved): not
    lo0, hi0 = np.zeros((3, 2)), np.ones((3, 2))
    lo1 = lo0 + np.array([[-0.3, 0.0], [-0.3, 0.0], [0.3, 0.0]])
    hi1 = hi0 + np.array([[0.3, 0.0], [0.1, 0.0], [0.3, 0.0]])
    assert reshaped(lo0, hi0, lo1, hi1, 0.2).tolist() == [True, False, False]
    assert not reshaped(lo0, hi0, lo1, hi1, 0.0).any()

    def obs(scan: int, lo: float, hi: float, online: float, far: float = 0.0) -> Observation:
        lo3, hi3 = np.array([lo, 2.0, 0.0]), np.array([hi, 3.8, 1.5])
        return Observation(scan, 0, (lo3 + hi3) / 2, 200, lo3, hi3, 0.0, far, online)  # near, far, online

    # A car creeping towards -x at 0.5 m/s (0.05 m a scan) as the sensor comes up beside it, seen through only at the
    # end (scans 20-21): its box grows at both ends as more of it comes into view (rear edge x 50 -> 47 over scans
    # 0-20, front edge 53 -> 55), so its edges move opposite ways and its box shift is nothing; the model labels it
    # moving.
    def creeping(online: float) -> Track:
        return Track(0, [obs(k, 50.0 - 0.15 * k, 53.0 + 0.1 * k, online, 0.5 if k >= 20 else 0.0) for k in range(22)])

    tracker = Tracker()
    result = AutolabelResult("creeper", 22, np.repeat(np.eye(4)[None], 22, 0), np.arange(22) * 0.1, tracker,
                             {0: SEEN_THROUGH}, [200] * 22)
    for cue_reshape, online, moving in ((0.2, 0.9, set(range(22))), (0.0, 0.9, set()), (0.2, 0.3, set())):
        tracker.tracks = [creeping(online)]
        labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(instant_cue_reshape=cue_reshape))
        assert labeler._moving_now(result) == {(k, 0) for k in moving}
    # A car that waits, its box still, is not moving now however much the model says it is
    tracker.tracks = [Track(0, [obs(k, 50.0, 54.5, 0.9, 0.5 if k >= 20 else 0.0) for k in range(22)])]
    assert AutoLabeler(sensor_preset("hdl64"), AutolabelConfig())._moving_now(result) == set()
    with pytest.raises(ConfigError, match="instant_cue_reshape"):
        AutolabelConfig(instant_cue_reshape=float("nan"))
    # A car driving towards -x at 0.5 m/s (its centroid), whose front edge moves 0.07 m a scan and its rear 0.03 as
    # more of it comes into view: its box moved 0.3 m/s (the edges agree on that much; instant_speed 0.4), its
    # centroid 0.5 m/s. Moving now where the model labels it moving and the centroid is heeded; not otherwise.
    def driving(rear: float, online: float) -> Track:
        return Track(0, [obs(k, 50.0 - (0.1 - rear) * k, 53.0 - rear * k, online) for k in range(22)])

    tracker.tracks = [driving(0.03, 0.9)]
    for centroid, moving in ((True, set(range(22))), (False, set())):
        labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig(instant_cue_centroid=centroid))
        assert labeler._moving_now(result) == {(k, 0) for k in moving}
    labeler = AutoLabeler(sensor_preset("hdl64"), AutolabelConfig())
    for track in (driving(0.03, 0.3),  # the model calls it static
                  Track(0, [obs(k, 50.0, 54.5, 0.9, 0.5 if k >= 20 else 0.0) for k in range(22)])):  # it waits
        tracker.tracks = [track]
        assert labeler._moving_now(result) == set()
    # 3 m beside the sensor (CUE_VIEW_DISTANCE): the view of it, not it, may have moved
    tracker.tracks = [Track(0, [dataclasses.replace(o, distance=3.0) for o in driving(0.03, 0.9).observations])]
    assert labeler._moving_now(result) == set()

    # A car that waits 10 scans, then moves off (centroid 0.5 m/s, box 0.1 m/s: its rear comes into view): moving now
    # as it drives where the model labelled it static while it waited; where the model labelled the waiting car
    # moving (a model that calls queues moving), its word on the driving does not count either.
    def waits_then_drives(waiting_online: float) -> Track:
        return Track(0, [obs(k, 50.0, 54.5, waiting_online) if k < 10 else
                         obs(k, 50.0 - 0.09 * (k - 10), 54.5 - 0.01 * (k - 10), 0.9) for k in range(22)])

    tracker.tracks = [waits_then_drives(0.1)]
    now = {k for k, _ in labeler._moving_now(result)}
    assert set(range(15, 22)) <= now and not now & set(range(10))
    tracker.tracks = [waits_then_drives(0.9)]
    assert labeler._moving_now(result) == set()


def test_an_object_whose_seen_through_part_lies_apart_from_the_rest_is_two():
    from ros2_mos.offline.autolabel import split_seen_apart

    def surface(x0: float, x1: float, y: float, z0: float = 0.2, z1: float = 1.5, step: float = 0.05) -> np.ndarray:
        """Points on the vertical face x0..x1 at y, every ``step`` m."""
        x, z = np.meshgrid(np.arange(x0, x1, step), np.arange(z0, z1, step))
        return np.stack([x.ravel(), np.full(x.size, y), z.ravel()], axis=1)

    # A parked car's side (y 2.2) and a cyclist 0.25 m beside it (y 1.95), one object; only the cyclist seen through.
    car, cyclist = surface(40.0, 44.5, 2.2), surface(41.0, 42.8, 1.95)
    world = np.concatenate([car, cyclist])
    seen = np.r_[np.zeros(len(car), bool), np.ones(len(cyclist), bool)]
    obj, n = split_seen_apart(world, np.zeros(len(world), np.int64), seen, 1, 0.1, 8)
    assert n == 2 and (obj[len(car):] == 1).all() and (obj[: len(car)] == 0).all()
    # A car that moves: its rear 1 m was seen through by a later scan, its front not; one surface, one object.
    side = surface(10.0, 14.5, 3.0)
    rear = side[:, 0] < 11.0
    obj, n = split_seen_apart(side, np.zeros(len(side), np.int64), rear, 1, 0.1, 8)
    assert n == 1 and (obj == 0).all()
    # Seen-through points scattered over a parked car (a few per cent, noise): no part of their own.
    rng = np.random.default_rng(0)
    obj, n = split_seen_apart(car, np.zeros(len(car), np.int64), rng.random(len(car)) < 0.05, 1, 0.1, 8)
    assert n == 1
    # A part that was seen through above another that was not (a roof line over a bonnet): they overlap from above.
    low, high = surface(20.0, 24.0, 5.0, 0.2, 0.6), surface(20.5, 23.5, 5.0, 1.0, 1.4)
    both = np.concatenate([low, high])
    obj, n = split_seen_apart(both, np.zeros(len(both), np.int64), np.r_[np.zeros(len(low), bool),
                                                                         np.ones(len(high), bool)], 1, 0.1, 8)
    assert n == 1


# -- hand-made drives -------------------------------------------------------------------------------------------
def test_a_car_that_waits_then_drives_is_moving_throughout_in_semantickitti_and_only_while_driving_in_instant(
        tmp_path):
    car = Mover((4.5, 1.8, 1.5), lambda k: (12.0 + max(0, k - 20) * 0.6, 4.0), 7)
    seq, share, others, _ = label_scene(tmp_path, 50, lambda k: 0.0, [car])
    for k in (0, 8, 14):  # waiting, long before it leaves
        assert share(k, 7, "semantickitti") > 0.8
        assert share(k, 7, "instant") < 0.05
    for k in (30, 38):
        assert share(k, 7, "semantickitti") > 0.6 and share(k, 7, "instant") > 0.6
    assert max(others(k, 7, "semantickitti") for k in range(50)) == 0


def test_a_car_that_waits_while_the_sensor_passes_it_closely_is_static_then_in_instant(tmp_path):
    # Arrives at 0.8 m per scan, waits at (20, 3) from scan 12 to 40 while the sensor drives past 2 m beside it (its
    # visible part, and so its centroid, slides as the view turns), then drives on.
    def path(k: int) -> tuple[float, float]:
        return (20.0 - 0.8 * max(0, 12 - k) + 0.8 * max(0, k - 40), 3.0)

    car = Mover((4.5, 1.8, 1.5), path, 7)
    seq, share, others, _ = label_scene(tmp_path, 52, lambda k: 0.8 * k, [car])
    for k in range(18, 35, 2):  # waiting, more than 5 scans from either motion, while the sensor passes (x 14-28)
        assert share(k, 7, "instant") < 0.05, k
        assert share(k, 7, "semantickitti") > 0.6, k


def test_a_pedestrian_who_stops_beside_a_wall(tmp_path):
    person = Mover((0.5, 0.5, 1.7), lambda k: (6.0 + min(k, 25) * 0.14, 6.5), 9)
    walls = [(-40, 80, 7.5, 8.0), (-40, 80, -13, -12)]  # a wall 0.75 m beside the person
    seq, share, others, _ = label_scene(tmp_path, 50, lambda k: 0.0, [person], walls)
    assert share(12, 9, "instant") > 0.5
    assert share(45, 9, "semantickitti") > 0.5 and share(45, 9, "instant") < 0.1
    for k in range(0, 50, 7):  # the wall is seen, and nothing but the person moves: not the wall, not the road
        assert (semantic_ids(seq[k].labels) == WALL).any() and others(k, 9, "semantickitti") == 0


def test_a_parked_car_passed_closely_stays_static(tmp_path):
    parked = Mover((4.5, 1.8, 1.5), lambda k: (20.0, 2.4), 5)
    seq, share, others, _ = label_scene(tmp_path, 40, lambda k: 1.0 * k, [parked])
    for k in range(0, 40, 3):
        assert share(k, 5, "semantickitti") == 0.0 and others(k, 5, "semantickitti") == 0


def test_a_wall_revealed_behind_a_mover_is_never_labelled_moving(tmp_path):
    car = Mover((4.5, 1.8, 1.5), lambda k: (-5.0 + 0.8 * k, 5.0), 3)
    walls = [(-10, 40, 8.0, 8.5), (-40, 80, -13, -12)]
    seq, share, others, (labeler, result, work) = label_scene(tmp_path, 40, lambda k: 0.0, [car], walls)
    for k in range(40):
        wall = semantic_ids(seq[k].labels) == WALL
        assert not scan_labels(labeler, result, work, k, "semantickitti")[wall].any()
    assert share(20, 3, "semantickitti") > 0.8 and share(20, 3, "instant") > 0.8


def test_a_bus_alongside_the_moving_sensor_is_found(tmp_path):
    bus = Mover((12.0, 2.5, 3.2), lambda k: (5.0 + 0.7 * k, -4.5), 4)
    seq, share, others, _ = label_scene(tmp_path, 60, lambda k: 0.5 * k, [bus])
    shares = [share(k, 4, "semantickitti") for k in range(0, 60, 5)]
    assert np.mean(shares) > 0.8, shares
    assert max(others(k, 4, "semantickitti") for k in range(0, 60, 5)) < 50


@pytest.mark.parametrize("ever_from_motion", [True, False])
def test_a_car_driving_ahead_at_the_sensor_s_speed_is_moving_to_the_drive_s_end(tmp_path, ever_from_motion):
    # The car hides its own next place from the sensor behind it, so only later scans see through where it was: its
    # last scans have no such scan. Its box travels 0.8 m a scan: moving (in both conventions) to the end; without
    # counting that motion (ever_from_motion False) its last scans fall to static, the case the rule is for.
    car = Mover((4.5, 1.8, 1.5), lambda k: (15.0 + 0.8 * k, 0.0), 6)
    seq, share, others, _ = label_scene(tmp_path, 40, lambda k: 0.8 * k, [car], ever_from_motion=ever_from_motion)
    last = [share(k, 6, "semantickitti") for k in range(33, 40)]
    if ever_from_motion:
        assert min(last) > 0.8, last
        assert min(share(k, 6, "instant") for k in range(33, 40)) > 0.8
        assert max(others(k, 6, "semantickitti") for k in range(0, 40, 3)) < 50
    else:
        assert min(last) < 0.2, last


# -- the command ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def jam(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("jam")
    result = runner.invoke(app, ["simulate", str(root), "--sequences", "00", "--scans", "30",
                                 "--preset", "traffic_jam", "--sensor", "vlp32c", "--seed", "5"])
    assert result.exit_code == 0, result.output
    return root


def test_autolabel_runs_kiss_icp_on_one_thread_so_that_a_drive_labelled_twice_gets_the_same_poses(monkeypatch):
    import kiss_icp.registration
    from kiss_icp.pybind import kiss_icp_pybind

    from ros2_mos.core.config import OdometryConfig
    from ros2_mos.core.odometry import KissIcpOdometry
    from ros2_mos.offline.autolabel import REPEATABLE_ODOMETRY
    from ros2_mos.offline.viewpoints import PairRegistration, PairRegistrationConfig

    threads = []
    for module, name in ((kiss_icp_pybind, "_Registration"), (kiss_icp.registration, "Registration")):
        real = getattr(module, name)

        def recording(*args, real=real, **kwargs):
            threads.append(kwargs.get("max_num_threads"))
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, recording)
    odometry = KissIcpOdometry(REPEATABLE_ODOMETRY)  # autolabel's poses: KISS-ICP's and both ICP slices on one thread
    assert len(threads) >= 2 and set(threads) == {1}
    assert AutoLabeler(sensor_preset("vlp32c")).odometry_config.threads == 1
    assert odometry._kiss.config.registration.max_num_threads == 1  # its preprocessing's too
    threads.clear()
    PairRegistration(PairRegistrationConfig(), (-5, 5))  # autolabel's pairs
    assert threads and set(threads) == {1}
    threads.clear()
    KissIcpOdometry(OdometryConfig())  # the node's: every core, as KISS-ICP's default
    assert len(threads) >= 2 and set(threads) == {0}
    for bad in (-1, 1.5, float("nan")):
        with pytest.raises(ConfigError, match="threads"):
            OdometryConfig(threads=bad)
        with pytest.raises(ConfigError, match="threads"):
            PairRegistrationConfig(threads=bad)


def test_the_first_kiss_icp_registration_the_autolabel_command_builds_asks_for_one_thread(jam, tmp_path):
    # KISS-ICP fixes its threads for the whole process when its first registration is built (a static TBB limit):
    # the command's must be autolabel's own, on one thread, for the poses to repeat to the bit.
    import subprocess
    import sys

    script = f"""
import json, sys
from kiss_icp.pybind import kiss_icp_pybind
real, asked = kiss_icp_pybind._Registration, []
def recording(*args, **kwargs):
    asked.append(kwargs.get("max_num_threads", args[2] if len(args) > 2 else None))
    return real(*args, **kwargs)
kiss_icp_pybind._Registration = recording
from ros2_mos.cli import app
try:
    app(["autolabel", {str(jam / "sequences" / "00")!r}, "--out", {str(tmp_path / "out")!r}, "--sensor", "vlp32c"])
except SystemExit:
    pass
print(json.dumps(asked))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    asked = __import__("json").loads(done.stdout.strip().splitlines()[-1])
    assert asked and asked[0] == 1, (asked, done.stderr[-2000:])
    assert (tmp_path / "out" / "sequences" / "00" / "poses.txt").is_file()


def test_tracks_built_once_are_decided_again_under_other_settings_as_labelling_again_would(jam, tmp_path):
    import copy
    import inspect
    import re

    from ros2_mos.offline.tracks import TRACKING_FIELDS, TrackConfig, Tracker

    drive = FolderDrive(jam / "sequences" / "00")
    default = AutoLabeler(sensor_preset("vlp32c"))
    (tmp_path / "tracked").mkdir()
    tracked = default.track(drive, tmp_path / "tracked")
    assert tracked.movers == {} and tracked.moving_ever == set() and tracked.moving_now == set()  # nothing decided
    # judged by stricter rules: a mover must be seen through in 90 % of its observations, and move 2 m/s now
    strict_config = AutolabelConfig(instant_speed=2.0, tracks=dataclasses.replace(TrackConfig(), moving_share=0.9))
    for labeler in (default, AutoLabeler(sensor_preset("vlp32c"), strict_config)):
        decided = labeler.decide(copy.deepcopy(tracked))
        work = tmp_path / f"again{len(list(tmp_path.iterdir()))}"
        work.mkdir()
        again = labeler.label(drive, work)  # the whole drive labelled again with the same settings
        assert decided.movers == again.movers and decided.movers
        assert decided.moving_ever == again.moving_ever and decided.moving_now == again.moving_now
        assert decided.tracker.config == labeler.config.tracks
        if labeler is default:
            loose = decided
    assert decided.movers != loose.movers and decided.moving_now != loose.moving_now  # the settings told
    # a setting read while the tracks are built cannot change afterwards
    with pytest.raises(ConfigError, match="gate 1.5 -> 3.0"):
        AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(tracks=TrackConfig(gate=3.0))).decide(
            copy.deepcopy(tracked))
    # the settings add_scan reads are the ones listed (a new one read there must be listed too)
    assert set(re.findall(r"cfg\.(\w+)", inspect.getsource(Tracker.add_scan))) == set(TRACKING_FIELDS)


@pytest.mark.parametrize("convention", ["semantickitti", "instant"])
def test_autolabel_end_to_end_on_a_simulated_drive(jam, tmp_path, convention):
    out = tmp_path / "auto"
    result = runner.invoke(app, ["autolabel", str(jam / "sequences" / "00"), "--out", str(out),
                                 "--convention", convention, "--png"])
    assert result.exit_code == 0, result.output
    assert "online cue vlp32c.onnx" in result.output  # the model shipped for the drive's sensor
    seq_out = out / "sequences" / "00"
    assert (seq_out / "label_convention.txt").read_text().strip() == convention
    assert len(list((seq_out / "predictions").glob("*.label"))) == 30
    assert (seq_out / "movers.png").stat().st_size > 1000 and (seq_out / "poses.txt").is_file()
    rows = (seq_out / "objects.csv").read_text().splitlines()
    assert rows[0].startswith("id,first_scan,last_scan") and len(rows) > 3
    assert not [p for p in (out / "sequences").iterdir() if p.name.startswith(".")]  # no partial output left
    result = runner.invoke(app, ["eval", str(out), str(jam), "--convention", convention])
    assert result.exit_code == 0, result.output
    iou = float(next(line.split()[1] for line in result.output.splitlines() if line.startswith("       all")))
    assert iou > 55.0, result.output  # 30 scans: less past and future than a real drive has


def test_points_on_no_object_near_a_mover_that_the_online_model_labels_moving_are_moving_too(jam, tmp_path):
    from ros2_mos.core.config import sensor_preset

    drive = FolderDrive(jam / "sequences" / "00")
    runs = {}
    for reach in (0.0, 2.0):
        work = tmp_path / str(reach)
        work.mkdir()
        labeler = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(cue_attach=reach))
        runs[reach] = labeler, labeler.label(drive, work), work
    added = 0
    for k, scan in enumerate(drive):
        labels = {reach: scan_labels(*runs[reach], k, "instant") for reach in runs}
        assert not (labels[0.0] & ~labels[2.0]).any()  # it only adds
        new = np.flatnonzero(labels[2.0] & ~labels[0.0])
        added += len(new)
        objects = np.load(runs[0.0][2] / f"{k:06d}.npy")
        assert (objects[new] < 0).all()  # points on no object, ...
        moving = scan.points[labels[0.0], :2]
        if len(new):  # ... each within 2 m of a moving point, seen from above
            gap = np.linalg.norm(scan.points[new, None, :2] - moving[None], axis=-1).min(axis=1)
            assert gap.max() <= 2.0 + 1e-5
    assert added > 0


def test_kiss_icp_runs_backwards_too_over_clouds_it_keeps_only_while_it_needs_them(jam, tmp_path, monkeypatch):
    import ros2_mos.offline.autolabel as autolabel_module
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import progress_steps

    drive = FolderDrive(jam / "sequences" / "00")
    config = AutolabelConfig(online_cue=False, odometry_prefer="forward")
    runs = {}
    for stood in (True, False):  # the sensor stood and moved off, or not: the backward pass runs, or not
        monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps, stood=stood: stood)
        stages: dict[str, int] = {}

        def count(stage: str, n: int, stages=stages) -> None:
            stages[stage] = stages.get(stage, 0) + n

        work = tmp_path / str(stood)
        work.mkdir()
        runs[stood] = AutoLabeler(sensor_preset("vlp32c"), config).label(drive, work, count)
        assert stages == {"poses": 30, "backward": 30, "objects": 30}  # the bar fills either way
        assert not list(work.glob("kiss*.npy"))  # the clouds kept for the backward pass are gone
    assert progress_steps(30, config) == 4 * 30
    assert runs[True].odometry_followed == "f"  # run, and the passes agree on this drive
    assert runs[False].odometry_followed == ""  # not run
    np.testing.assert_allclose(runs[True].poses, runs[False].poses)  # the forward pass's poses either way
    monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps: True)
    work = tmp_path / "prefer"
    work.mkdir()
    backward = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(online_cue=False)).label(drive, work)
    assert backward.odometry_followed == "b"  # by default the backward pass, where neither is clearly farther
    assert np.abs(backward.poses[:, :3, 3] - runs[True].poses[:, :3, 3]).max() < 0.3  # they agree here
    one_pass = AutolabelConfig(online_cue=False, backward_odometry=False)
    assert progress_steps(30, one_pass) == 3 * 30
    # where the backward pass is taken, the command says so
    monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps: True)
    monkeypatch.setattr(autolabel_module, "farther_pass", lambda forward, backward, *margins, **prefer: (backward, "b"))
    out = runner.invoke(app, ["autolabel", str(jam / "sequences" / "00"), "--out", str(tmp_path / "o")])
    assert out.exit_code == 0 and "KISS-ICP run backwards" in out.output, out.output


def test_autolabel_refuses_bad_input_with_one_line_and_writes_nothing(jam, tmp_path):
    out = tmp_path / "o"
    empty = tmp_path / "empty" / "velodyne"
    empty.mkdir(parents=True)
    one = tmp_path / "one"
    (one / "velodyne").mkdir(parents=True)
    src = jam / "sequences" / "00" / "velodyne" / "000000.bin"
    (one / "velodyne" / "000000.bin").write_bytes(src.read_bytes())
    for drive, message in ((empty.parent, "no .bin scans"), (one, "at least 2"),
                           (tmp_path / "missing", "drive not found"), (tmp_path, "neither a SemanticKITTI")):
        result = runner.invoke(app, ["autolabel", str(drive), "--out", str(out), "--sensor", "vlp32c"])
        assert result.exit_code != 0 and message in str(result.exception) + result.output, (drive, result.output)
    result = runner.invoke(app, ["autolabel", str(jam / "sequences" / "00"), "--out", str(out),
                                 "--convention", "moving"])
    assert result.exit_code != 0 and "unknown --convention" in result.output
    assert not out.exists()
    # mixed sensors: VLP-16 scans among the VLP-32C ones
    mixed = tmp_path / "mixed"
    (mixed / "velodyne").mkdir(parents=True)
    for i in range(12):
        (mixed / "velodyne" / f"{i:06d}.bin").write_bytes(
            (jam / "sequences" / "00" / "velodyne" / f"{i:06d}.bin").read_bytes())
    runner.invoke(app, ["simulate", str(tmp_path / "v16"), "--sequences", "00", "--scans", "12", "--preset", "easy",
                        "--sensor", "vlp16"])
    for i in range(12, 24):
        (mixed / "velodyne" / f"{i:06d}.bin").write_bytes(
            (tmp_path / "v16" / "sequences" / "00" / "velodyne" / f"{i - 12:06d}.bin").read_bytes())
    result = runner.invoke(app, ["autolabel", str(mixed), "--out", str(out), "--sensor", "vlp32c"])
    assert result.exit_code != 0 and "does not fit the configured sensor" in str(result.exception)
    assert not out.exists()
    # a scan with no finite point (a driver's dropout) among them: named, nothing written
    dropout = tmp_path / "dropout"
    shutil.copytree(jam / "sequences" / "00" / "velodyne", dropout / "velodyne")
    scan = read_scan(dropout / "velodyne" / "000005.bin")
    write_scan(dropout / "velodyne" / "000005.bin", np.full_like(scan[:, :3], np.nan), scan[:, 3])
    result = runner.invoke(app, ["autolabel", str(dropout), "--out", str(out), "--sensor", "vlp32c"])
    assert result.exit_code != 0 and "dropout scan 5 (000005): no finite points" in str(result.exception)
    assert not (out / "sequences").exists() and not out.exists()  # not even an empty OUT/sequences/
    # an existing output
    (out / "sequences" / "00").mkdir(parents=True)
    result = runner.invoke(app, ["autolabel", str(jam / "sequences" / "00"), "--out", str(out)])
    assert result.exit_code != 0 and "already exists" in result.output


def test_a_bag_without_pointcloud2_is_refused(tmp_path):
    from ros2_mos.io.bags import BagWriter, header, msg_class

    bag = tmp_path / "strings"
    with BagWriter(bag) as writer:
        msg = msg_class("std_msgs/msg/Header")
        writer.write("/header", 1, header(1, "x") if msg else None)
    with pytest.raises(DatasetError, match="PointCloud2"):
        from ros2_mos.offline.drives import open_drive

        open_drive(bag)


def test_labels_in_the_drive_are_read_by_nobody_but_eval(tmp_path):
    """autolabel uses no label: the same scans without labels/ give the same predictions."""
    car = Mover((4.5, 1.8, 1.5), lambda k: (10.0 + 0.5 * k, 4.0), 2)
    folder = write_drive(tmp_path, 20, lambda k: 0.0, [car], WALLS)
    import shutil

    for sub in ("labels", "labels_instant"):
        shutil.rmtree(folder / sub)
    labeler = AutoLabeler(SENSOR, AutolabelConfig(use_poses=True))
    (tmp_path / "w").mkdir()
    result = labeler.label(FolderDrive(folder), tmp_path / "w")
    assert result.movers  # labels gone, movers still found


def test_map_cleans_with_autolabel_s_labels(jam, tmp_path):
    """`map --labels` builds the cleaned map from autolabel's labels and poses: fewer ghosts than the raw map."""
    out = tmp_path / "auto"
    assert runner.invoke(app, ["autolabel", str(jam / "sequences" / "00"), "--out", str(out)]).exit_code == 0
    result = runner.invoke(app, ["map", str(jam / "sequences" / "00"), "--out", str(tmp_path / "m.ply"),
                                 "--labels", str(out)])
    assert result.exit_code == 0, result.output
    ghosts = {line.split()[0]: float(line.split()[2]) for line in result.output.splitlines()
              if line.split()[:1] in (["raw"], ["cleaned"])}
    assert ghosts["cleaned"] < 0.5 * ghosts["raw"], result.output
    assert (tmp_path / "m_cleaned.ply").is_file()
    result = runner.invoke(app, ["map", str(jam / "sequences" / "00"), "--out", str(tmp_path / "n.ply"),
                                 "--labels", str(tmp_path / "nothing")])
    assert result.exit_code != 0 and "predictions" in str(result.exception)


def test_every_stored_point_gets_a_label_also_non_finite_and_zero_ones(tmp_path):
    """Scans with NaN rows and points at the origin: one label per stored point, those static."""
    from ros2_mos.io.semantic_kitti import read_label, read_scan, write_scan

    car = Mover((4.5, 1.8, 1.5), lambda k: (8.0 + 0.6 * k, 4.0), 2)
    folder = write_drive(tmp_path, 12, lambda k: 0.0, [car], WALLS)
    for k in (0, 5):
        path = folder / "velodyne" / f"{k:06d}.bin"
        scan = read_scan(path)
        bad = np.array([[np.nan, 1.0, 1.0, 0.1], [0.0, 0.0, 0.0, 0.2], [np.inf, 0.0, 0.0, 0.0]], np.float32)
        scan = np.vstack([bad, scan, bad])
        write_scan(path, scan[:, :3], scan[:, 3])
    out = tmp_path / "out"
    result = runner.invoke(app, ["autolabel", str(folder), "--out", str(out), "--use-poses", "--sensor", "vlp32c"])
    assert result.exit_code == 0, result.output
    for k in (0, 5, 7):
        n = len(read_scan(folder / "velodyne" / f"{k:06d}.bin"))
        labels = read_label(out / "sequences" / "scene" / "predictions" / f"{k:06d}.label", n)
        if k in (0, 5):
            assert (labels[:3] == 9).all() and (labels[-3:] == 9).all()


def test_use_poses_takes_semantickitti_s_seven_digit_poses(tmp_path):
    """Poses written as SemanticKITTI writes them (%e: seven significant digits) of a sensor that turns as it drives:
    the pair registration starts from them (it aborted the process on rotations off by 1e-10)."""
    from ros2_mos.io.semantic_kitti import read_label, read_scan, write_scan

    car = Mover((4.5, 1.8, 1.5), lambda k: (8.0 + 0.6 * k, 4.0), 2)
    folder = write_drive(tmp_path, 12, lambda k: 0.3 * k, [car], WALLS)
    lidar = read_poses(folder / "poses.txt", KITTI_TR)
    for k in range(12):  # the sensor turned by 0.05 k rad: the same world points, seen from the turned sensor
        c, s = np.cos(0.05 * k), np.sin(0.05 * k)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        lidar[k, :3, :3] = lidar[k, :3, :3] @ turn
        scan = read_scan(folder / "velodyne" / f"{k:06d}.bin")
        write_scan(folder / "velodyne" / f"{k:06d}.bin", (scan[:, :3] @ turn).astype(np.float32), scan[:, 3])
    camera = KITTI_TR @ lidar @ np.linalg.inv(KITTI_TR)
    np.savetxt(folder / "poses.txt", camera[:, :3].reshape(-1, 12), fmt="%e")
    result = runner.invoke(app, ["autolabel", str(folder), "--out", str(tmp_path / "out"), "--use-poses",
                                 "--sensor", "vlp32c"])
    assert result.exit_code == 0, result.output
    written = read_poses(tmp_path / "out" / "sequences" / "scene" / "poses.txt", KITTI_TR)
    np.testing.assert_allclose(written, lidar, atol=1e-5)
    found = truth = 0
    for k in range(12):  # the car is found from the turned, rounded poses
        n = len(read_scan(folder / "velodyne" / f"{k:06d}.bin"))
        moving = semantic_ids(read_label(folder / "labels" / f"{k:06d}.label", n)) >= 251
        labelled = read_label(tmp_path / "out" / "sequences" / "scene" / "predictions" / f"{k:06d}.label", n) == 251
        found, truth = found + int((moving & labelled).sum()), truth + int(moving.sum())
    assert truth > 1000 and found > 0.95 * truth


def test_a_drive_scan_keeps_the_finite_points_with_a_range_and_says_where_they_sat():
    points = np.array([[1, 0, 0], [np.nan, 0, 0], [0, 0, 0], [0, np.inf, 1], [2e19, 0, 0], [0, 3, 4]], np.float32)
    intensity = np.arange(6, dtype=np.float32)
    scan = _scan(7, 0.5, points, intensity)
    assert scan.kept.tolist() == [0, 5] and scan.stored == 6  # NaN, zero range, inf, overflowing range dropped
    assert scan.points.tolist() == [[1, 0, 0], [0, 3, 4]] and scan.intensity.tolist() == [0, 5]
    assert scan.points.flags.c_contiguous and scan.points.dtype == np.float32
    clean = _scan(0, 0.0, points[[0, 5]], intensity[[0, 5]])  # nothing to drop: every point, in order
    assert clean.kept.tolist() == [0, 1] and clean.points.tolist() == [[1, 0, 0], [0, 3, 4]]


def test_deskewing_a_skewed_drive_drops_the_static_points_it_calls_moving(tmp_path):
    """A simulated VLP-32C drive whose sweeps are skewed (``--intra-sweep-motion``, as real sweeps are): static
    points seen through by scans far apart because each sweep is bent by the drive. Deskewed, autolabel calls a
    quarter as many static points moving under SemanticKITTI's convention (measured: 804 -> 210). ``--deskew auto``
    (the default) deskews because the folder's sweep.txt says skewed; ``off`` does not; the summary says which."""
    result = runner.invoke(app, ["simulate", str(tmp_path / "sim"), "--sequences", "00", "--scans", "40", "--preset",
                                 "easy", "--sensor", "vlp32c", "--seed", "5", "--intra-sweep-motion"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "sim" / "sequences" / "00" / "sweep.txt").read_text().strip() == "skewed"
    false_moving = {}
    for mode in ("auto", "off"):
        out = tmp_path / mode
        result = runner.invoke(app, ["autolabel", str(tmp_path / "sim" / "sequences" / "00"), "--out", str(out),
                                     "--deskew", mode])
        assert result.exit_code == 0, result.output
        assert ("scans deskewed" in result.output) == (mode == "auto")
        result = runner.invoke(app, ["eval", str(out), str(tmp_path / "sim"), "--convention", "semantickitti"])
        assert result.exit_code == 0, result.output
        false_moving[mode] = int(next(line.split()[3] for line in result.output.splitlines()
                                      if line.startswith("       all")))
    assert false_moving["auto"] < 0.5 * false_moving["off"], false_moving
    # The labels say how they took the sweeps, and `map --labels` builds its maps from the scans deskewed alike.
    for mode, word in (("auto", "skewed"), ("off", "compensated")):
        assert (tmp_path / mode / "sequences" / "00" / "sweep.txt").read_text().strip() == word
        result = runner.invoke(app, ["map", str(tmp_path / "sim" / "sequences" / "00"), "--out",
                                     str(tmp_path / f"map_{mode}.ply"), "--labels", str(tmp_path / mode)])
        assert result.exit_code == 0, result.output
        assert ("40 scans, deskewed" in result.output) == (mode == "auto"), result.output
    # The same drive as a bag whose clouds carry each point's time in ns (an Ouster driver's ``t``; here the firing
    # times the simulator cast the columns at): 'auto' deskews it by those times, to the same labels within a few
    # points.
    from ros2_mos.io.bags import BagWriter, empty_cloud, point_field
    from ros2_mos.io.pointcloud2 import fill_from_records

    timed = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("t", "<u4")])
    with BagWriter(tmp_path / "bag" / "00") as writer:
        for k, frame in enumerate(SemanticKittiSequence(tmp_path / "sim" / "sequences" / "00")):
            records = np.zeros(len(frame.points), timed)
            for i, axis in enumerate("xyz"):
                records[axis] = frame.points[:, i]
            azimuth = np.arctan2(frame.points[:, 1], frame.points[:, 0])
            records["t"] = np.round((0.5 - azimuth / (2 * np.pi)) * 1e8)  # behind, clockwise: 0 .. 100 ms
            stamp = 1_000_000_000 + k * 100_000_000
            writer.write("/points", stamp, fill_from_records(empty_cloud(stamp, "os_sensor"), records,
                                                             field_factory=point_field))
    result = runner.invoke(app, ["autolabel", str(tmp_path / "bag" / "00"), "--out", str(tmp_path / "from_bag"),
                                 "--sensor", "vlp32c"])
    assert result.exit_code == 0 and "scans deskewed" in result.output, result.output
    result = runner.invoke(app, ["eval", str(tmp_path / "from_bag"), str(tmp_path / "sim"), "--convention",
                                 "semantickitti"])
    fp_bag = int(next(line.split()[3] for line in result.output.splitlines() if line.startswith("       all")))
    assert abs(fp_bag - false_moving["auto"]) <= max(50, 0.2 * false_moving["auto"]), (fp_bag, false_moving)
    # `map` takes the bag too, with its labels, deskewed by the clouds' own times: about the folder's maps.
    raw_points = {}
    for name, drive, labels in (("bag", tmp_path / "bag" / "00", tmp_path / "from_bag"),
                                ("folder", tmp_path / "sim" / "sequences" / "00", tmp_path / "auto")):
        result = runner.invoke(app, ["map", str(drive), "--out", str(tmp_path / f"map_{name}_again.ply"),
                                     "--labels", str(labels)])
        assert result.exit_code == 0 and "40 scans, deskewed" in result.output, result.output
        raw_points[name] = next(int(line.split()[1]) for line in result.output.splitlines()
                                if line.split()[:1] == ["raw"])
    assert abs(raw_points["bag"] - raw_points["folder"]) <= 0.02 * raw_points["folder"], raw_points


def test_deskew_auto_follows_the_drive_s_word_and_on_off_override_it(jam, tmp_path):
    """The jam was simulated without intra-sweep motion: its sweep.txt says compensated, so 'auto' leaves it; a
    folder without sweep.txt (real data) is left too; 'on' deskews either. An unknown mode or sweep.txt word is one
    clear line."""
    folder = jam / "sequences" / "00"
    assert (folder / "sweep.txt").read_text().strip() == "compensated"
    assert FolderDrive(folder).skewed is False
    bare = tmp_path / "bare"
    shutil.copytree(folder, bare)
    (bare / "sweep.txt").unlink()
    assert FolderDrive(bare).skewed is None
    sensor = sensor_preset("vlp32c")
    assert not AutoLabeler(sensor).deskews(FolderDrive(folder))
    assert not AutoLabeler(sensor).deskews(FolderDrive(bare))
    assert AutoLabeler(sensor, AutolabelConfig(deskew="on")).deskews(FolderDrive(bare))
    assert not AutoLabeler(sensor, AutolabelConfig(deskew="off")).deskews(FolderDrive(folder))
    # The command says when it had to take a drive's sweeps as compensated because nothing said otherwise.
    for folder_, says in ((bare, True), (folder, False)):
        result = runner.invoke(app, ["autolabel", str(folder_), "--out", str(tmp_path / f"out_{says}")])
        assert result.exit_code == 0, result.output
        assert ("sweeps taken as compensated" in result.output) == says, result.output
    (bare / "sweep.txt").write_text("wobbly\n")
    with pytest.raises(DatasetError, match="sweep.txt.*'wobbly'"):
        FolderDrive(bare)
    result = runner.invoke(app, ["autolabel", str(folder), "--out", str(tmp_path / "out"), "--deskew", "yes"])
    assert result.exit_code != 0 and "unknown --deskew 'yes'" in result.output
    assert not (tmp_path / "out").exists()


def test_pairs_and_cue_in_processes_of_their_own_label_as_in_this_one(jam, tmp_path):
    """The traffic jam (30 scans) with its scan pairs registered and its online cue computed in processes of their
    own and in this one: the same labels; an interruption midway stops both processes."""
    from ros2_mos.core import worker

    drive = FolderDrive(jam / "sequences" / "00")
    labels = {}
    for processes_from in (1, 0):
        labeler = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(processes_from=processes_from))
        work = tmp_path / f"work{processes_from}"
        work.mkdir()
        result = labeler.label(drive, work)
        labels[processes_from] = [scan_labels(labeler, result, work, k, "semantickitti") for k in range(len(drive))]
        assert result.cue_model == "vlp32c.onnx"
    assert sum(int(m.sum()) for m in labels[0]) > 1000
    for there, here in zip(labels[1], labels[0]):
        np.testing.assert_array_equal(there, here)

    started = []

    class Watched(worker.Worker):
        def __init__(self, *args):
            super().__init__(*args)
            started.append(self)

    def interrupt(stage: str, n: int) -> None:
        if stage == "objects":
            raise KeyboardInterrupt

    original = worker.Worker
    modules = ("viewpoints", "cue", "kiss_passes")
    for module in modules:
        setattr(importlib.import_module(f"ros2_mos.offline.{module}"), "Worker", Watched)
    try:
        labeler = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(processes_from=1))
        (tmp_path / "interrupted").mkdir()
        with pytest.raises(KeyboardInterrupt):
            labeler.label(drive, tmp_path / "interrupted", interrupt)
        assert sorted(w.name for w in started) == ["backward KISS-ICP pass", "online cue", "pair registration"]
        assert all(w.returncode is not None for w in started)  # stopped, not left running
        # stopped midway through the forward pass: the backward one, in its process meanwhile, stops with it
        started.clear()
        (tmp_path / "poses").mkdir()

        def interrupt_poses(stage: str, n: int, seen=[]) -> None:
            seen.append(stage)
            if len(seen) == 12:
                raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            labeler.label(drive, tmp_path / "poses", interrupt_poses)
        assert "backward KISS-ICP pass" in [w.name for w in started]
        assert all(w.returncode is not None for w in started)
        assert not list((tmp_path / "poses").glob("kiss*.npy"))  # its kept clouds are gone too
    finally:
        for module in modules:
            setattr(importlib.import_module(f"ros2_mos.offline.{module}"), "Worker", original)


def test_a_backward_pass_process_that_dies_is_one_line_naming_it(jam, tmp_path):
    from ros2_mos.core.errors import WorkerError
    from ros2_mos.offline.autolabel import REPEATABLE_ODOMETRY
    from ros2_mos.offline.kiss_passes import BackwardPass

    killed = BackwardPass(FolderDrive(jam / "sequences" / "00"), REPEATABLE_ODOMETRY, tmp_path)
    try:
        killed._worker._process.kill()  # as the kernel's OOM killer would
        with pytest.raises(WorkerError, match="backward KISS-ICP pass process ended without its result"):
            killed.poses()
    finally:
        killed.close()
    assert killed._worker.returncode is not None


def test_the_backward_pass_beside_the_forward_one_gives_the_poses_it_gives_after_it(jam, tmp_path, monkeypatch):
    """The backward KISS-ICP pass in a process of its own, reading the drive itself while the forward pass runs,
    and the same pass run here afterwards over the clouds the forward one kept: the same poses. A drive that cannot
    go to another process (it does not pickle) has its backward pass here."""
    import ros2_mos.offline.autolabel as autolabel_module
    from ros2_mos.offline.kiss_passes import BackwardPass

    monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps: True)
    monkeypatch.setattr(autolabel_module, "farther_pass", lambda forward, backward, *margins, **prefer: (backward, "b"))
    drive = FolderDrive(jam / "sequences" / "00")
    started = []
    real_start = BackwardPass.start

    def start(*args):
        started.append(real_start(*args))
        return started[-1]

    monkeypatch.setattr(BackwardPass, "start", start)
    poses = {}
    for processes_from in (1, 0):
        work = tmp_path / f"work{processes_from}"
        work.mkdir()
        labeler = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(processes_from=processes_from,
                                                                        online_cue=False))
        result = labeler.label(drive, work)
        assert result.odometry_followed == "b"
        poses[processes_from] = result.poses
        assert not list(work.glob("kiss*.npy"))
    assert len(started) == 1 and started[0].going  # beside the forward pass once, not here
    # to the bit where this process runs KISS-ICP on one thread, as the command does (benchmarks/autolabel.md, round
    # 52: label files identical); in pytest's process, which built KISS-ICP on every core first (round 51), its sums
    # may add up in another order: 1e-15 apart. Other clouds would be millimetres apart.
    np.testing.assert_allclose(poses[1], poses[0], rtol=0, atol=1e-9)

    # a drive on which the sensor never stood: the process only reads it, is never told to register, and stops
    monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps: False)
    (tmp_path / "never").mkdir()
    result = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(processes_from=1, online_cue=False)).label(
        drive, tmp_path / "never")
    assert result.odometry_followed == "" and not started[-1].going
    assert started[-1]._worker.returncode is not None
    assert not list((tmp_path / "never").glob("kiss*.npy"))

    class Unpicklable(FolderDrive):
        def __init__(self, root):
            super().__init__(root)
            self.on_the_side = lambda: None  # a lambda does not pickle

    monkeypatch.setattr(autolabel_module, "starts_from_rest", lambda poses, stamps: True)
    # a bag: the process reads it itself too
    from ros2_mos.offline.drives import BagDrive

    made = runner.invoke(app, ["simulate", str(tmp_path / "sim"), "--sequences", "00", "--scans", "16", "--preset",
                               "traffic_jam", "--sensor", "vlp32c", "--seed", "5", "--bag"])
    assert made.exit_code == 0, made.output
    bag_poses = []
    for processes_from in (1, 0):
        work = tmp_path / f"bag{processes_from}"
        work.mkdir()
        bag_poses.append(AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(
            processes_from=processes_from, online_cue=False)).label(BagDrive(tmp_path / "sim" / "bags" / "00"),
                                                                    work).poses)
    assert isinstance(started[-1], BackwardPass) and started[-1].going
    np.testing.assert_allclose(bag_poses[0], bag_poses[1], rtol=0, atol=1e-9)
    work = tmp_path / "unpicklable"
    work.mkdir()
    result = AutoLabeler(sensor_preset("vlp32c"), AutolabelConfig(processes_from=1, online_cue=False)).label(
        Unpicklable(jam / "sequences" / "00"), work)
    assert started[-1] is None  # not in a process of its own
    np.testing.assert_allclose(result.poses, poses[0], rtol=0, atol=1e-9)


def test_find_objects_finds_the_same_objects_on_the_compiled_kernels_and_the_numpy_code(jam):
    # The jam's VLP-32C scans: their clusters and the points their columns attach (attach_below, attach_over), both
    # ways, must be the same ids; the scene has both kinds of attachment (a test that can fail).
    from ros2_mos.core import kernels
    from ros2_mos.offline.drives import open_drive

    if not kernels.enabled():
        pytest.fail(f"the compiled kernels are not in use here: {kernels.status()} (make install builds them)")
    sensor = sensor_preset("vlp32c")
    drive = open_drive(jam / "sequences" / "00")
    attached = 0
    for k, scan in enumerate(drive):
        if k % 6:
            continue
        compiled = find_objects(scan.points, ObjectConfig(), None, sensor)
        with kernels.disabled():
            reference = find_objects(scan.points, ObjectConfig(), None, sensor)
        np.testing.assert_array_equal(compiled.point_object, reference.point_object)
        np.testing.assert_array_equal(compiled.attached, reference.attached)
        assert compiled.n_objects == reference.n_objects > 3
        attached += int(compiled.attached.sum())
    assert attached > 100


def test_a_mover_on_the_online_model_s_word_moves_now_only_where_the_rules_for_every_mover_say_so_too():
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.offline.autolabel import AutolabelConfig, AutoLabeler, AutolabelResult
    from ros2_mos.offline.tracks import ONLINE_MODEL, Observation, Track, Tracker

    def obs(scan: int, x: float, online: float) -> Observation:
        lo, hi = np.array([x, 2.0, 0.0]), np.array([x + 4.5, 3.8, 1.5])
        return Observation(scan, 0, (lo + hi) / 2, 40, lo, hi, 0.0, 0.0, online)

    # A car 50 m away, never seen through, waits at x 50 (scans 0-9), then drives on at 0.25 m a scan (scans 10-29);
    # the model labels all of it moving. By hand, its box over +-5 observations (instant_span, 0.1 s a
    # scan): scan 5 spans x 50 -> 50.25 in 1 s (0.25 m/s < instant_speed 0.4), scan 6 50 -> 50.5 (0.5 m/s), scan
    # 29 (the last) 53.75 -> 55 in 0.5 s: moving now from scan 6 on, not while it waits.
    def car(online: float) -> Track:
        return Track(0, [obs(k, 50.0 + 0.25 * max(k - 9, 0), online) for k in range(30)])

    tracker = Tracker()
    tracker.tracks = [car(0.9)]
    result = AutolabelResult("waits then drives", 30, np.repeat(np.eye(4)[None], 30, 0), np.arange(30) * 0.1, tracker,
                             {0: ONLINE_MODEL}, [40] * 30)
    labeler = AutoLabeler(sensor_preset("vlp16"), AutolabelConfig())
    assert labeler._moving_now(result) == {(k, 0) for k in range(6, 30)}
    assert labeler._moving_ever(result) == {(k, 0) for k in range(30)}  # SemanticKITTI's: moving throughout
    # where the model calls it static it is not moving now, however it travels
    tracker.tracks = [Track(0, [obs(o.scan, o.lo[0], 0.9 if o.scan < 20 else 0.3) for o in car(0.9).observations])]
    assert labeler._moving_now(result) == {(k, 0) for k in range(6, 20)}
    # without the rule: the model's word alone, its waiting scans too
    tracker.tracks = [car(0.9)]
    word_alone = AutoLabeler(sensor_preset("vlp16"), AutolabelConfig(instant_cue_motion=False))
    assert word_alone._moving_now(result) == {(k, 0) for k in range(30)}
    # A car that waits at x 48-52.5 as the sensor passes 3-5 m beside it: its box stands still, its centroid slides
    # 0.2 m a scan (2 m/s) as the view of it changes, and the model calls it moving. Not moving now (the centroid
    # rule that movers seen through have is not theirs) ...
    passed = Track(0, [dataclasses.replace(obs(k, 48.0, 0.9), centroid=np.array([48.5 + 0.2 * k, 2.9, 0.75]),
                                           distance=4.0) for k in range(30)])
    tracker.tracks = [passed]
    assert labeler._moving_now(result) == set()
    assert word_alone._moving_now(result) == {(k, 0) for k in range(30)}
    # ... but where a near scan saw through it (the rule for every mover), it is
    tracker.tracks = [Track(0, [dataclasses.replace(o, near=0.5 if o.scan >= 25 else 0.0)
                                for o in passed.observations])]
    assert labeler._moving_now(result) == {(k, 0) for k in range(25, 30)}
