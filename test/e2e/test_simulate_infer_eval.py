"""simulate -> infer -> eval through the real CLI, and KISS-ICP odometry against ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import make_threshold_model
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.core.config import MosConfig, sensor_preset
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.io.semantic_kitti import SemanticKittiSequence, read_label
from ros2_mos.scoring.evaluation import predict_sequence

runner = CliRunner()
N_SCANS = 25


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sim")
    result = runner.invoke(app, ["simulate", str(root), "--sequences", "00", "--scans", str(N_SCANS),
                                 "--preset", "easy", "--sensor", "vlp16", "--seed", "3", "--no-bag"])
    assert result.exit_code == 0, result.output
    return root


@pytest.fixture(scope="module")
def vlp16_model(tmp_path_factory) -> Path:
    return make_threshold_model(tmp_path_factory.mktemp("m") / "vlp16.onnx", sensor_preset("vlp16"), n_past=2)


def test_infer_writes_one_label_per_point_and_eval_scores_it(dataset, vlp16_model, tmp_path):
    pred = tmp_path / "pred"
    result = runner.invoke(app, ["infer", str(dataset / "sequences" / "00"), "--model", str(vlp16_model),
                                 "--out", str(pred)])
    assert result.exit_code == 0, result.output
    seq = SemanticKittiSequence(dataset / "sequences" / "00")
    files = sorted((pred / "sequences" / "00" / "predictions").glob("*.label"))
    assert len(files) == N_SCANS
    for i, f in enumerate(files):
        labels = read_label(f, len(seq[i].points))
        assert set(np.unique(labels)) <= {9, 251}
    result = runner.invoke(app, ["eval", str(pred), str(dataset)])
    assert result.exit_code == 0, result.output
    assert "all" in result.output and "IoU" in result.output


def test_pipeline_odometry_stays_close_to_ground_truth(dataset, vlp16_model):
    seq = SemanticKittiSequence(dataset / "sequences" / "00")
    pipe = MosPipeline(MosConfig(model=str(vlp16_model)))
    estimated = np.array([p.result.pose for p in predict_sequence(pipe, seq)])
    gt = seq.poses[: len(estimated)]
    # Both trajectories start at their first pose: compare motion relative to it.
    rel_est = np.linalg.inv(estimated[0]) @ estimated
    rel_gt = np.linalg.inv(gt[0]) @ gt
    travelled = np.linalg.norm(rel_gt[-1][:3, 3])
    error = np.linalg.norm(rel_est[:, :3, 3] - rel_gt[:, :3, 3], axis=1).max()
    assert error < 0.05 * travelled + 0.3, f"max position error {error:.2f} m over {travelled:.1f} m"


def test_eval_says_when_it_covers_only_part_of_the_ground_truth(dataset, tmp_path):
    """Two ground-truth sequences, predictions for one: 'all' is the one, and the output says so; a short
    ground-truth label file is named as the ground truth's fault, not the prediction's."""
    import shutil

    from ros2_mos.io.semantic_kitti import write_label

    gt = tmp_path / "gt"
    for name in ("00", "01"):
        shutil.copytree(dataset / "sequences" / "00", gt / "sequences" / name)
    pred = tmp_path / "pred"
    seq = SemanticKittiSequence(gt / "sequences" / "00")
    for i in range(len(seq)):
        write_label(pred / "sequences" / "00" / "predictions" / f"{i:06d}.label", np.full(len(seq[i].points), 9))
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 0, result.output
    assert "'all' covers 1 of 2 ground-truth sequences; no predictions for 01" in result.output
    short = gt / "sequences" / "00" / "labels" / "000003.label"
    short.write_bytes(short.read_bytes()[:-8])
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code != 0 and "000003.label" in str(result.exception) and "labels/" in str(result.exception)


def test_eval_of_missing_predictions_is_a_clear_error(dataset, tmp_path):
    result = runner.invoke(app, ["eval", str(tmp_path), str(dataset)])
    assert result.exit_code != 0


def test_console_script_turns_library_errors_into_one_line_messages(tmp_path, vlp16_model):
    import subprocess
    import sys

    script = Path(sys.executable).parent / "ros2-mos"
    proc = subprocess.run([str(script), "infer", str(tmp_path / "nothing"), "--model", str(vlp16_model),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "error:" in proc.stderr and "velodyne" in proc.stderr
    assert "Traceback" not in proc.stderr
    proc = subprocess.run([str(script), "infer", str(tmp_path), "--model", str(tmp_path / "missing.onnx"),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "model file not found" in proc.stderr


def test_eval_by_instance_lists_each_mover_with_its_recall_range_and_speed(dataset, tmp_path):
    """Predictions equal to the ground truth: every mover at 100 % and no false positives; all static: every mover
    at 0 %, the most missed first. The simulator's poses give each mover a speed."""
    from ros2_mos.io.labels import to_moving_classes, to_submission
    from ros2_mos.io.semantic_kitti import write_label

    seq = SemanticKittiSequence(dataset / "sequences" / "00")
    for name, predict in (("perfect", lambda gt: gt == 1), ("static", lambda gt: np.zeros(len(gt), bool))):
        for i in range(len(seq)):
            gt = to_moving_classes(seq[i].labels)
            out = tmp_path / name / "sequences" / "00" / "predictions" / f"{i:06d}.label"
            write_label(out, to_submission(predict(gt)))
    result = runner.invoke(app, ["eval", str(tmp_path / "perfect"), str(dataset), "--by-instance", "--top", "100",
                                 "--convention", "semantickitti"])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.output.splitlines() if line.startswith("00 ")]
    assert rows and all(r[6] == "100.0" for r in rows), result.output
    assert all(r[2].startswith("moving-") for r in rows)
    seen_long = [r for r in rows if int(r[3]) >= 10]  # seen over a second: a speed from the poses
    assert seen_long and all(0.3 < float(r[8]) < 30 for r in seen_long), result.output
    assert "false positives by class" in result.output and "none" in result.output
    result = runner.invoke(app, ["eval", str(tmp_path / "static"), str(dataset), "--by-instance", "--top", "2",
                                 "--convention", "semantickitti"])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.output.splitlines() if line.startswith("00 ")]
    assert len(rows) == 2 and all(r[6] == "0.0" for r in rows)
    assert int(rows[0][5]) >= int(rows[1][5])  # most missed first
    result = runner.invoke(app, ["eval", str(tmp_path / "static"), str(dataset), "--by-instance", "--top", "0"])
    assert result.exit_code != 0


def _write_predictions(root: Path, seq: SemanticKittiSequence, labels_of) -> Path:
    from ros2_mos.io.semantic_kitti import write_label

    for i in range(len(seq)):
        write_label(root / "sequences" / seq.name / "predictions" / f"{i:06d}.label", labels_of(i))
    return root


def _iou_lines(output: str) -> dict[str, float]:
    """{convention: the 'all' IoU} from eval's output."""
    found, convention = {}, None
    for line in output.splitlines():
        if line.startswith("label convention:"):
            convention = line.split(":")[1].strip()
        elif line.split()[:1] == ["all"]:
            found[convention] = float(line.split()[1])
    return found


def test_eval_scores_both_label_conventions_of_simulated_ground_truth(tmp_path):
    """Predictions equal to one convention's labels score 100 under it and less under the other (this jam has
    movers that stand in some scans); --convention picks one."""
    from ros2_mos.io.labels import to_moving_classes, to_submission

    dataset = tmp_path / "jam"
    result = runner.invoke(app, ["simulate", str(dataset), "--sequences", "00", "--scans", "25",
                                 "--preset", "traffic_jam", "--sensor", "vlp16", "--seed", "3"])
    assert result.exit_code == 0, result.output
    seq = SemanticKittiSequence(dataset / "sequences" / "00")
    instant_dir = dataset / "sequences" / "00" / "labels_instant"
    pred = _write_predictions(tmp_path / "p", seq, lambda i: to_submission(
        to_moving_classes(read_label(instant_dir / f"{i:06d}.label")) == 1))
    result = runner.invoke(app, ["eval", str(pred), str(dataset)])
    assert result.exit_code == 0, result.output
    scores = _iou_lines(result.output)
    assert list(scores) == ["semantickitti", "instant"], result.output
    assert scores["instant"] == 100.0 and scores["semantickitti"] < 100.0
    result = runner.invoke(app, ["eval", str(pred), str(dataset), "--convention", "instant"])
    assert result.exit_code == 0 and list(_iou_lines(result.output)) == ["instant"]
    result = runner.invoke(app, ["eval", str(pred), str(dataset), "--convention", "moving"])
    assert result.exit_code != 0 and "unknown --convention" in result.output


def test_eval_reads_predictions_as_the_benchmark_does(dataset, tmp_path):
    """Every id 251-259 is moving (252 scores as 251); binary 0/1 and unknown ids are a clear error; a damaged file
    is an error; a prediction file without a scan is a warning."""
    from ros2_mos.io.labels import to_moving_classes

    seq = SemanticKittiSequence(dataset / "sequences" / "00")

    def moving(i: int) -> np.ndarray:
        return to_moving_classes(seq[i].labels) == 1

    ious = {}
    for name, ids in (("251", (9, 251)), ("252", (40, 252)), ("binary", (0, 1)), ("classes", (3, 7))):
        pred = _write_predictions(tmp_path / name, seq, lambda i: np.where(moving(i), ids[1], ids[0]).astype(np.uint32))
        result = runner.invoke(app, ["eval", str(pred), str(dataset), "--convention", "semantickitti"])
        if name in ("251", "252"):
            assert result.exit_code == 0, result.output
            ious[name] = _iou_lines(result.output)["semantickitti"]
        else:
            assert result.exit_code != 0 and "SemanticKITTI" in str(result.exception), name
    assert ious["251"] == ious["252"] == 100.0
    pred = tmp_path / "251" / "sequences" / "00" / "predictions"
    (pred / "000999.label").write_bytes(b"")
    result = runner.invoke(app, ["eval", str(tmp_path / "251"), str(dataset), "--convention", "semantickitti"])
    assert result.exit_code == 0 and "1 prediction file(s) without a scan" in result.output
    damaged = pred / "000004.label"
    damaged.write_bytes(damaged.read_bytes() + b"\x00\x00")
    result = runner.invoke(app, ["eval", str(tmp_path / "251"), str(dataset), "--convention", "semantickitti"])
    assert result.exit_code != 0 and "not a multiple of 4" in str(result.exception)
