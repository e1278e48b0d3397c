"""ONNX export: the file ends in a softmax, carries its metadata, and matches PyTorch."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
ort = pytest.importorskip("onnxruntime")

from ros2_mos.core.config import SensorConfig  # noqa: E402
from ros2_mos.core.errors import ModelError  # noqa: E402
from ros2_mos.core.metadata import METADATA_KEY, ModelMetadata  # noqa: E402
from ros2_mos.core.network_input import InputSetup  # noqa: E402
from ros2_mos.training.export import INPUT_NAME, OUTPUT_NAME, export_onnx, read_metadata  # noqa: E402
from ros2_mos.training.nets import build_network  # noqa: E402

SMALL = SensorConfig("small", 16, 256, 3.0, -25.0, 0.0, 120.0)


def _meta(n_past: int = 2) -> ModelMetadata:
    return ModelMetadata(
        network="fastmos",
        input=InputSetup("residual", n_past),
        sensor=SMALL,
        trained_on="unit test",
        valid_iou=0.5,
        extra={"epochs": 1},
    )


def test_export_round_trip_matches_pytorch(tmp_path):
    torch.manual_seed(0)
    meta = _meta()
    net = build_network("fastmos", meta.input.channels)
    report = export_onnx(net, meta, tmp_path / "m.onnx")
    assert report.max_abs_diff < 1e-5
    session = ort.InferenceSession(str(report.path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == [INPUT_NAME]
    assert [o.name for o in session.get_outputs()] == [OUTPUT_NAME]
    x = np.random.default_rng(1).normal(size=(1, meta.input.channels, SMALL.height, SMALL.width)).astype(np.float32)
    (prob,) = session.run([OUTPUT_NAME], {INPUT_NAME: x})
    assert prob.shape == (1, 2, SMALL.height, SMALL.width)
    np.testing.assert_allclose(prob.sum(axis=1), 1.0, atol=1e-5)
    with torch.no_grad():
        expected = torch.softmax(net.eval()(torch.from_numpy(x)), dim=1).numpy()
    assert np.max(np.abs(prob - expected)) < 1e-5


def test_metadata_round_trip_through_onnx(tmp_path):
    import onnx

    meta = _meta(3)
    export_onnx(build_network("fastmos", meta.input.channels), meta, tmp_path / "m.onnx")
    assert read_metadata(tmp_path / "m.onnx") == meta
    proto = onnx.load(str(tmp_path / "m.onnx"))
    props = {p.key: p.value for p in proto.metadata_props}
    assert ModelMetadata.from_json(props[METADATA_KEY]) == meta


def test_export_rejects_a_network_of_the_wrong_input(tmp_path):
    meta = _meta(2)
    with pytest.raises(ModelError):
        export_onnx(build_network("fastmos", meta.input.channels + 1), meta, tmp_path / "m.onnx")
    assert not (tmp_path / "m.onnx").exists()


def test_export_keeps_training_mode(tmp_path):
    meta = _meta(1)
    net = build_network("fastmos", meta.input.channels).train()
    export_onnx(net, meta, tmp_path / "m.onnx")
    assert net.training


def test_export_names_the_training_config(tmp_path):
    from ros2_mos.core.metadata import TRAINING_CONFIG_KEY, read_training_config

    meta = _meta()
    net = build_network("fastmos", meta.input.channels)
    export_onnx(net, meta, tmp_path / "a.onnx", training_config="configs/x.yaml")
    assert read_training_config(tmp_path / "a.onnx") == "configs/x.yaml"
    assert read_metadata(tmp_path / "a.onnx") == meta
    # from the metadata's extra (export_checkpoint(..., extra=...)): its own entry, not kept in the JSON
    named = ModelMetadata(**{**meta.__dict__, "extra": {**meta.extra, TRAINING_CONFIG_KEY: "configs/y.yaml"}})
    export_onnx(net, named, tmp_path / "b.onnx")
    assert read_training_config(tmp_path / "b.onnx") == "configs/y.yaml"
    assert TRAINING_CONFIG_KEY not in read_metadata(tmp_path / "b.onnx").extra
    export_onnx(net, meta, tmp_path / "c.onnx")
    assert read_training_config(tmp_path / "c.onnx") is None
