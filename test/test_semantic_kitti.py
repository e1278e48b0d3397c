"""SemanticKITTI folder I/O round trips, including the camera <-> LiDAR pose convention."""

import numpy as np
import pytest

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.semantic_kitti import (
    KITTI_TR,
    SemanticKittiSequence,
    read_calib,
    read_poses,
    write_calib,
    write_label,
    write_poses,
    write_scan,
    write_times,
)


def test_sequence_round_trip(tmp_path):
    seq = tmp_path / "sequences" / "00"
    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.5]
    for i in range(3):
        pts = rng.normal(size=(100 + i, 3)).astype(np.float32)
        write_scan(seq / "velodyne" / f"{i:06d}.bin", pts, np.full(len(pts), 0.5, np.float32))
        write_label(seq / "labels" / f"{i:06d}.label", np.full(len(pts), 252 | (3 << 16), np.uint32))
    write_poses(seq / "poses.txt", poses)
    write_calib(seq / "calib.txt")
    write_times(seq / "times.txt", np.arange(3) * 0.1)
    s = SemanticKittiSequence(seq)
    assert len(s) == 3 and s.has_labels
    frame = s[2]
    assert frame.points.shape == (102, 3) and frame.labels.shape == (102,)
    np.testing.assert_allclose(frame.pose, poses[2], atol=1e-9)
    np.testing.assert_allclose(read_calib(seq / "calib.txt"), KITTI_TR)
    # The file holds camera poses: Tr @ P @ inv(Tr).
    np.testing.assert_allclose(read_poses(seq / "poses.txt")[2], KITTI_TR @ poses[2] @ np.linalg.inv(KITTI_TR),
                               atol=1e-9)
    # Plain numpy reads the same bytes.
    raw = np.fromfile(seq / "velodyne" / "000002.bin", np.float32).reshape(-1, 4)
    np.testing.assert_array_equal(raw[:, :3], frame.points)


def test_bare_velodyne_folder_is_a_sequence(tmp_path):
    write_scan(tmp_path / "velodyne" / "000000.bin", np.ones((5, 3), np.float32))
    s = SemanticKittiSequence(tmp_path)
    assert s.poses is None and not s.has_labels and s[0].pose is None


def test_missing_and_malformed_files_raise(tmp_path):
    with pytest.raises(DatasetError, match="velodyne"):
        SemanticKittiSequence(tmp_path)
    (tmp_path / "velodyne").mkdir()
    (tmp_path / "velodyne" / "000000.bin").write_bytes(b"\0" * 10)
    with pytest.raises(DatasetError, match="multiple of 16"):
        SemanticKittiSequence(tmp_path)[0]
    write_scan(tmp_path / "velodyne" / "000000.bin", np.ones((5, 3), np.float32))
    write_label(tmp_path / "labels" / "000000.label", np.zeros(4, np.uint32))
    with pytest.raises(DatasetError, match="4 labels for 5 points"):
        SemanticKittiSequence(tmp_path)[0]


@pytest.mark.parametrize("extra", [1, 2, 3, 17])
def test_scan_sizes_that_are_not_whole_points_are_named_with_their_byte_size(tmp_path, extra):
    (tmp_path / "velodyne").mkdir()
    (tmp_path / "velodyne" / "000000.bin").write_bytes(b"\0" * (32 + extra))
    with pytest.raises(DatasetError, match=f"size {32 + extra} bytes is not a multiple of 16"):
        SemanticKittiSequence(tmp_path)[0]


@pytest.mark.parametrize("name, content, message", [
    ("times.txt", "0.0\nabc\n", "times.txt: not a table of numbers"),
    ("times.txt", "0.0\n0.2\n0.1\n", r"times must increase, but line 3 \(0.1 s\) does not come after line 2"),
    ("times.txt", "0.0\nnan\n0.2\n", "line 2 is not a finite time"),
    ("times.txt", b"\xff\xfe\x00", "not a UTF-8 text file"),
    ("calib.txt", "Tr: 1 2 x\n", "'Tr' holds text"),
])
def test_malformed_text_files_are_one_line_errors(tmp_path, name, content, message):
    for i in range(3):
        write_scan(tmp_path / "velodyne" / f"{i:06d}.bin", np.ones((5, 3), np.float32))
    write_poses(tmp_path / "poses.txt", np.tile(np.eye(4), (3, 1, 1)))
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(DatasetError, match=message):
        seq = SemanticKittiSequence(tmp_path)
        seq.require_poses()


def test_a_bad_poses_file_matters_only_where_poses_are_used(tmp_path):
    for i in range(3):
        write_scan(tmp_path / "velodyne" / f"{i:06d}.bin", np.ones((5, 3), np.float32))
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")  # one pose for three scans
    seq = SemanticKittiSequence(tmp_path)  # opens: infer without --use-poses does not need them
    assert seq[2].pose is None
    with pytest.raises(DatasetError, match="--use-poses need poses.txt: .*1 poses for 3 scans"):
        seq.require_poses("--use-poses")
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 nan\n" * 3)
    with pytest.raises(DatasetError, match="line 1 holds a non-finite number"):
        SemanticKittiSequence(tmp_path).require_poses()


def test_poses_rounded_to_seven_digits_read_back_as_rotations(tmp_path):
    """SemanticKITTI's own poses.txt has seven significant digits: its rotations are off orthonormal by ~1e-7, which
    KISS-ICP's Sophus aborts on; read_poses hands back the nearest rotation, within the rounding of the file."""
    yaw = np.radians(37.0)
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    pose[:3, 3] = [1.0, 2.0, 3.0]
    np.savetxt(tmp_path / "poses.txt", np.tile(pose[:3].reshape(1, 12), (2, 1)), fmt="%e")
    rounded = np.loadtxt(tmp_path / "poses.txt")[0].reshape(3, 4)[:, :3]
    assert np.abs(rounded.T @ rounded - np.eye(3)).max() > 1e-9  # the file's rotation is not one
    read = read_poses(tmp_path / "poses.txt")
    assert np.abs(read[0, :3, :3].T @ read[0, :3, :3] - np.eye(3)).max() < 1e-14
    assert np.linalg.det(read[0, :3, :3]) > 0
    np.testing.assert_allclose(read[0], pose, atol=1e-6)  # the file's own precision


@pytest.mark.parametrize("row, message", [
    ("0.9 0 0 0 0 1 0 0 0 0 1 0", "line 2 is no rigid pose"),  # scaled
    ("-1 0 0 0 0 1 0 0 0 0 1 0", "line 2 is no rigid pose"),  # a mirror
])
def test_a_pose_whose_rotation_is_no_rotation_is_a_one_line_error(tmp_path, row, message):
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" + row + "\n")
    with pytest.raises(DatasetError, match=message):
        read_poses(tmp_path / "poses.txt")
