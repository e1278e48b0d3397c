"""``ros2-mos odometry`` and ``ros2-mos map`` end to end on a tiny labelled sequence."""

from __future__ import annotations

from pathlib import Path

import pytest
from apps_scenes import write_street_sequence
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.io.semantic_kitti import read_poses

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "fastmos_vlp16_free.yaml"


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


def test_outputs_that_cannot_be_written_fail_before_any_work(street, tmp_path):
    """Issue 13.10: map, train and export checked their output paths only after all the work."""
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases = [
        (["map", str(street), "--out", str(a_file / "m.ply")], f"--out {a_file / 'm_raw.ply'}: {a_file} is a file"),
        (["map", str(street), "--out", str(tmp_path / "m.ply"), "--png", str(tmp_path)],
         "is a folder; expected a file"),
        (["map", str(street), "--out", str(tmp_path / "m.ply"), "--deskew", "yes"],
         "unknown --deskew 'yes': use one of auto, on, off"),
        (["export", str(REPO / "checkpoints/fastmos_beams_free16_best.pt"), "--out", str(a_file / "m.onnx")],
         f"{a_file} is a file"),
        (["train", "--config", str(CONFIG), "--data", str(tmp_path / "none"), "--out", str(a_file)],
         f"out_dir {a_file} is a file; expected a folder"),
        (["train", "--config", str(CONFIG), "--data", str(tmp_path / "none"),
          "--out", str(tmp_path / "run"), "--export", str(a_file / "m.onnx")], f"--export {a_file / 'm.onnx'}"),
    ]
    for args, message in cases:
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 1, (args, result.output)
        assert message in result.output, (args, result.output)
    assert not (tmp_path / "run").exists()  # nothing was started
