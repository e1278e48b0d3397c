"""The torch (GPU) geometry path computes what the numpy path computes (checked on the CPU)."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from conftest import TEST_SENSOR  # noqa: E402
from scenes import street_sequence  # noqa: E402

from ros2_mos.core import torch_geometry  # noqa: E402
from ros2_mos.core.config import PostprocessConfig, ResidualConfig  # noqa: E402
from ros2_mos.core.postprocess import knn_backproject  # noqa: E402
from ros2_mos.core.projection import project, project_range  # noqa: E402
from ros2_mos.core.residuals import residual_images  # noqa: E402


def test_range_image_and_residuals_match_numpy():
    seq = street_sequence(3)
    (p0, _, _, pose0), (p1, _, _, pose1), (p2, _, _, pose2) = seq
    cur = torch.from_numpy(p2)
    np.testing.assert_allclose(torch_geometry.range_image(cur, TEST_SENSOR).numpy(), project_range(p2, TEST_SENSOR),
                               atol=1e-4)
    ref = residual_images(project_range(p2, TEST_SENSOR), pose2, [(p1, pose1), (p0, pose0)], 2, TEST_SENSOR,
                          ResidualConfig())
    got = torch_geometry.residual_images(torch_geometry.range_image(cur, TEST_SENSOR), pose2,
                                    [(torch.from_numpy(p1), pose1), (torch.from_numpy(p0), pose0)], 2, TEST_SENSOR,
                                    ResidualConfig()).numpy()
    assert ref.any()
    # float32 transforms in torch vs float64 in numpy: a few boundary pixels may flip, values agree.
    close = np.isclose(got, ref, atol=1e-3)
    assert close.mean() > 0.995


def test_signed_residuals_at_offsets_match_numpy():
    seq = street_sequence(4)
    past = [(p, pose) for p, _, _, pose in seq[:3]][::-1]  # newest first
    pts, _, _, pose = seq[3]
    current = project_range(pts, TEST_SENSOR)
    ref = residual_images(current, pose, past, 2, TEST_SENSOR, ResidualConfig(), offsets=(1, 3), signed=True)
    geometry = torch_geometry.TorchGeometry(TEST_SENSOR, "cpu")
    got = geometry.residuals(current, pose, past, 2, ResidualConfig(), (1, 3), True)
    assert (ref < 0).any() and (ref > 0).any()
    assert np.isclose(got, ref, atol=1e-3).mean() > 0.995


def test_knn_matches_numpy():
    pts, rem, _, _ = street_sequence(1)[0]
    image = project(pts, rem, TEST_SENSOR)
    rng = np.random.default_rng(0)
    prob = np.zeros(image.range.shape, np.float32)
    prob[8:20, 100:160] = rng.uniform(0, 1, (12, 60))
    cfg = PostprocessConfig()
    ref = knn_backproject(prob, image.range, image.pixels, cfg)
    got = torch_geometry.knn_backproject(torch.from_numpy(prob), torch.from_numpy(image.range), image.pixels,
                                         cfg).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-5)


def test_pipeline_with_the_torch_backend_gives_the_numpy_labels(tiny_model_path):
    from ros2_mos.core.config import MosConfig
    from ros2_mos.core.pipeline import MosPipeline

    pipes = [MosPipeline(MosConfig(model=str(tiny_model_path), geometry_backend=b, device="cpu"))
             for b in ("numpy", "torch")]
    agree = []
    for i, (pts, rem, _, pose) in enumerate(street_sequence(4)):
        a, b = (p.process(pts, rem, 0.1 * i, pose=pose) for p in pipes)
        agree.append((a.labels == b.labels).mean())
    assert min(agree) > 0.995 and pipes[1].process(pts, rem, 1.0, pose=pose).labels.any()


def test_devices_this_torch_cannot_use_are_config_errors():
    from ros2_mos.core.config import MosConfig
    from ros2_mos.core.errors import ConfigError
    from ros2_mos.core.torch_geometry import pick_device

    with pytest.raises(ConfigError, match="device must be auto, cpu, cuda or cuda:N, got 'quantum'"):
        MosConfig(geometry_backend="torch", device="quantum")
    with pytest.raises(ConfigError, match="not a torch device"):
        pick_device("quantum")
    assert pick_device("cpu").type == "cpu" and pick_device("auto").type in ("cpu", "cuda")
    if not torch.cuda.is_available():  # this CPU build: cuda is refused with the reason, not at the first scan
        with pytest.raises(ConfigError, match="no CUDA device"):
            pick_device("cuda")


def test_free_space_matches_numpy():
    from ros2_mos.core.residuals import free_space_images

    seq = street_sequence(4)
    past = [(project_range(p, TEST_SENSOR), pose) for p, _, _, pose in seq[:3]][::-1]  # own range images
    pts, _, _, pose = seq[3]
    current = project(pts, np.zeros(len(pts), np.float32), TEST_SENSOR)
    ref = free_space_images(current.xyz, current.mask, pose, past, (1, 3), TEST_SENSOR, ResidualConfig())
    got = torch_geometry.TorchGeometry(TEST_SENSOR, "cpu").free_space(current, pose, past, (1, 3), ResidualConfig())
    assert (ref > 0.05).any()
    assert np.isclose(got, ref, atol=1e-3).mean() > 0.995
