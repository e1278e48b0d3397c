"""The evaluation suite, the threshold calibration and the baselines as functions (hand cases + a tiny run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import TEST_SENSOR, make_threshold_model
from scenes import write_sequence

from ros2_mos.core.config import MosConfig
from ros2_mos.core.errors import ModelError
from ros2_mos.core.metadata import check_threshold, write_recommended_threshold
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.io.semantic_kitti import SemanticKittiSequence
from ros2_mos.scoring.baselines import (
    free_space_seeds,
    grow_regions,
    residual_threshold,
)
from ros2_mos.scoring.calibration import BINS, ThresholdCurve, threshold_curve
from ros2_mos.scoring.suite import (
    RowScore,
    format_table,
    real_sequences,
    score_sequence,
)


def test_region_growing_labels_whole_regions_by_their_seed_share():
    regions = np.array([[0, 0, 0, 0, 4, 4, -1, 7]])
    seeds = np.array([[1, 0, 0, 0, 1, 0, 1, 0]], bool)
    # region 0: 1 of 4 seeds (25 %), region 4: 1 of 2 (50 %), the seed at -1 is no region's, region 7: none.
    np.testing.assert_array_equal(grow_regions(seeds, regions, 0.3), [[0, 0, 0, 0, 1, 1, 0, 0]])
    np.testing.assert_array_equal(grow_regions(seeds, regions, 0.25), [[1, 1, 1, 1, 1, 1, 0, 0]])
    assert not grow_regions(np.zeros_like(seeds), regions, 0.0).any()


def test_free_space_seeds_need_both_residuals_positive_and_the_threshold_is_absolute():
    signed = np.array([[[0.2, 0.2, -0.3]], [[0.15, -0.2, -0.3]]])
    np.testing.assert_array_equal(free_space_seeds(signed, 0.1), [[True, False, False]])
    np.testing.assert_array_equal(residual_threshold(signed[0], 0.25), [[False, False, True]])


def test_threshold_curve_counts_by_hand():
    moving = np.zeros(BINS, np.int64)
    static = np.zeros(BINS, np.int64)
    moving[[90, 60, 20]] = [10, 5, 5]  # 20 moving points
    static[[95, 55, 10]] = [2, 8, 100]
    curve = ThresholdCurve(moving, static)
    iou = curve.iou()
    assert iou[90] == pytest.approx(10 / (10 + 2 + 10))  # >= 0.90: tp 10, fp 2 (the 0.95 bin), fn 10
    assert iou[60] == pytest.approx(15 / (15 + 2 + 5))
    assert iou[50] == pytest.approx(15 / (15 + 10 + 5))
    assert iou[20] == pytest.approx(20 / (20 + 10))
    # best: just above the 0.55 static bin, below the 0.60 moving one (the first such threshold)
    assert curve.best() == (pytest.approx(0.56), pytest.approx(15 / 22))
    # at a threshold: the nearest bin edge; above the last edge (0.99), the last
    assert curve.iou_at(0.5) == curve.iou_at(0.504) == pytest.approx(15 / 30)
    assert curve.iou_at(0.996) == pytest.approx(0.0)  # >= 0.99: no point, tp 0


@pytest.fixture(scope="module")
def labelled_sequence(tmp_path_factory) -> SemanticKittiSequence:
    return SemanticKittiSequence(write_sequence(tmp_path_factory.mktemp("score"), "00", 6, seed=2))


def test_calibration_curve_agrees_with_the_pipelines_labels(labelled_sequence, tiny_model_path):
    """The full kNN vote thresholded at t gives the labels the pipeline's shortcut vote gives at t."""
    from ros2_mos.io.labels import to_moving_classes
    from ros2_mos.scoring.metrics import MovingIoU

    for threshold in (0.3, 0.5, 0.8):
        pipe = MosPipeline(MosConfig(model=str(tiny_model_path), threshold=threshold))
        curve = threshold_curve(pipe, [labelled_sequence], use_dataset_poses=True)
        pipe.reset()
        score = MovingIoU()
        for frame in labelled_sequence:
            result = pipe.process(frame.points, frame.remission, frame.timestamp, pose=frame.pose)
            score.update(result.labels, to_moving_classes(frame.labels))
        tp, fp, fn = (int(c[int(round(threshold * BINS))]) for c in curve.counts())
        assert (tp, fp, fn) == (score.tp, score.fp, score.fn)
        assert score.tp > 0


def test_suite_row_scores_the_model_and_both_baselines_on_the_same_scans(labelled_sequence, tiny_model_path):
    pipe = MosPipeline(MosConfig(model=str(tiny_model_path)))
    rows = score_sequence(pipe, labelled_sequence, "street", warmup=2)
    assert list(rows) == ["semantickitti"]  # labels/ without label_convention.txt: SemanticKITTI's, as real data
    row = rows["semantickitti"]
    assert row.scans == 4
    n_points = sum(len(labelled_sequence[i].points) for i in range(2, 6))
    for score in (row.model, row.residual, row.region_growing):
        assert score.tp + score.fp + score.fn + score.tn == n_points
    assert row.model.iou > 0.3 and row.residual.tp > 0
    assert 0 < row.max_moving_fraction < 0.5
    table = format_table([row, RowScore("total")])
    assert "| street | 4 |" in table and "| total | 0 | **–** |" in table


def test_a_suite_row_per_label_convention_scores_the_same_labels_against_each(tmp_path, tiny_model_path):
    """A sequence with labels/ (instant, by label_convention.txt) and labels_semantickitti/: one row each; where the
    instant labels have nothing moving, that row has no true positive and no miss, and both rows count the same
    points labelled moving."""
    import shutil

    from ros2_mos.io.conventions import write_convention_file
    from ros2_mos.io.semantic_kitti import read_label, write_label

    seq_dir = write_sequence(tmp_path, "00", 6, seed=2)
    shutil.copytree(seq_dir / "labels", seq_dir / "labels_semantickitti")
    for f in (seq_dir / "labels").glob("*.label"):
        write_label(f, np.full(len(read_label(f)), 40, np.uint32))
    write_convention_file(seq_dir, "instant")
    pipe = MosPipeline(MosConfig(model=str(tiny_model_path)))
    rows = score_sequence(pipe, SemanticKittiSequence(seq_dir), "street", warmup=2)
    assert list(rows) == ["instant", "semantickitti"]
    instant, sk = rows["instant"].model, rows["semantickitti"].model
    assert instant.tp == 0 and instant.fn == 0 and sk.tp > 0
    assert instant.tp + instant.fp == sk.tp + sk.fp > 0
    assert rows["instant"].region_growing.tp == 0 and rows["semantickitti"].region_growing.tp > 0


def test_a_suite_row_s_breakdown_accounts_for_every_scored_point(labelled_sequence, tiny_model_path):
    """The breakdown of the scored scans: movers' found and missed points are the row's TP and FN, the false
    positives by class and by range both add up to its FP."""
    from ros2_mos.scoring.breakdown import ErrorBreakdown

    pipe = MosPipeline(MosConfig(model=str(tiny_model_path)))
    breakdown = ErrorBreakdown()
    row = score_sequence(pipe, labelled_sequence, "street", warmup=2, breakdown=breakdown)["semantickitti"]
    movers = breakdown.movers()
    assert breakdown.scans == row.scans == 4 and movers
    assert {m.sequence for m in movers} == {labelled_sequence.name}
    assert sum(m.found for m in movers) == row.model.tp > 0
    assert sum(m.missed for m in movers) == row.model.fn
    assert sum(n for _, n in breakdown.false_positives_by_class()) == row.model.fp
    assert sum(band.false_positives for band in breakdown.by_range()) == row.model.fp


def test_real_scans_are_skipped_cleanly_when_absent(tmp_path):
    assert real_sequences(tmp_path / "nothing") == []
    assert real_sequences(None) == []
    (tmp_path / "sequences" / "08a" / "velodyne").mkdir(parents=True)
    assert real_sequences(tmp_path) == []  # no labels/: not scorable
    (tmp_path / "sequences" / "08a" / "labels").mkdir()
    assert [p.name for p in real_sequences(tmp_path)] == ["08a"]


def test_recommended_threshold_is_checked_and_written(tmp_path):
    path = make_threshold_model(tmp_path / "m.onnx")
    write_recommended_threshold(path, 0.73)
    assert MosPipeline(MosConfig(model=str(path))).threshold == pytest.approx(0.73)
    for bad in (0.0, 1.0, 7.0, float("nan"), "0.5", True):
        with pytest.raises(ModelError):
            check_threshold(bad)
        with pytest.raises(ModelError):
            write_recommended_threshold(path, bad)
    assert MosPipeline(MosConfig(model=str(path))).threshold == pytest.approx(0.73)


def test_suite_uses_the_test_sensor(tiny_model_path):
    assert MosPipeline(MosConfig(model=str(tiny_model_path))).sensor == TEST_SENSOR


def test_model_metadata_with_zero_or_non_finite_stds_is_refused():
    import json

    from ros2_mos.core.config import SensorConfig
    from ros2_mos.core.metadata import ModelMetadata
    from ros2_mos.core.network_input import InputSetup

    good = ModelMetadata("fastmos", InputSetup("residual", 1), SensorConfig()).to_json()
    for key, value in (("stds", [1.0, 1.0, 0.0, 1.0, 1.0]), ("means", [0.0, float("nan"), 0, 0, 0]),
                       ("extra", {"recommended_threshold": 7})):
        data = json.loads(good)
        data[key] = value
        with pytest.raises(ModelError):
            ModelMetadata.from_json(json.dumps(data))
    assert ModelMetadata.from_json(good).stds[2] > 0


def test_calibrate_reports_the_iou_at_the_models_own_threshold_and_the_best(labelled_sequence, tiny_model_path):
    """`ros2-mos calibrate`: the best threshold, and the IoU at the model's own as the pipeline labels it."""
    import re

    from typer.testing import CliRunner

    from ros2_mos.cli import app
    from ros2_mos.io.labels import to_moving_classes
    from ros2_mos.scoring.metrics import MovingIoU

    result = CliRunner().invoke(app, ["calibrate", str(labelled_sequence.root), "--model", str(tiny_model_path),
                                      "--use-poses"])
    assert result.exit_code == 0, result.output
    found = re.search(r"best threshold ([\d.]+): moving IoU ([\d.]+) \(00; at the model's own ([\d.]+): ([\d.]+)\)",
                      result.output)
    assert found, result.output
    best, best_iou, own, own_iou = (float(g) for g in found.groups())
    # At the model's own threshold the pipeline labels exactly what the curve counts (at another one, state that
    # depends on the labels, such as the memory of movers, evolves differently: the curve is an estimate there).
    pipe = MosPipeline(MosConfig(model=str(tiny_model_path)))
    assert own == pytest.approx(pipe.threshold)
    score = MovingIoU()
    for frame in labelled_sequence:
        out = pipe.process(frame.points, frame.remission, frame.timestamp, pose=frame.pose)
        score.update(out.labels, to_moving_classes(frame.labels))
    assert own_iou == pytest.approx(100 * score.iou, abs=0.051)
    assert best_iou > own_iou and best != own  # this model's best threshold is not its own


def test_simulated_suite_drives_are_not_mixed_with_skewed_ones(tmp_path):
    """A root of drives simulated without intra-sweep motion (their sweep.txt says compensated) is refused for skewed
    ones, and the other way round; each is reused as it is."""
    from ros2_mos.core.errors import DatasetError
    from ros2_mos.scoring.suite import ensure_sim_sequences

    seeds = {"easy": (3,)}
    plain = ensure_sim_sequences(tmp_path / "plain", 3, seeds, sensor="vlp16")
    assert (plain[0][2] / "sweep.txt").read_text().strip() == "compensated"
    assert ensure_sim_sequences(tmp_path / "plain", 3, seeds, sensor="vlp16") == plain
    with pytest.raises(DatasetError, match="simulated without intra-sweep motion"):
        ensure_sim_sequences(tmp_path / "plain", 3, seeds, sensor="vlp16", skewed=True)
    skewed = ensure_sim_sequences(tmp_path / "skewed", 3, seeds, sensor="vlp16", skewed=True)
    assert (skewed[0][2] / "sweep.txt").read_text().strip() == "skewed"
    with pytest.raises(DatasetError, match="simulated with intra-sweep motion"):
        ensure_sim_sequences(tmp_path / "skewed", 3, seeds, sensor="vlp16")


def test_a_suite_drive_written_by_another_simulator_or_not_to_its_end_is_simulated_anew(tmp_path, monkeypatch):
    """Each simulated drive says what made it (simulator.txt, written last): one this simulator made with these
    settings is reused as it is; one that another version made, one cut off before its end and one that says nothing
    are simulated again, with a line saying why."""
    import ros2_mos.sim.writer as writer
    from ros2_mos.scoring.suite import ensure_sim_sequences

    seeds = {"easy": (3,)}
    log: list[str] = []
    (_, _, folder), = ensure_sim_sequences(tmp_path, 3, seeds, log.append, sensor="vlp16")
    stamp = folder / writer.SIMULATOR_FILE
    first = stamp.read_text()
    scan = (folder / "velodyne" / "000002.bin").read_bytes()
    assert len(log) == 1 and len(first.strip()) == 16
    ensure_sim_sequences(tmp_path, 3, seeds, log.append, sensor="vlp16")
    assert len(log) == 1  # reused

    for spoil in (lambda: stamp.write_text("0123456789abcdef\n"),  # another version of the simulator
                  stamp.unlink):  # cut off before its end, or written before the stamp existed
        spoil()
        log.clear()
        ensure_sim_sequences(tmp_path, 3, seeds, log.append, sensor="vlp16")
        assert len(log) == 2 and "anew" in log[0]
        assert stamp.read_text() == first and (folder / "velodyne" / "000002.bin").read_bytes() == scan

    # A simulation into the folder that stops before its end leaves it unstamped
    def broken_scan(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(writer, "write_scan", broken_scan)
    with pytest.raises(OSError):
        writer.simulate_sequence(tmp_path, folder.name, 3, "easy", 3, "vlp16")
    assert not stamp.exists()
    monkeypatch.undo()

    # The fingerprint follows the settings and the simulator's own sources
    from ros2_mos.core.config import sensor_preset
    from ros2_mos.sim import sim_preset

    base = writer.simulator_fingerprint(sim_preset("easy"), sensor_preset("vlp16"), 3, folder.name, 3)
    assert base == first.strip()
    assert writer.simulator_fingerprint(sim_preset("easy"), sensor_preset("vlp32c"), 3, folder.name, 3) != base
    assert writer.simulator_fingerprint(sim_preset("easy"), sensor_preset("vlp16"), 4, folder.name, 3) != base
    source = tmp_path / "sim_copy"
    source.mkdir()
    for path in Path(writer.__file__).parent.glob("*.py"):
        (source / path.name).write_bytes(path.read_bytes())
    (source / "traffic.py").write_bytes((source / "traffic.py").read_bytes() + b"\n# changed\n")
    monkeypatch.setattr(writer, "__file__", str(source / "writer.py"))
    assert writer.simulator_fingerprint(sim_preset("easy"), sensor_preset("vlp16"), 3, folder.name, 3) != base
