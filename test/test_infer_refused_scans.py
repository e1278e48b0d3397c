"""`ros2-mos infer` and `map` over a scan they cannot label (a driver's dropout: no points, or only NaN): one line
naming the scan's file, exit code 1; `infer` leaves only whole label files of the scans before it, `map` no map
(docs/reliability.md: a hole would give the next scans residuals against the wrong past scans)."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import write_sequence
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.io.semantic_kitti import read_label, read_scan, write_scan


@pytest.mark.parametrize("damage", ["empty", "nan"])
def test_infer_stops_at_a_scan_it_cannot_label_and_names_its_file(tmp_path, tiny_model_path, damage):
    seq = write_sequence(tmp_path / "data", "00", n_scans=5)
    bad = seq / "velodyne" / "000002.bin"
    if damage == "empty":
        bad.write_bytes(b"")
        (seq / "labels" / "000002.label").write_bytes(b"")  # none for no points
    else:
        scan = read_scan(bad)
        write_scan(bad, np.full_like(scan[:, :3], np.nan), scan[:, 3])
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["infer", str(seq), "--out", str(out), "--model", str(tiny_model_path)])
    assert result.exit_code == 1, result.output
    message = str(result.exception)
    assert "\n" not in message and message.startswith("00 scan 2 (000002.bin): ") and "run again" in message
    assert ("empty scan" if damage == "empty" else "no finite point") in message
    predictions = out / "sequences" / "00" / "predictions"
    assert sorted(p.name for p in predictions.iterdir()) == ["000000.label", "000001.label"]
    for name in ("000000", "000001"):
        assert read_label(predictions / f"{name}.label").size == len(read_scan(seq / "velodyne" / f"{name}.bin"))


def test_map_stops_at_an_empty_scan_and_names_it_writing_no_map(tmp_path, tiny_model_path):
    seq = write_sequence(tmp_path / "data", "00", n_scans=4)
    (seq / "velodyne" / "000001.bin").write_bytes(b"")
    (seq / "labels" / "000001.label").write_bytes(b"")
    result = CliRunner().invoke(app, ["map", str(seq), "--out", str(tmp_path / "map.ply"), "--model",
                                      str(tiny_model_path)])
    assert result.exit_code == 1, result.output
    message = str(result.exception)
    assert message.startswith("00 scan 1 (000001): empty scan") and "\n" not in message
    assert not (tmp_path / "map.ply").exists()
