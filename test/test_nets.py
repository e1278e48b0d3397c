"""Every registered network builds for the paper's input setups, maps (B, C, H, W) to (B, 2, H, W), and exports."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from ros2_mos.core.config import SensorConfig  # noqa: E402
from ros2_mos.core.errors import ConfigError  # noqa: E402
from ros2_mos.core.metadata import ModelMetadata  # noqa: E402
from ros2_mos.core.network_input import InputSetup  # noqa: E402
from ros2_mos.training.export import export_onnx  # noqa: E402
from ros2_mos.training.nets import build_network, network_names  # noqa: E402

# one frame, two frames, N = 1, N = 8 (5, 10, 6, 13 channels); z + signed residuals and free space at 1, 2, 4, 8 (9)
SETUPS = [InputSetup("residual", 0), InputSetup("frames", 1), InputSetup("residual", 1), InputSetup("residual", 8),
          InputSetup("residual", 4, (1, 2, 4, 8), True, ("z",), free_space=True)]
NETS = ["fastmos", "salsanext", "rangenet21", "minet"]


@pytest.mark.parametrize("name", NETS)
@pytest.mark.parametrize("setup", SETUPS, ids=lambda s: f"C{s.channels}")
def test_network_shapes(name, setup):
    torch.manual_seed(0)
    net = build_network(name, setup.channels).eval()
    with torch.no_grad():
        out = net(torch.randn(2, setup.channels, 32, 256))
    assert out.shape == (2, 2, 32, 256)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("name", NETS)
def test_network_exports_to_onnx(name, tmp_path):
    setup = InputSetup("residual", 8)
    meta = ModelMetadata(name, setup, SensorConfig("t", 32, 256, 3.0, -25.0, 0.0, 120.0))
    report = export_onnx(build_network(name, setup.channels), meta, tmp_path / f"{name}.onnx")
    assert report.max_abs_diff < 1e-4


def test_salsanext_parameter_names_match_the_original():
    net = build_network("salsanext", 13)
    keys = set(net.state_dict())
    for key in (
        "downCntx.conv1.weight", "downCntx3.bn2.running_mean", "resBlock1.conv5.weight", "resBlock5.bn4.weight",
        "upBlock1.conv1.weight", "upBlock4.conv4.weight", "logits.weight",
    ):
        assert key in keys
    assert net.state_dict()["downCntx.conv1.weight"].shape == (32, 13, 1, 1)
    assert net.state_dict()["upBlock1.conv1.weight"].shape == (128, 64 + 256, 3, 3)
    assert sum(p.numel() for p in net.parameters()) == pytest.approx(6.7e6, rel=0.02)


def test_rangenet21_structure():
    net = build_network("rangenet21", 5)
    keys = set(net.state_dict())
    assert "backbone.enc3.residual_1.conv2.weight" in keys and "backbone.enc3.residual_2.conv2.weight" not in keys
    assert "decoder.dec5.upconv.weight" in keys and "head.1.weight" in keys


def test_registry_rejects_unknown_names():
    assert set(NETS) <= set(network_names())
    with pytest.raises(ConfigError):
        build_network("nope", 5)
