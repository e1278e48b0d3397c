"""`ros2-mos simulate`: the command writes sequences (and a bag that reads back with the same points)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.io.semantic_kitti import SemanticKittiSequence


def test_simulate_writes_sequences_stats_and_a_bag_with_the_same_points(tmp_path: Path) -> None:
    from ros2_mos.io.bags import iter_pointclouds
    from ros2_mos.io.pointcloud2 import decode_xyz_intensity

    result = CliRunner().invoke(app, [
        "simulate", str(tmp_path), "--sequences", "00", "01", "--scans", "3", "--preset", "easy",
        "--sensor", "vlp16", "--seed", "4", "--stats", "--bag",
    ])
    assert result.exit_code == 0, result.output
    assert "moving points" in result.output and "parked cars" in result.output
    for name in ("00", "01"):
        seq = SemanticKittiSequence(tmp_path / "sequences" / name)
        assert len(seq) == 3
        clouds = list(iter_pointclouds(tmp_path / "bags" / name))
        assert len(clouds) == 3
        stamps = np.array([stamp for stamp, _ in clouds])
        assert np.allclose(np.diff(stamps), 100_000_000)
        for frame, (_, msg) in zip(seq, clouds):
            points, intensity, _ = decode_xyz_intensity(msg)
            assert msg.header.frame_id == "velodyne"
            assert np.array_equal(points, frame.points) and np.array_equal(intensity, frame.remission)


def test_simulate_rejects_bad_input_with_one_line(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["simulate", str(tmp_path), "--scans", "1", "--preset", "rush_hour"])
    assert result.exit_code != 0
    result = runner.invoke(app, ["simulate", str(tmp_path), "--sequences", "00", "00", "--scans", "1"])
    assert result.exit_code != 0 and "repeat" in result.output
