"""``ros2-mos odometry`` and ``ros2-mos map`` end to end on a tiny labelled sequence."""

from __future__ import annotations

import pytest
from apps_scenes import write_street_sequence
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.datasets.semantic_kitti import read_poses


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    return write_street_sequence(tmp_path_factory.mktemp("cli") / "00", n_scans=10)


def test_odometry_prints_a_table_for_every_mask_and_saves_poses(street, tiny_model_path, tmp_path):
    result = CliRunner().invoke(app, ["odometry", str(street), "--model", str(tiny_model_path), "--mask", "all",
                                      "--segments", "3,6", "--save-poses", str(tmp_path)])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.output.splitlines()]
    rows = [r for r in rows if len(r) == 9 and r[0] == "00"]  # the table (tqdm's lines are not 9 words)
    assert [r[1] for r in rows] == ["none", "mos", "gt", "gt-map"]
    assert all(float(r[2]) < 10.0 for r in rows)  # t_err %
    assert read_poses(tmp_path / "00" / "mos.txt").shape == (10, 4, 4)


def test_odometry_rejects_a_bad_mask(street):
    result = CliRunner().invoke(app, ["odometry", str(street), "--mask", "raw"])
    assert result.exit_code != 0


def test_map_writes_both_maps_the_png_and_reports_ghosts(street, tiny_model_path, tmp_path):
    result = CliRunner().invoke(app, ["map", str(street), "--out", str(tmp_path / "m.pcd"),
                                      "--png", str(tmp_path / "bev.png"),
                                      "--model", str(tiny_model_path), "--voxel-size", "0.2", "--poses", "gt"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "m_raw.pcd").stat().st_size > 1000 and (tmp_path / "m_cleaned.pcd").stat().st_size > 1000
    assert (tmp_path / "bev.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ghosts = {line.split()[0]: float(line.split()[2]) for line in result.output.splitlines()
              if line.split() and line.split()[0] in ("raw", "cleaned")}
    assert ghosts["raw"] > ghosts["cleaned"]
    bad = CliRunner().invoke(app, ["map", str(street), "--out", str(tmp_path / "m.obj")])
    assert bad.exit_code != 0 and ".ply or .pcd" in bad.output
