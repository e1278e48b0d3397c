"""Shared fixtures: a real (non-learned) ONNX model exported with the project's exporter.

``tiny_model_path`` is the paper's "Residual" baseline as a network: a pixel is moving
when its largest residual exceeds a threshold.  It is exact, tiny and needs no training,
so the pipeline, the node and the CLI can be tested end to end before and beside the
trained default model.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from ros2_mos.core import kernels  # noqa: E402
from ros2_mos.core.config import SensorConfig  # noqa: E402

TEST_SENSOR = SensorConfig(
    "test32", height=32, width=512, fov_up_deg=10.0, fov_down_deg=-20.0, min_range=0.0, max_range=100.0
)


def make_threshold_model(path: Path, sensor: SensorConfig = TEST_SENSOR, n_past: int = 2, threshold: float = 0.08,
                         setup=None) -> Path:
    """Export the thresholded-residual baseline as an ONNX model with metadata (any residual ``setup``)."""
    import torch
    from torch import nn

    from ros2_mos.core.metadata import ModelMetadata
    from ros2_mos.core.network_input import InputSetup
    from ros2_mos.training.export import export_onnx

    class ResidualThreshold(nn.Module):
        def __init__(self, n_frame: int) -> None:
            super().__init__()
            self.gain, self.threshold, self.n_frame = 200.0, threshold, n_frame

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            d = x[:, self.n_frame :].abs().amax(dim=1, keepdim=True)
            moving = self.gain * (d - self.threshold)
            return torch.cat([torch.zeros_like(moving), moving], dim=1)

    setup = setup or InputSetup("residual", n_past)
    meta = ModelMetadata(network="residual-threshold", input=setup, sensor=sensor,
                         trained_on="none (hand-set threshold)")
    export_onnx(ResidualThreshold(len(setup.image_channels)), meta, path)
    return path


def make_wrong_channels_model(path: Path) -> Path:
    """A network taking 7 channels (N=2) whose metadata claims N=5 (10 channels): the wrong input size."""
    import dataclasses

    import onnx

    from ros2_mos.core.metadata import METADATA_KEY, ModelMetadata

    make_threshold_model(path, n_past=2)
    model = onnx.load(str(path))
    prop = next(p for p in model.metadata_props if p.key == METADATA_KEY)
    meta = ModelMetadata.from_json(prop.value)
    meta.input = dataclasses.replace(meta.input, n_past=5)
    prop.value = meta.to_json()
    onnx.save(model, str(path))
    return path


@pytest.fixture(scope="session")
def tiny_model_path(tmp_path_factory) -> Path:
    return make_threshold_model(tmp_path_factory.mktemp("models") / "threshold.onnx")


@pytest.fixture(params=["compiled", "numpy"])
def geometry_code(request):
    """Runs a test on the compiled kernels and again on the numpy code (``kernels.disabled``)."""
    if request.param == "numpy":
        with kernels.disabled():
            yield request.param
    else:
        if not kernels.enabled():
            pytest.skip(kernels.status())
        yield request.param
