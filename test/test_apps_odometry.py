"""KISS-ICP over a tiny labelled sequence with every mask, evaluated against its ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from apps_scenes import write_street_sequence

from ros2_mos.apps.odometry import MASKS, evaluate_run, ground_truth_camera_poses, parse_masks, run_odometry
from ros2_mos.core.config import MosConfig
from ros2_mos.core.errors import ConfigError, DatasetError
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, write_scan


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    return SemanticKittiSequence(write_street_sequence(tmp_path_factory.mktemp("odom") / "00", n_scans=14))


@pytest.fixture(scope="module")
def runs(street, tiny_model_path):
    cfg = MosConfig(model=str(tiny_model_path))
    return {mask: run_odometry(street, mask, cfg) for mask in MASKS}


def test_every_mask_tracks_the_ego_motion(street, runs):
    gt = street.poses[: len(street)]
    for mask, run in runs.items():
        assert run.poses.shape == (len(street), 4, 4) and run.milliseconds.shape == (len(street),)
        travelled = np.linalg.norm(run.poses[-1][:3, 3] - run.poses[0][:3, 3])
        assert travelled == pytest.approx(np.linalg.norm(gt[-1][:3, 3] - gt[0][:3, 3]), abs=0.3), mask
        np.testing.assert_allclose(run.poses[0], np.eye(4), atol=1e-9)


def test_masked_shares_reflect_what_each_mask_removes(runs):
    assert runs["none"].masked_share == 0.0
    assert runs["gt"].masked_share == pytest.approx(runs["gt-map"].masked_share) and runs["gt"].masked_share > 0.01
    assert 0.0 < runs["mos"].masked_share < 0.2


def test_short_segment_errors_and_ate_are_small_for_a_good_run(street, runs):
    for run in runs.values():
        res = evaluate_run(run, street, lengths=(4.0, 8.0), step=1)
        assert res.n_segments > 0 and res.translation_pct < 5.0 and res.ate_rmse < 0.2
    gt, tr = ground_truth_camera_poses(street)
    assert tr is not None
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-9)  # poses.txt's first camera pose


def test_gt_masks_need_labels_and_unknown_masks_are_refused(tmp_path):
    write_scan(tmp_path / "00" / "velodyne" / "000000.bin", np.ones((10, 3), np.float32))
    seq = SemanticKittiSequence(tmp_path / "00")
    with pytest.raises(DatasetError, match="labels"):
        run_odometry(seq, "gt")
    with pytest.raises(DatasetError, match="poses.txt"):
        ground_truth_camera_poses(seq)
    with pytest.raises(ConfigError, match="unknown mask"):
        run_odometry(seq, "semantic")
    assert parse_masks("all") == list(MASKS) and parse_masks("none,gt") == ["none", "gt"]
    with pytest.raises(ConfigError):
        parse_masks("raw")
