"""Importing the LiDAR-MOS authors' released models: layouts, safety, errors, and the official preprocessing.

Checkpoints are built here in the published layouts with random weights (nothing is downloaded):
SalsaNext's ``torch.save`` dict (with and without DataParallel's ``module.`` prefix, with a pickled
scheduler object whose unpickling would run a command) and RangeNet++'s three state dicts.
"""

from __future__ import annotations

import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
yaml = pytest.importorskip("yaml")

from ros2_mos.core.config import ResidualConfig, SensorConfig  # noqa: E402
from ros2_mos.core.errors import ModelError  # noqa: E402
from ros2_mos.core.inference import MosModel  # noqa: E402
from ros2_mos.core.network_input import assemble_input  # noqa: E402
from ros2_mos.core.projection import project  # noqa: E402
from ros2_mos.core.residuals import residual_images  # noqa: E402
from ros2_mos.training.lidar_mos import import_lidar_mos, safe_load  # noqa: E402
from ros2_mos.training.nets import build_network  # noqa: E402

H, W = 32, 256
MEANS = [12.12, 10.88, 0.23, -1.04, 0.21]
STDS = [12.32, 11.47, 6.91, 0.86, 0.16]


def write_arch(folder: Path, n: int, layers: int | None = None) -> None:
    sensor = {"name": "HDL64", "type": "spherical", "fov_up": 3, "fov_down": -25, "img_prop": {"width": W, "height": H},
              "img_means": MEANS, "img_stds": STDS, "n_input_scans": n, "residual": n > 0, "transform": False}
    arch = {"dataset": {"sensor": sensor, "max_points": 150000},
            "post": {"KNN": {"use": True, "params": {"knn": 5, "search": 5, "sigma": 1.0, "cutoff": 1.0}}}}
    if layers:
        arch["backbone"] = {"name": "darknet", "extra": {"layers": layers}}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "arch_cfg.yaml").write_text(yaml.safe_dump(arch))


def write_salsanext(folder: Path, n: int, prefix: str, marker: Path) -> torch.nn.Module:
    """The published SalsaNext_valid_best layout, with a scheduler object that would run a command if unpickled."""
    write_arch(folder, n)
    net = build_network("salsanext", 5 + n, 3)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.1)
    module = types.ModuleType("warmupLR")

    class warmupLR:  # noqa: N801  (the authors' name)
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    warmupLR.__module__ = "warmupLR"
    module.warmupLR = warmupLR
    sys.modules["warmupLR"] = module
    try:
        optimizer = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
        torch.save({"epoch": 7, "state_dict": {prefix + k: v for k, v in net.state_dict().items()},
                    "optimizer": optimizer.state_dict(), "info": {"best_val_iou": np.float64(0.6)},
                    "scheduler": warmupLR()}, folder / "SalsaNext_valid_best")
    finally:
        del sys.modules["warmupLR"]
    return net.eval()


def moving_probability(net: torch.nn.Module, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return torch.softmax(net(torch.from_numpy(x)[None]), dim=1)[0, 2].numpy()


@pytest.mark.parametrize("n, prefix", [(1, "module."), (8, "module."), (1, "")])
def test_salsanext_imports_and_onnx_gives_the_official_moving_probability(tmp_path, n, prefix):
    marker = tmp_path / "PICKLED_CODE_RAN"
    net = write_salsanext(tmp_path / "model", n, prefix, marker)
    report = import_lidar_mos(tmp_path / "model", tmp_path / "m.onnx")
    assert not marker.exists(), "loading ran code from the checkpoint"
    model = MosModel(tmp_path / "m.onnx")
    meta = model.metadata
    assert meta.network == "salsanext" and meta.input.n_past == n and not meta.input.signed
    assert meta.input.image_channels == ("range", "x", "y", "z", "remission")
    assert list(meta.means) == MEANS and list(meta.stds) == STDS
    assert (meta.sensor.height, meta.sensor.width, meta.sensor.fov_up_deg) == (H, W, 3.0)
    x = np.random.default_rng(n).normal(size=(5 + n, H, W)).astype(np.float32)
    np.testing.assert_allclose(model.predict(x), moving_probability(net, x), atol=1e-4)
    assert report.max_abs_diff < 1e-4


def test_rangenet_three_state_dicts_import(tmp_path):
    folder = tmp_path / "rn"
    write_arch(folder, 1, layers=21)
    net = build_network("rangenet21", 6, 3).eval()
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.05)
    torch.save(net.backbone.state_dict(), folder / "backbone")
    torch.save(net.decoder.state_dict(), folder / "segmentation_decoder")
    torch.save(net.head.state_dict(), folder / "segmentation_head")
    import_lidar_mos(folder, tmp_path / "rn.onnx")
    model = MosModel(tmp_path / "rn.onnx")
    assert model.metadata.network == "rangenet21"
    x = np.random.default_rng(3).normal(size=(6, H, W)).astype(np.float32)
    np.testing.assert_allclose(model.predict(x), moving_probability(net, x), atol=1e-4)


def test_import_errors_are_one_line_model_errors(tmp_path):
    marker = tmp_path / "ran"
    write_salsanext(tmp_path / "n1", 1, "module.", marker)
    write_arch(tmp_path / "n1", 8)  # the folder's weights are N=1
    with pytest.raises(ModelError, match="takes 6 input channels, but arch_cfg.yaml says N=8"):
        import_lidar_mos(tmp_path / "n1", tmp_path / "x.onnx")

    folder = tmp_path / "keys"
    write_salsanext(folder, 1, "module.", marker)
    ckpt = safe_load(folder / "SalsaNext_valid_best")  # not torch.load: that would run the scheduler's code
    ckpt["state_dict"].pop("module.logits.bias")
    ckpt["state_dict"]["module.extra.weight"] = torch.zeros(1)
    ckpt["scheduler"], ckpt["info"] = None, {}  # the stubs stand in for foreign objects: not re-saved
    torch.save(ckpt, folder / "SalsaNext_valid_best")
    with pytest.raises(ModelError, match=r"1 missing, e.g. \['logits.bias'\]; 1 unexpected, e.g. \['extra.weight'\]"):
        import_lidar_mos(folder, tmp_path / "x.onnx")

    (folder / "SalsaNext_valid_best").write_bytes(os.urandom(3000))
    with pytest.raises(ModelError, match="not a readable PyTorch checkpoint"):
        import_lidar_mos(folder, tmp_path / "x.onnx")

    empty = tmp_path / "empty"
    write_arch(empty, 1)
    with pytest.raises(ModelError, match="an unknown layout"):
        import_lidar_mos(empty, tmp_path / "x.onnx")
    (empty / "arch_cfg.yaml").write_text("dataset: {sensor: {}}\n")
    with pytest.raises(ModelError, match="not a LiDAR-MOS arch config"):
        import_lidar_mos(empty, tmp_path / "x.onnx")
    with pytest.raises(ModelError, match="model folder not found"):
        import_lidar_mos(tmp_path / "nothing", tmp_path / "x.onnx")
    assert not marker.exists() and not (tmp_path / "x.onnx").exists()


def test_network_input_follows_the_official_definitions():
    """LiDAR-MOS's parser, written out here from its definitions: [r, x, y, z, e] normalised with img_means /
    img_stds, residuals |r - r_j| / r where both ranges lie in (2, 50) m, everything times the projection mask."""
    from ros2_mos.core.network_input import InputSetup

    sensor = SensorConfig("lidar-mos", H, W, 3.0, -25.0, 0.0, 120.0)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20000, 3)).astype(np.float32) * [20, 20, 1]
    rem = rng.random(20000).astype(np.float32)
    past = pts + np.float32([0.3, 0.0, 0.0])
    image = project(pts, rem, sensor)
    res = residual_images(image.range, np.eye(4), [(past, np.eye(4))], 1, sensor, ResidualConfig(2.0, 50.0))
    x = assemble_input(image, res, InputSetup("residual", 1), np.array(MEANS), np.array(STDS))

    mask = image.range > 0
    frame = np.stack([image.range, image.xyz[..., 0], image.xyz[..., 1], image.xyz[..., 2], image.remission])
    expected = (frame - np.array(MEANS)[:, None, None]) / np.array(STDS)[:, None, None] * mask
    np.testing.assert_allclose(x[:5], expected, atol=1e-5)
    past_range = project(past, rem, sensor).range
    both = (image.range > 2) & (image.range < 50) & (past_range > 2) & (past_range < 50)
    official = np.where(both, np.abs(image.range - past_range) / np.where(both, image.range, 1.0), 0.0) * mask
    np.testing.assert_allclose(x[5], official, atol=1e-6)
    assert (x[5] > 0).sum() > 1000
    # The closest point wins a pixel, as the reference's order of decreasing range does.
    u, v, inside = image.pixels.u, image.pixels.v, image.pixels.in_image
    ranges = image.pixels.range
    assert inside.sum() > 5000
    assert (image.range[v[inside], u[inside]] <= ranges[inside] + 1e-5).all()
