"""The simulator: ray casting by hand, written files, labels against the world's truth, poses, determinism."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ros2_mos.core.config import SENSOR_PRESETS, SensorConfig
from ros2_mos.core.errors import ConfigError
from ros2_mos.io.conventions import label_dirs, main_convention
from ros2_mos.io.labels import MOVING_IDS, instance_ids, semantic_ids
from ros2_mos.io.semantic_kitti import KITTI_TR, SemanticKittiSequence, read_label, read_poses
from ros2_mos.sim import SequenceSimulator, format_stats, sequence_dir, sim_preset, simulate_sequence, with_effects
from ros2_mos.sim.geometry import TriangleSoup, box, quad
from ros2_mos.sim.lidar import Lidar, beam_elevations
from ros2_mos.sim.motion import Stop, simulate_profile
from ros2_mos.sim.presets import SensorEffects
from ros2_mos.sim.raycast import SoupScene, cast_nearest
from ros2_mos.sim.road import Path as RoutePath
from ros2_mos.sim.terrain import Terrain

SMALL = SensorConfig("small", 32, 512, 10.0, -25.0, 0.0, 120.0)
NO_NOISE = SensorEffects(range_sigma=0.0, dropout=0.0, grazing_dropout=0.0, far_dropout=0.0, remission_sigma=0.0,
                         ego_clearance=0.0)


# -- ray casting and the sensor by hand ---------------------------------------------------------------


def test_ray_cast_hits_a_box_and_a_plane_at_the_analytic_distance() -> None:
    ground = TriangleSoup.labelled(quad(-50, -50, 50, 50, 0.0), 40)
    wall = TriangleSoup.labelled(box((1.0, 4.0, 4.0), (10.5, 0.0, 2.0)), 50, inst=7)
    origin = np.array([0.0, 0.0, 1.0])
    dirs = np.array(
        [[1.0, 0.0, 0.0], [0.0, 1.0, -1.0] / np.sqrt(2), [0.0, 0.0, 1.0], [10.0, 1.0, 2.0] / np.sqrt(105.0)]
    )
    hits = cast_nearest([SoupScene(ground, origin * 0), SoupScene(wall, np.array([100.0, 0.0, 0.0]))], origin, dirs)
    # front face of the box at x = 10; the ground 1 m below at 45 degrees; nothing above; (10, 1, 3) on the face
    assert hits.distance[0] == pytest.approx(10.0, abs=1e-4)
    assert hits.soup[0] == 1 and wall.inst[hits.triangle[0]] == 7
    assert hits.distance[1] == pytest.approx(np.sqrt(2.0), abs=1e-4) and hits.soup[1] == 0
    assert np.isinf(hits.distance[2]) and hits.triangle[2] == -1
    assert hits.distance[3] == pytest.approx(np.sqrt(105.0), abs=1e-4) and hits.soup[3] == 1
    assert np.allclose(np.abs(hits.normal[0]), [1, 0, 0], atol=1e-6)


def test_noise_free_lidar_sees_the_ground_at_the_sensor_height() -> None:
    ground = TriangleSoup.labelled(quad(-500, -500, 500, 500, 0.0), 40)
    lidar = Lidar(SMALL, NO_NOISE)
    pose = Terrain.flat().vehicle_pose(np.array([3.0]), np.array([-2.0]), np.array([0.3]), NO_NOISE.sensor_height)[0]
    scan = lidar.scan([SoupScene(ground, np.zeros(3))], pose, np.random.default_rng(0))
    down = beam_elevations(SMALL) < np.radians(-0.6)  # beams that meet the ground within 120 m
    assert len(scan.points) == down.sum() * SMALL.width
    assert np.allclose(scan.points[:, 2], -NO_NOISE.sensor_height, atol=1e-4)
    assert (scan.sem == 40).all() and (scan.inst == 0).all()


def test_hdl64_layout_and_point_count_are_plausible() -> None:
    el = np.degrees(beam_elevations(SENSOR_PRESETS["hdl64"]))
    assert len(el) == 64 and el[0] == pytest.approx(2.0) and el[-1] == pytest.approx(-24.8)
    assert (np.diff(el) < 0).all()
    sim = SequenceSimulator(1, "benchmark", seed=3)
    scan = sim.scan(0).scan
    assert 60_000 <= len(scan.points) <= 130_000
    assert np.isfinite(scan.points).all() and np.isfinite(scan.remission).all()
    assert (scan.remission >= 0).all() and (scan.remission <= 1).all()
    r = np.linalg.norm(scan.points, axis=1)
    assert r.min() >= sim.preset.effects.ego_clearance and r.max() <= SENSOR_PRESETS["hdl64"].max_range + 1
    # a street scene: road, buildings and cars all show up
    assert {40, 48, 50, 10} <= set(np.unique(scan.sem).tolist())


# -- motion -----------------------------------------------------------------------------------------


def test_stops_are_exactly_still_and_speeds_respect_the_cruise() -> None:
    prof = simulate_profile(0.0, 40.0, 10.0, [Stop(100.0, 5.0)])
    t = np.arange(0.0, 40.0, 0.1)
    s = prof.at(t)
    assert (np.diff(s) >= 0).all()
    v = np.diff(s) / 0.1
    assert v.max() <= 10.0 + 1e-6
    still = np.diff(s) == 0.0
    assert 45 <= still.sum() <= 52  # ~5 s at 10 Hz, held exactly
    assert np.allclose(s[1:][still], 100.0)


def test_route_offsets_move_continuously_through_corners() -> None:
    pts = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 80.0], [0.0, 80.0]])
    path = RoutePath.from_nodes(pts, radius=12.0)
    assert path.length == pytest.approx(100 + 80 + 100 - 4 * 12 + 2 * np.pi * 12 / 2, rel=1e-3)
    s = np.linspace(0, path.length, 5000)
    for lateral in (-8.8, -1.75, 0.0, 5.25):
        x, y, _ = path.pose(s, lateral)
        assert np.hypot(np.diff(x), np.diff(y)).max() < 0.2


# -- written sequences ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("sim")
    stats = simulate_sequence(out, "00", 25, preset="benchmark", seed=11, sensor=SMALL)
    return out, stats


def test_written_files_load_with_the_reader_and_with_numpy(written: tuple[Path, object]) -> None:
    out, stats = written
    root = sequence_dir(out, "00")
    seq = SemanticKittiSequence(root)
    assert len(seq) == 25 and seq.has_labels and seq.poses is not None
    assert np.allclose(seq.times, np.arange(25) * 0.1)
    for k in (0, 12, 24):
        frame = seq[k]
        raw = np.fromfile(root / "velodyne" / f"{k:06d}.bin", dtype=np.float32).reshape(-1, 4)
        labels = np.fromfile(root / "labels" / f"{k:06d}.label", dtype=np.uint32)
        assert len(raw) == len(labels) == len(frame.points) > 0.5 * SMALL.height * SMALL.width
        assert np.isfinite(raw).all()
        assert np.array_equal(raw[:, :3], frame.points) and np.array_equal(labels, frame.labels)
    assert stats.n_scans == 25 and len(stats.points) == 25  # type: ignore[attr-defined]


def test_poses_chain_with_the_ego_motion(written: tuple[Path, object]) -> None:
    out, _ = written
    root = sequence_dir(out, "00")
    poses = read_poses(root / "poses.txt", KITTI_TR)  # LiDAR poses back from camera poses
    assert np.allclose(poses[0], np.eye(4), atol=1e-9)
    sim = SequenceSimulator(25, "benchmark", seed=11, sensor=SMALL, name="00")
    steps = np.linalg.inv(poses[:-1]) @ poses[1:]
    moved = np.linalg.norm(steps[:, :2, 3], axis=1)
    ego = np.hypot(np.diff(sim.traffic.ego_x[1:]), np.diff(sim.traffic.ego_y[1:]))
    # the sensor's planar step is the ego's, up to the body's pitch and roll; standing is exactly still
    assert np.allclose(moved, ego, atol=0.02 + 0.02 * ego.max())
    assert (moved[ego == 0] == 0).all()
    assert np.abs(steps[:, 2, 3]).max() < 0.02 + 0.05 * ego.max()  # gentle slopes only
    assert np.allclose(poses[:, :3, :3] @ poses[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-9)
    for k in (5, 24):
        assert np.allclose(poses[k], np.linalg.inv(sim.world_pose(0)) @ sim.world_pose(k), atol=1e-6)


def test_moving_labels_exactly_on_objects_whose_pose_changed(written: tuple[Path, object]) -> None:
    """labels_instant/: moving exactly where the pose changed since the previous scan; labels/ (the default,
    SemanticKITTI's convention): moving in every scan of an agent that moved at some scan within the sensor's range,
    also in the scans where it stands."""
    out, _ = written
    root = sequence_dir(out, "00")
    assert main_convention(root) == "semantickitti" and list(label_dirs(root)) == ["semantickitti", "instant"]
    sim = SequenceSimulator(25, "benchmark", seed=11, sensor=SMALL, name="00")
    agents = {a.inst: a for a in sim.traffic.agents}
    parked = set(sim.static.parked_ids.tolist())
    reach = sim.lidar.max_range
    seen_moving = waiting_movers = 0
    for k in range(25):
        instant = read_label(root / "labels_instant" / f"{k:06d}.label")
        semantickitti = read_label(root / "labels" / f"{k:06d}.label")
        assert np.array_equal(instance_ids(instant), instance_ids(semantickitti))
        for labels, convention in ((instant, "instant"), (semantickitti, "semantickitti")):
            sem, inst = semantic_ids(labels), instance_ids(labels)
            moving = np.isin(sem, MOVING_IDS)
            assert set(np.unique(inst[moving]).tolist()) <= set(agents)
            for i in np.unique(inst[inst > 0]).tolist():
                s = np.unique(sem[inst == i])
                assert len(s) == 1, "one object, one label per scan"
                if i in parked:
                    assert s[0] == 10
                    continue
                agent = agents[i]
                if convention == "instant":
                    expected = bool(agent.moving[k])
                    seen_moving += int(expected)
                else:
                    d2 = (agent.x[1:] - sim.traffic.ego_x[1:]) ** 2 + (agent.y[1:] - sim.traffic.ego_y[1:]) ** 2
                    expected = bool((agent.moving & (d2 < reach**2)).any())
                    waiting_movers += int(expected and not agent.moving[k])
                assert (s[0] == agent.kind.moving_id) == expected, (convention, k, i)
                assert s[0] in (agent.kind.moving_id, agent.kind.static_id)
            assert (inst[np.isin(sem, [40, 48, 50, 70, 71, 72, 80])] == 0).all()
    assert seen_moving > 0
    assert waiting_movers > 0, "this drive has a mover that stands in some scan: the conventions differ there"


def test_relabel_movers_gives_the_listed_instances_their_moving_id() -> None:
    from ros2_mos.sim.traffic import relabel_movers

    labels = np.array([10 | 5 << 16, 30 | 7 << 16, 40, 10 | 9 << 16, 252 | 5 << 16], np.uint32)
    out = relabel_movers(labels, {5: 252, 7: 254})
    assert out.tolist() == [252 | 5 << 16, 254 | 7 << 16, 40, 10 | 9 << 16, 252 | 5 << 16]
    assert relabel_movers(labels, {}).tolist() == labels.tolist()


def test_same_seed_same_bytes_other_seed_other_scene(tmp_path: Path) -> None:
    for run in ("a", "b"):
        simulate_sequence(tmp_path / run, "03", 3, preset="easy", seed=5, sensor=SMALL)
    simulate_sequence(tmp_path / "c", "03", 3, preset="easy", seed=6, sensor=SMALL)
    for name in ("velodyne/000002.bin", "labels/000002.label", "poses.txt"):
        a, b, c = ((tmp_path / r / "sequences" / "03" / name).read_bytes() for r in "abc")
        assert a == b
        if name.startswith("velodyne"):
            assert a != c


def test_presets_differ_in_how_much_moves() -> None:
    def moving_fraction(preset: str, seed: int) -> float:
        sim = SequenceSimulator(12, preset, seed=seed, sensor=SMALL)
        scans = [sim.scan(k).scan for k in range(0, 12, 3)]
        return float(np.mean([np.isin(s.sem, MOVING_IDS).mean() for s in scans]))

    jam = np.mean([moving_fraction("traffic_jam", s) for s in (1, 2)])
    bench = np.mean([moving_fraction("benchmark", s) for s in (1, 2)])
    assert jam > 0.1 and jam > 1.5 * bench


def test_slow_traffic_shows_slower_movers_and_more_walking_people_than_the_benchmark(tmp_path: Path) -> None:
    def sightings(preset: str) -> dict[str, list[float]]:
        speeds: dict[str, list[float]] = {}
        for seed in (1, 2):
            stats = simulate_sequence(tmp_path / preset, f"{seed:02d}", 15, preset=preset, seed=seed, sensor=SMALL)
            for kind, values in stats.speeds.items():
                speeds.setdefault(kind, []).extend(values)
        return speeds

    slow, bench = sightings("slow_traffic"), sightings("benchmark")
    median = {name: float(np.median(np.concatenate([np.asarray(v) for v in speeds.values()])))
              for name, speeds in (("slow", slow), ("bench", bench))}
    assert median["slow"] < 0.6 * median["bench"]
    assert len(slow["pedestrian"]) > 2 * len(bench["pedestrian"])


def test_parked_cars_are_static_and_at_least_as_many_as_moving_ones(written: tuple[Path, object]) -> None:
    _, stats = written
    assert len(stats.parked_cars) >= stats.n_moving_objects > 0  # type: ignore[attr-defined]
    text = format_stats([stats])  # type: ignore[list-item]
    assert "moving points" in text and "parked cars" in text


def test_intra_sweep_motion_skews_a_moving_scan_only() -> None:
    base = SequenceSimulator(30, "easy", seed=2, sensor=SMALL)
    skew = SequenceSimulator(30, with_effects(sim_preset("easy"), intra_sweep_motion=True), seed=2, sensor=SMALL)
    speeds = np.hypot(np.diff(base.traffic.ego_x), np.diff(base.traffic.ego_y)) / 0.1
    k = int(np.argmax(speeds[1:]))
    a, b = base.scan(k).scan, skew.scan(k).scan
    assert np.isfinite(b.points).all()
    assert not (len(a.points) == len(b.points) and np.allclose(a.points, b.points))


def test_porous_foliage_lengthens_only_vegetation_ranges_by_the_set_depth() -> None:
    """A wall of foliage (70) beside a wall (50): with penetration 1 every foliage return lies deeper, by the
    exponential depth's mean on average; the building's returns do not move."""
    foliage = TriangleSoup.labelled(box((1.0, 40.0, 40.0), (10.5, 20.0, 0.0)), 70)
    wall = TriangleSoup.labelled(box((1.0, 40.0, 40.0), (10.5, -20.0, 0.0)), 50)
    scenes = [SoupScene(foliage, np.zeros(3)), SoupScene(wall, np.zeros(3))]
    pose = np.eye(4)
    solid = Lidar(SMALL, NO_NOISE).scan(scenes, pose, np.random.default_rng(0))
    porous = Lidar(SMALL, replace(NO_NOISE, vegetation_penetration=1.0, vegetation_depth=0.8)).scan(
        scenes, pose, np.random.default_rng(0))
    assert len(solid.points) == len(porous.points) and (solid.sem == porous.sem).all()
    grow = np.linalg.norm(porous.points, axis=1) - np.linalg.norm(solid.points, axis=1)
    veg = solid.sem == 70
    assert veg.sum() > 500 and (solid.sem == 50).sum() > 500
    assert (grow[veg] > 0).all() and grow[veg].mean() == pytest.approx(0.8, rel=0.1)
    assert np.abs(grow[~veg]).max() < 1e-5
    randomized = SensorEffects()  # the presets stay solid: their scans are unchanged
    assert randomized.vegetation_penetration == 0.0
    with pytest.raises(ConfigError):
        SensorEffects(vegetation_penetration=1.5)


def test_mixed_pixels_only_at_depth_edges_and_between_the_two_surfaces() -> None:
    from ros2_mos.sim.lidar import _mix_edges

    dist = np.array([10, 10, 20, 20, 20, 10, 5, 5, 5, np.inf, 5, 5], float)  # two beams of 6 columns
    out = _mix_edges(dist.copy(), dist, 6, 1.0, np.random.default_rng(0))
    mixed = out != dist
    # beam 0: edges between columns 1|2 and 4|5 (10 m vs 20 m); beam 1: no return is no edge
    np.testing.assert_array_equal(np.flatnonzero(mixed), [1, 2, 4, 5])
    assert ((out[mixed] >= 10) & (out[mixed] <= 20)).all()
    assert not (_mix_edges(dist.copy(), dist, 6, 0.0, np.random.default_rng(0)) != dist).any()


def test_randomized_presets_vary_by_sequence_and_repeat_by_seed() -> None:
    from ros2_mos.sim.presets import randomized_for_sequence

    base = sim_preset("benchmark")
    a, b = randomized_for_sequence(base, 100, "b00"), randomized_for_sequence(base, 100, "b01")
    assert a == randomized_for_sequence(base, 100, "b00") and a != b
    assert a.street == base.street and a.traffic == base.traffic
    for p in (a, b):
        assert 0.005 <= p.effects.range_sigma <= 0.04 and 0.2 <= p.effects.vegetation_penetration <= 0.8


def test_large_trees_are_randomised_and_built_as_lumpy_scaled_crowns() -> None:
    from ros2_mos.sim.objects import TRUNK, VEGETATION
    from ros2_mos.sim.presets import SceneConfig, randomized_for_sequence
    from ros2_mos.sim.scene import _Builder

    base = sim_preset("benchmark")
    big = randomized_for_sequence(base, 100, "b00", large_trees=True, beam_layout=False)
    assert 0.5 <= big.scene.tree_prob <= 0.95 and 1 <= big.scene.crown_blobs <= 5
    assert big.scene.tree_scale[0] == 1.0 and 1.3 <= big.scene.tree_scale[1] <= 2.5
    small = randomized_for_sequence(base, 100, "b00", large_trees=False, beam_layout=False)
    assert small.scene == base.scene and small.effects == big.effects  # the same draws, no large trees

    def tree(scene: SceneConfig) -> tuple[np.ndarray, np.ndarray]:
        builder = _Builder(np.random.default_rng(5), base.street, scene, None, 1)
        builder._tree(0.0, 0.0, 0.0)
        trunk, crown = (p.tris for p in builder.parts)
        assert builder.parts[0].sem[0] == TRUNK and builder.parts[1].sem[0] == VEGETATION
        return trunk, crown

    trunk, crown = tree(SceneConfig())
    assert len(crown) == 8  # one octahedron, as the presets have always drawn it
    assert 2.0 <= trunk[..., 2].max() <= 3.5
    trunk, crown = tree(SceneConfig(tree_scale=(2.0, 2.0), crown_blobs=4))
    assert len(crown) == 32 and 4.0 <= trunk[..., 2].max() <= 7.0  # four lumps, twice the height
    with pytest.raises(ConfigError):
        SceneConfig(crown_blobs=0)
    with pytest.raises(ConfigError):
        SceneConfig(tree_scale=(0.0, 1.0))


def test_beam_layout_is_raised_and_jittered_per_sequence_and_fills_the_top_rows() -> None:
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.sim.lidar import Lidar, beam_elevations
    from ros2_mos.sim.presets import SensorEffects, randomized_for_sequence

    base = sim_preset("benchmark")
    round3 = randomized_for_sequence(base, 100, "b00", beam_layout=False)
    assert round3.effects.beam_elevation_offset_deg == 0.0 and round3.effects.beam_elevation_jitter_deg == 0.0
    shifted = randomized_for_sequence(base, 100, "b00")
    e = shifted.effects
    assert 0.2 <= e.beam_elevation_offset_deg <= 1.0 and 0.0 <= e.beam_elevation_jitter_deg <= 0.12
    assert replace(e, beam_elevation_offset_deg=0.0, beam_elevation_jitter_deg=0.0, beam_seed=0) == round3.effects
    hdl = sensor_preset("hdl64")
    nominal = np.degrees(beam_elevations(hdl))
    lidar = Lidar(hdl, SensorEffects(beam_elevation_offset_deg=0.5))
    elevation = np.degrees(np.arcsin(lidar.dirs_sensor[::hdl.width, 2]))
    np.testing.assert_allclose(elevation, nominal + 0.5, atol=1e-9)
    assert (3.0 - elevation[0]) / (28.0 / 64) < 2  # the top beam now lands in row 1, as a real unit's does
    jittered = [np.degrees(np.arcsin(Lidar(hdl, SensorEffects(beam_elevation_jitter_deg=0.1, beam_seed=s))
                                     .dirs_sensor[::hdl.width, 2])) for s in (1, 1, 2)]
    np.testing.assert_array_equal(jittered[0], jittered[1])  # fixed per seed (per sequence)
    assert 0.05 < np.std(jittered[0] - nominal) < 0.15 and not np.array_equal(jittered[0], jittered[2])
    with pytest.raises(ConfigError):
        SensorEffects(beam_elevation_offset_deg=float("nan"))


def test_bad_arguments_raise_typed_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        SequenceSimulator(0, "easy")
    with pytest.raises(ConfigError):
        SequenceSimulator(1, "rush_hour")
    with pytest.raises(ConfigError):
        simulate_sequence(tmp_path, "00", 1, preset="easy", sensor="hdl65")


def test_narrow_streets_are_drawn_after_everything_else_and_bring_parked_cars_closer() -> None:
    from ros2_mos.sim.presets import (
        NARROW_BIKE_LANE_WIDTH,
        NARROW_LANE_WIDTH,
        NARROW_PARKING_WIDTH,
        randomized_for_sequence,
    )

    base = sim_preset("benchmark")
    wide = randomized_for_sequence(base, 100, "b00")
    narrow = randomized_for_sequence(base, 100, "b00", narrow_street=True)
    # The other draws are the same, so every earlier recipe's data is unchanged by the option.
    assert narrow.effects == wide.effects and narrow.ego == wide.ego and wide.street == base.street
    st = narrow.street
    assert NARROW_LANE_WIDTH[0] <= st.lane_width <= NARROW_LANE_WIDTH[1]
    assert NARROW_BIKE_LANE_WIDTH[0] <= st.bike_lane_width <= NARROW_BIKE_LANE_WIDTH[1]
    assert NARROW_PARKING_WIDTH[0] <= st.parking_width <= NARROW_PARKING_WIDTH[1]
    # The sensor drives in the middle of lane 0; the parking lane's inner edge, by hand: preset 3.5 / 2 + 1.5 = 3.25 m
    # away, never more on a narrow street (at most 3.5 / 2 + 1.5), at least 2.8 / 2 + 0.3 = 1.7 m.
    inner_edge = lambda s: (s.half_road_width - s.parking_width) + s.lane_offset(0)  # noqa: E731
    assert inner_edge(base.street) == pytest.approx(-1.75 + 3.5 + 1.5)
    edges = [inner_edge(randomized_for_sequence(base, 100, f"b{i:02d}", narrow_street=True).street) for i in range(20)]
    assert all(1.7 <= e <= 3.25 for e in edges) and min(edges) < 2.5


def _parked_heights(preset) -> dict[int, tuple[set[int], float]]:
    """Each parked vehicle's semantic ids and height above its lowest vertex, from the static scene."""
    soup = SequenceSimulator(2, preset, seed=5, sensor=SMALL, name="00").static.soup
    out = {}
    for i in np.unique(soup.inst[soup.inst > 0]).tolist():
        tris = soup.tris[soup.inst == i]
        out[i] = (set(np.unique(soup.sem[soup.inst == i]).tolist()), float(np.ptp(tris[..., 2])))
    return out


def test_parked_vans_are_taller_than_cars_static_trucks_and_only_where_asked_for() -> None:
    from ros2_mos.sim.presets import PARKED_VAN_SHARE, randomized_for_sequence

    base = sim_preset("narrow_street")
    cars = _parked_heights(base)
    vans = _parked_heights(replace(base, scene=replace(base.scene, parked_van_prob=1.0)))
    # Cars 1.4-1.6 m tall (cabin top) as the car shape's draw, vans 1.9-2.8 m and labelled truck (18), both static
    # ids. (The van draws move the random stream on, so the later blocks differ.)
    assert len(cars) > 5 and len(vans) > 5
    assert all(sem == {10} and 1.4 <= h <= 1.6 + 1e-9 for sem, h in cars.values())
    assert all(sem == {18} and 1.9 <= h <= 2.8 + 1e-9 for sem, h in vans.values())
    # A share in between parks both.
    mixed = _parked_heights(replace(base, scene=replace(base.scene, parked_van_prob=0.5)))
    assert {frozenset(s) for s, _ in mixed.values()} == {frozenset({10}), frozenset({18})}
    # In training data the share is drawn last, so the other draws (and earlier recipes' data) stay the same.
    plain = randomized_for_sequence(base, 100, "bw00", narrow_street=True)
    with_vans = randomized_for_sequence(base, 100, "bw00", narrow_street=True, parked_vans=True)
    assert plain.scene.parked_van_prob == 0.0 and base.scene.parked_van_prob == 0.0
    assert PARKED_VAN_SHARE[0] <= with_vans.scene.parked_van_prob <= PARKED_VAN_SHARE[1]
    assert replace(with_vans.scene, parked_van_prob=0.0) == plain.scene
    assert (with_vans.effects, with_vans.ego, with_vans.street) == (plain.effects, plain.ego, plain.street)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ConfigError):
            replace(base.scene, parked_van_prob=bad)


def test_the_narrow_street_preset_is_the_benchmark_street_narrowed_and_lined_with_more_parked_cars() -> None:
    narrow, bench = sim_preset("narrow_street"), sim_preset("benchmark")
    assert narrow.traffic == bench.traffic and narrow.ego == bench.ego and narrow.effects == bench.effects
    assert narrow.scene.parked_prob == 0.8 > bench.scene.parked_prob
    # The parking lane's inner edge seen from the middle of the sensor's lane, by hand: 3.0 / 2 + 0.5 = 2.0 m (the
    # benchmark's 3.5 / 2 + 1.5 = 3.25 m); the parked cars' sides stand a little inside the lane (2.1 m wide).
    st = narrow.street
    assert (st.half_road_width - st.parking_width) + st.lane_offset(0) == pytest.approx(2.0)
