"""Every shipped model names the training config that made it, and that config is in the repository."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from ros2_mos.core.errors import ModelError
from ros2_mos.core.inference import read_metadata
from ros2_mos.core.metadata import TRAINING_CONFIG_KEY, read_training_config, write_training_config

REPO = Path(__file__).resolve().parents[1]
SENSOR_MODELS = sorted((REPO / "ros2_mos" / "models").glob("*.onnx"))
#: Models adapted with `ros2-mos adapt` ship beside the defaults (benchmarks/adaptation.md), and so do alternatives
#: trained for a case the defaults are weak in (benchmarks/experiments.md, row 40).
MODELS = SENSOR_MODELS + sorted((REPO / "ros2_mos" / "models" / "adapted").glob("*.onnx")) + sorted(
    (REPO / "ros2_mos" / "models" / "alternatives").glob("*.onnx"))


def test_the_five_sensor_models_ship():
    assert {m.stem for m in SENSOR_MODELS} == {"default", "vlp16", "vlp32c", "os1-64", "os1-128"}


def test_the_alternatives_ship():
    assert {m.name for m in MODELS if m.parent.name == "alternatives"} == {"hdl64_narrow_streets.onnx"}


@pytest.mark.parametrize("name, base", [("hdl64_kitti.onnx", "default.onnx"),
                                        ("hdl64_kitti_narrow_streets.onnx", "hdl64_narrow_streets.onnx")])
def test_an_adapted_model_says_what_it_was_adapted_on(name, base):
    import json

    adapted = REPO / "ros2_mos" / "models" / "adapted" / name
    record = json.loads(read_metadata(adapted).extra["adaptation"])
    assert record["drives"] == ["08b", "r1", "r2"] and record["base"] == base
    # The base it names ships, for the same sensor.
    shipped = {m.name: m for m in MODELS}
    assert read_metadata(shipped[base]).sensor.name == read_metadata(adapted).sensor.name


def test_the_adapted_models_ship():
    assert {m.name for m in MODELS if m.parent.name == "adapted"} == {"hdl64_kitti.onnx",
                                                                      "hdl64_kitti_narrow_streets.onnx"}


@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.stem)
def test_every_shipped_model_names_an_existing_training_config(model):
    config = read_training_config(model)
    assert config, f"{model.name} names no {TRAINING_CONFIG_KEY}"
    assert config.startswith("configs/") and not config.startswith("configs/experiments/"), config
    assert (REPO / config).is_file(), f"{model.name} names {config}, which is not in the repository"
    pytest.importorskip("torch")  # the trainer's module needs it
    from ros2_mos.training.trainer import TrainConfig

    assert TrainConfig.from_yaml(REPO / config).sensor_config.name == read_metadata(model).sensor.name


def test_naming_a_config_changes_no_output(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    path = tmp_path / "m.onnx"
    shutil.copy(REPO / "ros2_mos" / "models" / "vlp16.onnx", path)
    x = None

    def run() -> np.ndarray:
        nonlocal x
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        node_input = session.get_inputs()[0]
        if x is None:
            x = np.random.default_rng(0).normal(size=node_input.shape).astype(np.float32)
        return session.run(None, {node_input.name: x})[0]

    before = run()
    write_training_config(path, "configs/elsewhere.yaml")
    write_training_config(path, "configs/other.yaml")  # replaced, not added twice
    assert read_training_config(path) == "configs/other.yaml"
    import onnx

    assert [p.key for p in onnx.load(str(path)).metadata_props].count(TRAINING_CONFIG_KEY) == 1
    assert run().tobytes() == before.tobytes()
    with pytest.raises(ModelError):
        write_training_config(path, "")
