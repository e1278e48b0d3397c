"""SemanticKITTI folder I/O round trips, including the camera <-> LiDAR pose convention."""

import numpy as np
import pytest

from ros2_mos.datasets.semantic_kitti import (
    KITTI_TR, SemanticKittiSequence, read_calib, read_poses, write_calib, write_label, write_poses, write_scan,
    write_times,
)
from ros2_mos.errors import DatasetError


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
    np.testing.assert_allclose(read_poses(seq / "poses.txt")[2], KITTI_TR @ poses[2] @ np.linalg.inv(KITTI_TR), atol=1e-9)
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
