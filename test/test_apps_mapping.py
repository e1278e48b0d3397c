"""VoxelMap, raw vs cleaned maps and ghost share, PLY/PCD round trips, the bird's-eye-view PNG."""

from __future__ import annotations

import numpy as np
import pytest
from apps_scenes import write_street_sequence

from ros2_mos.apps.mapping import (
    TAG_MOVING,
    TAG_STATIC,
    MapBuilder,
    MappingConfig,
    VoxelMap,
    VoxelMapConfig,
    build_maps,
    ghost_share,
    gt_tags,
    map_paths,
    write_bev_png,
    write_map,
)
from ros2_mos.core.config import MosConfig, PostprocessConfig
from ros2_mos.core.errors import ConfigError, ScanError
from ros2_mos.io.labels import MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import SemanticKittiSequence
from ros2_mos.offline.drives import FolderDrive

# ------------------------------------------------------------------ readers written from the format specs


def read_ply(path):
    """PLY (binary_little_endian or ascii) vertex element: a structured array, parsed from the spec."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply"
    fmt = header[1].split()[1]
    types = {"float": "<f4", "double": "<f8", "uchar": "u1", "int": "<i4", "uint": "<u4"}
    fields, count, in_vertex = [], 0, False
    for line in header:
        words = line.split()
        if words[0] == "element":
            in_vertex = words[1] == "vertex"
            if in_vertex:
                count = int(words[2])
        elif words[0] == "property" and in_vertex:
            fields.append((words[2], types[words[1]]))
    dtype = np.dtype(fields)
    if fmt == "ascii":
        rows = np.loadtxt(data[end:].decode().splitlines()[:count], ndmin=2)
        out = np.zeros(count, dtype)
        for i, (name, _) in enumerate(fields):
            out[name] = rows[:, i]
        return out
    assert fmt == "binary_little_endian"
    return np.frombuffer(data, dtype=dtype, count=count, offset=end)


def read_pcd(path):
    """PCD v0.7 with DATA binary or ascii: a structured array, parsed from PCL's spec."""
    data = path.read_bytes()
    header, offset = {}, 0
    for line in data.split(b"\n"):
        offset += len(line) + 1
        text = line.decode("ascii").strip()
        if not text or text.startswith("#"):
            continue
        key, *values = text.split()
        header[key] = values
        if key == "DATA":
            break
    kinds = {("F", "4"): "<f4", ("F", "8"): "<f8", ("U", "4"): "<u4", ("U", "1"): "u1", ("I", "4"): "<i4"}
    dtype = np.dtype([(n, kinds[(t, s)]) for n, t, s in zip(header["FIELDS"], header["TYPE"], header["SIZE"])])
    n = int(header["POINTS"][0])
    assert header["DATA"][0] == "binary"
    return np.frombuffer(data, dtype=dtype, count=n, offset=offset)


# ------------------------------------------------------------------ VoxelMap


def test_voxel_map_keeps_the_first_point_of_each_voxel_with_its_tag():
    vm = VoxelMap(VoxelMapConfig(voxel_size=1.0))
    added = vm.insert(np.array([[0.2, 0.2, 0.2], [0.8, 0.9, 0.1], [1.5, 0, 0], [-0.5, 0, 0]]),
                      tags=[1, 2, 3, 4], stamp=1.0)
    assert added == 3 and len(vm) == 3
    assert vm.insert(np.array([[0.5, 0.5, 0.5], [5.0, 5.0, 5.0], [np.nan, 0, 0]]), tags=[9, 5, 6], stamp=2.0) == 1
    by_tag = {int(t): p for t, p in zip(vm.tags, vm.points)}
    assert set(by_tag) == {1, 3, 4, 5}
    np.testing.assert_allclose(by_tag[1], [0.2, 0.2, 0.2], atol=1e-6)
    assert sorted(vm.stamps.tolist()) == [1.0, 1.0, 1.0, 2.0]
    np.testing.assert_array_equal(vm.contains(np.array([[0.9, 0.1, 0.9], [2.5, 0, 0], [-0.1, 0.5, 0.5]])),
                                  [True, False, True])
    with pytest.raises(ValueError):
        vm.points[0, 0] = 1.0  # read-only views


def test_voxel_map_downsamples_a_dense_cloud_to_one_point_per_voxel():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 10, (200_000, 3))
    vm = VoxelMap(VoxelMapConfig(voxel_size=0.5))
    vm.insert(pts[:100_000])
    vm.insert(pts[100_000:])
    assert len(vm) == 20**3
    assert len(np.unique(vm.voxel_keys(vm.points))) == len(vm)


def test_bounded_voxel_map_keeps_the_radius_and_the_nearest_points():
    vm = VoxelMap(VoxelMapConfig(voxel_size=1.0, max_radius=10.0, max_points=5))
    line = np.column_stack([np.arange(0, 30) + 0.5, np.zeros(30), np.zeros(30)])
    vm.insert(line, sensor_position=np.zeros(3))
    np.testing.assert_allclose(np.sort(vm.points[:, 0]), [0.5, 1.5, 2.5, 3.5, 4.5])
    vm = VoxelMap(VoxelMapConfig(voxel_size=1.0, max_radius=10.0))
    vm.insert(line, sensor_position=np.zeros(3))
    assert len(vm) == 10
    vm.insert_scan(np.zeros((1, 3)), np.array([[1, 0, 0, 20.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    assert vm.points[:, 0].min() >= 10.0  # moving the sensor drops what is now out of range
    with pytest.raises(ConfigError, match="sensor position"):
        vm.insert(line)


def test_voxel_map_refuses_bad_input():
    with pytest.raises(ConfigError):
        VoxelMapConfig(voxel_size=0.0)
    vm = VoxelMap()
    with pytest.raises(ScanError, match=r"\(N, 3\)"):
        vm.insert(np.zeros((3, 4)))
    with pytest.raises(ScanError, match="tags"):
        vm.insert(np.zeros((3, 3)), tags=[1, 2])
    with pytest.raises(ScanError, match="beyond"):
        vm.insert(np.array([[1e6, 0, 0]]))


# ------------------------------------------------------------------ maps and ghosts


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    return SemanticKittiSequence(write_street_sequence(tmp_path_factory.mktemp("street") / "00", n_scans=8))


def _gt_builder(seq: SemanticKittiSequence) -> MapBuilder:
    builder = MapBuilder(MappingConfig(voxel_size=0.2))
    for frame in seq:
        gt_moving = to_moving_classes(frame.labels) == MOVING
        builder.add(frame.points, frame.pose, gt_moving, gt_tags(frame.labels, len(frame.points)))
    return builder


def test_ghost_share_is_zero_for_a_gt_cleaned_map_and_positive_for_the_raw_one(street):
    builder = _gt_builder(street)
    assert ghost_share(builder.cleaned) == 0.0
    assert ghost_share(builder.raw) > 0.005  # the car's trail over 8 scans
    assert builder.static_kept() == 1.0  # removing only movers keeps every static voxel
    assert np.count_nonzero(builder.raw.tags == TAG_MOVING) > 100
    assert (builder.cleaned.tags == TAG_STATIC).all()


def test_build_maps_with_a_threshold_model_removes_ghosts(street, tiny_model_path):
    # The residual-threshold model finds about 2/3 of the car from scan 1 on (none in scan 0,
    # which has no past scan), so the cleaned map has clearly fewer ghosts, not none.
    # No speck filter: the analytic scene's random points leave the threshold model's moving pixels fragmented.
    config = MosConfig(model=str(tiny_model_path), postprocess=PostprocessConfig(min_region_pixels=0))
    result = build_maps(FolderDrive(street.root), config, MappingConfig(voxel_size=0.2, poses="gt"))
    assert result.poses.shape == (len(street), 4, 4)
    raw, cleaned = ghost_share(result.raw), ghost_share(result.cleaned)
    assert raw > 0.005 and cleaned < 0.8 * raw, (raw, cleaned)
    assert result.builder.static_kept() > 0.9


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_map_files_round_trip_through_a_spec_reader(tmp_path, suffix):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-50, 50, (1000, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (1000, 3)).astype(np.uint8)
    path = write_map(tmp_path / f"map{suffix}", pts, colors)
    if suffix == ".ply":
        data = read_ply(path)
        rgb = np.column_stack([data["red"], data["green"], data["blue"]])
    else:
        data = read_pcd(path)
        packed = data["rgb"].view(np.uint32) if data["rgb"].dtype != np.uint32 else data["rgb"]
        rgb = np.column_stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255])
    np.testing.assert_array_equal(np.column_stack([data["x"], data["y"], data["z"]]), pts)
    np.testing.assert_array_equal(rgb, colors)


def test_ply_is_also_read_by_trimesh(tmp_path):
    import trimesh

    pts = np.random.default_rng(2).uniform(-5, 5, (50, 3)).astype(np.float32)
    cloud = trimesh.load(write_map(tmp_path / "m.ply", pts))
    np.testing.assert_allclose(np.asarray(cloud.vertices), pts, atol=1e-6)


def test_unknown_map_format_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="ply or .pcd"):
        write_map(tmp_path / "map.xyz", np.zeros((1, 3)))
    assert [p.name for p in map_paths(tmp_path / "map.pcd")] == ["map_raw.pcd", "map_cleaned.pcd"]


def test_bev_png_shows_raw_and_cleaned_side_by_side_with_red_ghosts(tmp_path, street):
    from PIL import Image

    builder = _gt_builder(street)
    path = write_bev_png(tmp_path / "bev.png", {"raw": builder.raw, "cleaned": builder.cleaned}, max_pixels=300)
    image = np.asarray(Image.open(path).convert("RGB"))
    assert image.shape[1] > 2 * 250 and image.shape[0] > 50
    half = image.shape[1] // 2
    red = np.all(image == [230, 40, 40], axis=2)
    assert red[:, :half].sum() > 10 and red[:, half:].sum() == 0


# ------------------------------------------------------------------ deskewed maps


def _two_scan_drive(tmp_path, sweep: str | None):
    """Two scans of three points, the sensor 1 m further along x in the second (poses.txt, 0.1 s apart)."""
    from ros2_mos.io.semantic_kitti import write_poses, write_scan, write_times
    from ros2_mos.io.sweep import write_sweep_file

    root = tmp_path / "drive"
    points = np.array([[0.0, 5.0, 0.0], [5.0, 0.0, 0.0], [0.0, -5.0, 0.0]], np.float32)  # left, ahead, right
    for k in range(2):
        write_scan(root / "velodyne" / f"{k:06d}.bin", points, np.zeros(3, np.float32))
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, 0, 3] = 1.0
    write_poses(root / "poses.txt", poses, tr=None)  # no calib.txt: the folder holds LiDAR poses
    write_times(root / "times.txt", np.array([0.0, 0.1]))
    if sweep is not None:
        write_sweep_file(root, skewed=sweep == "skewed")
    return FolderDrive(root), points


def _labels_beside(tmp_path, seq, sweep: str | None):
    """An autolabel-like labels root for ``seq``: nothing moving, its poses, and its own sweep.txt."""
    from ros2_mos.io.labels import to_submission
    from ros2_mos.io.semantic_kitti import write_label, write_poses
    from ros2_mos.io.sweep import write_sweep_file

    folder = tmp_path / "labels" / "sequences" / seq.name
    for name in seq.scan_names:
        write_label(folder / "predictions" / f"{name}.label", to_submission(np.zeros(3, bool)))
    write_poses(folder / "poses.txt", seq.poses)
    if sweep is not None:
        write_sweep_file(folder, skewed=sweep == "skewed")
    return tmp_path / "labels"


def test_a_deskewed_map_holds_each_point_where_its_firing_pose_saw_it(tmp_path):
    """The sensor moves 1 m per sweep along x; the sweep starts behind and turns clockwise, so the point on the left
    was fired a quarter sweep before the scan's pose (0.25 m further back), the one ahead at it, the one on the right a
    quarter after (0.25 m on). Deskewed, scan 0's points lie at x -0.25, 0, +0.25 and scan 1's 1 m on from them."""
    from ros2_mos.apps.mapping import build_maps_from_labels

    seq, points = _two_scan_drive(tmp_path, None)
    labels = _labels_beside(tmp_path, seq, "skewed")  # autolabel deskewed: 'auto' follows it
    result = build_maps_from_labels(seq, labels, MappingConfig(voxel_size=0.01, min_range=1.0))
    assert result.deskewed
    expected = np.array([[-0.25, 5, 0], [0, 0, 0], [0.25, -5, 0]]) + [[0, 0, 0], [5, 0, 0], [0, 0, 0]]
    expected = np.vstack([expected, expected + [1.0, 0, 0]])
    got = result.raw.points[np.lexsort(result.raw.points.T[::-1])]
    np.testing.assert_allclose(got, expected[np.lexsort(expected.T[::-1])], atol=1e-5)
    raw = build_maps_from_labels(seq, labels, MappingConfig(voxel_size=0.01, min_range=1.0, deskew="off"))
    assert not raw.deskewed
    np.testing.assert_allclose(np.sort(raw.raw.points[:, 0]), np.sort(np.r_[points[:, 0], points[:, 0] + 1]),
                               atol=1e-6)


@pytest.mark.parametrize("labels_say, sequence_says, mode, deskewed", [
    ("skewed", "compensated", "auto", True),  # autolabel's word beats the folder's
    ("compensated", "skewed", "auto", False),
    (None, "skewed", "auto", True),  # labels that say nothing (infer's): the folder's word
    (None, None, "auto", False),  # nobody says: as they are
    ("compensated", None, "on", True),
    ("skewed", "skewed", "off", False),
])
def test_map_deskew_auto_follows_the_labels_then_the_sequence(tmp_path, labels_say, sequence_says, mode, deskewed):
    from ros2_mos.apps.mapping import build_maps_from_labels

    seq, _ = _two_scan_drive(tmp_path, sequence_says)
    labels = _labels_beside(tmp_path, seq, labels_say)
    assert build_maps_from_labels(seq, labels, MappingConfig(deskew=mode)).deskewed is deskewed


def test_the_online_map_deskews_with_the_pipeline_s_poses(street, tiny_model_path):
    """Deskewing moves the same scans' points (the street's poses move the sensor), and changes nothing else: the
    same poses, the same share labelled moving."""
    config = MosConfig(model=str(tiny_model_path), postprocess=PostprocessConfig(min_region_pixels=0))
    plain = build_maps(FolderDrive(street.root), config, MappingConfig(voxel_size=0.2, poses="gt", deskew="off"))
    bent = build_maps(FolderDrive(street.root), config, MappingConfig(voxel_size=0.2, poses="gt", deskew="on"))
    assert bent.deskewed and not plain.deskewed
    np.testing.assert_allclose(bent.poses, plain.poses)
    assert bent.moving_share == pytest.approx(plain.moving_share)
    assert not np.array_equal(np.sort(bent.raw.points, axis=0), np.sort(plain.raw.points, axis=0))


def test_an_unknown_map_deskew_mode_is_refused():
    with pytest.raises(ConfigError, match="mapping: deskew must be one of auto, on, off, got 'yes'"):
        MappingConfig(deskew="yes")
