"""The shipped default model on a held-out simulated street: a real quality check of what ships."""

from __future__ import annotations

import pytest

from ros2_mos.core.config import MosConfig
from ros2_mos.core.inference import default_model_path
from ros2_mos.io.semantic_kitti import SemanticKittiSequence
from ros2_mos.scoring.evaluation import predict_sequence
from ros2_mos.scoring.metrics import MovingIoU

# Measured on this held-out street (sequence name and seed never used in training), 60 scans, over the scans the
# 16-back input is complete for (16-59): 91.7 with round 19's 64 x 1024 model, 90.0 with round 10's 64 x 2048 one.
# (Over 14 scans, 16-29 of a 30-scan drive, the two read 75.3 and 81.9: too few scans to tell models apart.) Earlier
# models on the 30-scan drive: 87.0 round 4, 86.7 round 3, 50.1 round 2. The bound leaves room for platform
# differences, not for a regression.
MIN_IOU = 0.85
SCANS = 60


@pytest.mark.skipif(not default_model_path().is_file(), reason="no shipped model")
def test_shipped_model_finds_moving_objects_on_a_held_out_street(tmp_path):
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.sim import sequence_dir, simulate_sequence

    simulate_sequence(tmp_path, "heldout", SCANS, "benchmark", seed=4242, sensor="hdl64")
    seq = SemanticKittiSequence(sequence_dir(tmp_path, "heldout"))
    pipeline = MosPipeline(MosConfig())
    meta = pipeline.model.metadata
    assert meta.input.signed and meta.input.offsets == (1, 2, 4, 8, 16) and not meta.input.uses_remission
    assert meta.input.free_space
    assert (meta.sensor.name, meta.sensor.height, meta.sensor.width) == ("hdl64", 64, 1024)  # the LiDAR's 2048 / 2
    assert pipeline.threshold == pytest.approx(0.49)
    score = MovingIoU()
    for pred in predict_sequence(pipeline, seq):
        assert pred.result.labels.shape == pred.gt_classes.shape
        if pred.result.residuals_complete:
            score.update(pred.result.labels, pred.gt_classes)
    print(f"shipped model, held-out street: moving IoU {100 * score.iou:.1f} "
          f"(TP {score.tp}, FP {score.fp}, FN {score.fn})")
    assert score.tp > 0
    assert score.iou > MIN_IOU


NARROW_STREETS = default_model_path().parent / "alternatives" / "hdl64_narrow_streets.onnx"


@pytest.mark.skipif(not NARROW_STREETS.is_file(), reason="no shipped narrow-streets model")
def test_narrow_streets_model_keeps_parked_cars_and_vans_beside_the_sensor_static(tmp_path):
    """A held-out narrow street whose parking lane holds vans (seed never trained on), the sensor passing at 6.5 m/s:
    the default labels most of the parked vehicles passed about 2 m away moving (it never saw one that close, nor a
    parked vehicle that tall), the alternative trained with such streets under half as many (measured: 78 % and 35 %
    of their points within 5 m over scans 16-39; benchmarks/experiments.md, row 43). Not covered, because not
    learnt: a sensor standing beside a parked van (both models label most of it moving; docs/sensors.md)."""
    from dataclasses import replace

    import numpy as np

    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.labels import semantic_ids
    from ros2_mos.sim import sequence_dir, sim_preset, simulate_sequence

    preset = sim_preset("narrow_street")
    preset = replace(preset, scene=replace(preset.scene, parked_van_prob=0.5))
    simulate_sequence(tmp_path, "vans", 40, preset, seed=4348, sensor="hdl64", convention="instant")
    seq = SemanticKittiSequence(sequence_dir(tmp_path, "vans"))
    shares = {}
    for name, model in (("default", default_model_path()), ("narrow streets", NARROW_STREETS)):
        moving = parked = 0
        for pred in predict_sequence(MosPipeline(MosConfig(model=str(model))), seq):
            if not pred.result.residuals_complete:
                continue
            frame = seq[pred.index]
            near = np.linalg.norm(frame.points[:, :2], axis=1) < 5.0
            static_vehicle = np.isin(semantic_ids(frame.labels), (10, 18)) & near
            parked += int(static_vehicle.sum())
            moving += int((pred.result.labels.astype(bool) & static_vehicle).sum())
        shares[name] = moving / max(parked, 1)
    print(f"parked vehicles within 5 m labelled moving: {shares}")
    assert parked > 10_000
    assert shares["narrow streets"] < 0.6 * shares["default"]
