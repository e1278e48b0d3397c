"""Training: dataset cache + augmentation, losses, one step lowers the loss, checkpoint resume, export."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from conftest import TEST_SENSOR  # noqa: E402
from scenes import street_sequence, write_sequence  # noqa: E402

from ros2_mos.core.errors import ConfigError  # noqa: E402
from ros2_mos.core.network_input import InputSetup  # noqa: E402
from ros2_mos.core.projection import project  # noqa: E402
from ros2_mos.core.residuals import residual_images  # noqa: E402
from ros2_mos.io.labels import IGNORE  # noqa: E402
from ros2_mos.training.dataset import (  # noqa: E402
    AugmentConfig,
    CacheSpec,
    MosDataset,
    SequenceCache,
    as_range_image,
    flip_y,
    rotate_columns,
)
from ros2_mos.training.losses import MosLoss, inverse_frequency_weights, lovasz_softmax  # noqa: E402
from ros2_mos.training.trainer import TrainConfig, Trainer, export_checkpoint, load_checkpoint  # noqa: E402


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("kitti")
    write_sequence(root, "00", 5, seed=0)
    write_sequence(root, "01", 3, seed=1)
    return root


def _config(data_root, tmp_path, **kw) -> TrainConfig:
    base = dict(
        network="fastmos", n_past=2, sensor=TEST_SENSOR.to_dict(), train_sequences=["00"], valid_sequences=["01"],
        cache_dir=str(tmp_path / "cache"), out_dir=str(tmp_path / "run"), epochs=1, batch_size=2, lr=0.01,
        cache_workers=1, cache_n_residual=3, cache_n_frames=1, warmup_epochs=0.0, drop_max=0.0,
    )
    base.update(kw)
    return TrainConfig.from_dict(base)


def test_a_cache_of_some_offsets_holds_those_channels_of_the_full_cache(data_root, tmp_path):
    full = SequenceCache.build(data_root / "sequences" / "00", tmp_path / "full",
                               CacheSpec(sensor=TEST_SENSOR, n_residual=3, n_frames=0), workers=1)
    some_spec = CacheSpec(sensor=TEST_SENSOR, n_residual=3, n_frames=0, residual_offsets=(1, 3))
    some = SequenceCache.build(data_root / "sequences" / "00", tmp_path / "some", some_spec, workers=1)
    assert some.residual.shape[1] == 2 and some_spec.stored_offsets == (1, 3)
    np.testing.assert_array_equal(np.asarray(some.residual), np.asarray(full.residual)[:, [0, 2]])
    assert some.residual[3].any()
    assert some_spec.serves(InputSetup("residual", 2, (1, 3), signed=True))
    assert not some_spec.serves(InputSetup("residual", 2, (1, 2), signed=True))
    for bad in ((0, 1), (2, 1), (1, 4), (1, 1)):
        with pytest.raises(ConfigError, match="residual_offsets"):
            CacheSpec(sensor=TEST_SENSOR, n_residual=3, residual_offsets=bad)


def test_cache_matches_the_core_pipeline(data_root, tmp_path):
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=2, n_frames=1, with_points=True)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=2)
    scans = street_sequence(5, seed=0)
    i = 3
    pts, rem, moving, pose = scans[i]
    image = project(pts, rem, TEST_SENSOR)
    past = [(scans[j][0], scans[j][3]) for j in (2, 1)]
    expected = residual_images(image.range, pose, past, 2, TEST_SENSOR, spec.residual, signed=True)
    assert (expected < 0).any() and (expected > 0).any()  # the cache keeps the sign
    np.testing.assert_allclose(cache.residual[i].astype(np.float32), expected, rtol=2e-3, atol=2e-3)
    np.testing.assert_allclose(cache.frame[i, 0].astype(np.float32), image.range, rtol=1e-3)
    lab = cache.label[i]
    assert (lab[~image.mask] == IGNORE).all()
    np.testing.assert_array_equal(lab[image.mask], moving[image.point_index[image.mask]])
    assert (cache.residual[0] == 0).all()  # no past at the sequence start
    assert cache.points(i)["u"].shape == (len(pts),)
    # Opening again reuses the cache.
    assert SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec).directory == cache.directory


def test_cached_free_space_images_match_the_core(data_root, tmp_path):
    from ros2_mos.core.residuals import free_space_images

    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=3, n_frames=0, free_space_offsets=(1, 3))
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=2)
    scans = street_sequence(5, seed=0)
    i = 3
    pts, rem, _, pose = scans[i]
    image = project(pts, rem, TEST_SENSOR)
    past = [(project(scans[j][0], scans[j][1], TEST_SENSOR).range, scans[j][3]) for j in (2, 1, 0)]
    expected = free_space_images(image.xyz, image.mask, pose, past, (1, 3), TEST_SENSOR, spec.residual)
    assert (expected > 0.05).any()  # the moving box stands where past rays passed
    np.testing.assert_allclose(cache.free_space[i].astype(np.float32), expected, rtol=2e-3, atol=2e-3)
    assert (cache.free_space[0] == 0).all() and (cache.free_space[2, 1] == 0).all()  # no scan 3 back yet
    # The dataset appends them after the residuals at the setup's offsets.
    setup = InputSetup("residual", 2, (1, 3), signed=True, free_space=True)
    x, _ = MosDataset([cache], setup, [0.0] * 5, [1.0] * 5)[i]
    assert x.shape[0] == 5 + 2 + 2
    np.testing.assert_allclose(x[5:7].numpy(), np.asarray(cache.residual[i, [0, 2]], np.float32))
    np.testing.assert_allclose(x[7:].numpy(), np.asarray(cache.free_space[i], np.float32))
    # A cache without them does not serve such a setup; bad offsets are refused.
    assert not CacheSpec(sensor=TEST_SENSOR, n_residual=3).serves(setup) and spec.serves(setup)
    with pytest.raises(ConfigError, match="free_space_offsets"):
        CacheSpec(sensor=TEST_SENSOR, n_residual=3, free_space_offsets=(4,))


def test_free_space_inputs_are_residual_inputs_with_their_own_channels():
    setup = InputSetup("residual", 3, (1, 2, 4), signed=True, image_channels=("z",), free_space=True)
    assert (setup.past_channels, setup.channels) == (6, 7)
    assert setup.label == "signed residual N=3 at 1,2,4 + free space"
    assert setup.channel_names == ("z", "residual@1", "residual@2", "residual@4", "free_space@1", "free_space@2",
                                   "free_space@4")
    assert InputSetup("frames", 1).channel_names[5:7] == ("range@1", "x@1")
    for bad in (dict(kind="frames", n_past=1), dict(kind="residual", n_past=0)):
        with pytest.raises(ConfigError, match="free_space"):
            InputSetup(free_space=True, **bad)


def test_image_space_rotation_and_flip_match_point_space(data_root, tmp_path):
    """A column roll/reversal + x,y rotation/negation equals projecting rotated/flipped points."""
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=1, n_frames=0)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=1)
    setup = InputSetup("residual", 1)
    ds = MosDataset([cache], setup, [0.0] * 5, [1.0] * 5)
    current, extra, label = ds.components(2)
    w = TEST_SENSOR.width
    pts, rem = street_sequence(5, seed=0)[2][:2]
    k = 37
    theta = 2 * np.pi * k / w
    c, s = np.cos(theta), np.sin(theta)
    rot = pts @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32).T
    ref = project(rot, rem, TEST_SENSOR)

    cur2, _, _ = rotate_columns(current.copy(), extra.copy(), label.copy(), k, frames_kind=False)
    # Pixels that agree in occupancy (floor at pixel edges may move a few by one column).
    both = (cur2[0] > 0) & (ref.range > 0)
    assert both.mean() > 0.9 * (ref.range > 0).mean()
    close = np.abs(cur2[0][both] - ref.range[both]) < 0.05
    assert close.mean() > 0.97
    np.testing.assert_allclose(cur2[1][both][close], ref.xyz[..., 0][both][close], atol=0.15)
    np.testing.assert_allclose(cur2[2][both][close], ref.xyz[..., 1][both][close], atol=0.15)
    # flip y -> -y is a column reversal with y negated
    flipped = project(pts * np.array([1, -1, 1], np.float32), rem, TEST_SENSOR)
    cur3, _, _ = flip_y(current.copy(), extra.copy(), label.copy(), frames_kind=False)
    both = (cur3[0] > 0) & (flipped.range > 0)
    close = np.abs(cur3[0][both] - flipped.range[both]) < 0.05
    assert close.mean() > 0.95
    np.testing.assert_allclose(cur3[2][both][close], flipped.xyz[..., 1][both][close], atol=0.15)


def test_dataset_assembles_inputs_with_the_core(data_root, tmp_path):
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=3, n_frames=1)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=1)
    for setup in (InputSetup("residual", 0), InputSetup("residual", 3), InputSetup("frames", 1)):
        ds = MosDataset([cache], setup, [1.0] * 5, [2.0] * 5, AugmentConfig(crop_width=128, drop_max=0.2))
        x, y = ds[2]
        assert x.shape == (setup.channels, TEST_SENSOR.height, 128) and y.shape == (TEST_SENSOR.height, 128)
        assert x.dtype == torch.float32 and y.dtype == torch.int64
    ds = MosDataset([cache], InputSetup("residual", 2), [1.0] * 5, [2.0] * 5)
    x, _ = ds[2]
    current, extra, _ = ds.components(2)
    image = as_range_image(current)
    expected = (current - 1.0) / 2.0 * image.mask[None]
    np.testing.assert_allclose(x[:5].numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(x[5:].numpy(), np.abs(extra))  # an unsigned setup takes |signed residual|
    signed = InputSetup("residual", 2, (1, 3), signed=True, image_channels=("range", "z"))
    x, _ = MosDataset([cache], signed, [1.0] * 5, [2.0] * 5)[2]
    np.testing.assert_allclose(x[0].numpy(), expected[0], atol=1e-6)
    np.testing.assert_allclose(x[1].numpy(), expected[3], atol=1e-6)
    np.testing.assert_allclose(x[2:].numpy(), np.asarray(cache.residual[2, [0, 2]], np.float32))


def test_full_history_only_trains_on_the_scans_whose_every_past_scan_exists(data_root, tmp_path):
    """Scans 0..2 of a drive lack a scan 3 back: with full_history_only the training samples start at scan 3
    (every second one with train_stride 2); validation keeps every scan."""
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=3, n_frames=0)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=1)
    setup = InputSetup("residual", 2, (1, 3))
    assert [i for _, i in MosDataset([cache], setup, [0.0] * 5, [1.0] * 5).index] == list(range(len(cache)))
    later = MosDataset([cache], setup, [0.0] * 5, [1.0] * 5, stride=2, first_scan=setup.history)
    assert [i for _, i in later.index] == list(range(3, len(cache), 2))
    with pytest.raises(ConfigError, match="first_scan"):
        MosDataset([cache], setup, [0.0] * 5, [1.0] * 5, first_scan=-1)
    trainer = Trainer(_config(data_root, tmp_path, past_offsets=[1, 3], full_history_only=True), data_root,
                      show_progress=False)
    assert min(i for _, i in trainer.train_set.index) == 3 and min(i for _, i in trainer.valid_set.index) == 0


def test_augmented_sample_is_flip_then_rotation_then_crop(data_root, tmp_path):
    """The dataset's single column gather equals flip_y + rotate_columns + taking the first columns."""
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=2, n_frames=1)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=1)
    for setup in (InputSetup("residual", 2), InputSetup("frames", 1)):
        ds = MosDataset([cache], setup, [0.0] * 5, [1.0] * 5, AugmentConfig(True, 1.0, 0.0, 100))
        for seed in range(4):
            current, extra, label = ds._augmented(3, np.random.default_rng(seed))
            rng = np.random.default_rng(seed)
            assert rng.random() < 1.0
            k = int(rng.integers(TEST_SENSOR.width))
            frames = setup.kind == "frames"
            ref = flip_y(*ds.components(3), frames_kind=frames)
            ref = rotate_columns(*ref, k, frames_kind=frames)
            np.testing.assert_allclose(current, ref[0][..., :100], atol=1e-5)
            np.testing.assert_allclose(extra, ref[1][..., :100], atol=1e-5)
            np.testing.assert_array_equal(label, ref[2][..., :100])


def test_pose_noise_perturbs_by_the_given_sigmas():
    from ros2_mos.training.dataset import perturb_pose

    t = np.eye(4)
    t[:3, 3] = [1.0, 2.0, 3.0]
    assert perturb_pose(t, 0.0, 0.0, np.random.default_rng(0)) is t
    rng = np.random.default_rng(1)
    moves, angles = [], []
    for _ in range(400):
        out = perturb_pose(t, 0.02, 0.05, rng)
        np.testing.assert_allclose(out[:3, :3] @ out[:3, :3].T, np.eye(3), atol=1e-12)  # still a rotation
        moves.append(out[:3, 3] - out[:3, :3] @ t[:3, 3])  # the noise's own translation
        angles.append(np.degrees(np.arccos(np.clip((np.trace(out[:3, :3]) - 1) / 2, -1, 1))))
    assert 0.015 < np.std(np.asarray(moves)) < 0.025
    assert 0.02 < np.sqrt(np.mean(np.square(angles))) < 0.08
    with pytest.raises(ConfigError):
        CacheSpec(sensor=TEST_SENSOR, pose_noise=(float("nan"), 0.0))


def test_cache_is_rebuilt_when_labels_change(data_root, tmp_path):
    """Relabelling a sequence must not reuse the old labels (the key covers every input file)."""
    import os
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(data_root / "sequences" / "00", seq)
    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=1, n_frames=0)
    first = SequenceCache.build(seq, tmp_path / "cache", spec, workers=1)
    label_file = sorted((seq / "labels").glob("*.label"))[2]
    labels = np.fromfile(label_file, np.uint32)
    labels[:] = 251  # everything moving now
    labels.tofile(label_file)
    os.utime(label_file, ns=(1, 1))
    second = SequenceCache.build(seq, tmp_path / "cache", spec, workers=1)
    assert second.directory != first.directory
    lab = np.asarray(second.label[2])
    assert (lab[lab != IGNORE] == 1).all()


def test_class_weights_inverse_frequency_with_ignore():
    w = inverse_frequency_weights([997, 3], eps=1e-3)
    assert w[0] == pytest.approx(1 / (0.997 + 1e-3))
    assert w[1] == pytest.approx(250.0)
    w = inverse_frequency_weights([10, 990, 0], eps=1e-3, ignore=[0])
    assert w[0] == 0.0 and w[2] == pytest.approx(1000.0)


def test_lovasz_softmax_hand_cases():
    labels = torch.tensor([[[0, 1, 1, -1]]])
    perfect = torch.tensor([[[[1.0, 0.0, 0.0, 0.3]], [[0.0, 1.0, 1.0, 0.7]]]])
    assert float(lovasz_softmax(perfect, labels)) == pytest.approx(0.0, abs=1e-7)
    wrong = 1.0 - perfect
    assert float(lovasz_softmax(wrong, labels)) == pytest.approx(1.0)
    # Binary hard predictions: the Lovász extension equals 1 - IoU per class.
    # pred moving at pixels 1, 2 (gt moving at 1, 3): moving IoU 1/3, static IoU 0/2 (gt static at 0, 2).
    labels = torch.tensor([[[0, 1, 0, 1]]])
    hard = torch.tensor([[[[1.0, 0.0, 0.0, 1.0]], [[0.0, 1.0, 1.0, 0.0]]]])
    expected = ((1 - 1 / 3) + (1 - 1 / 3)) / 2
    assert float(lovasz_softmax(hard, labels)) == pytest.approx(expected)


def test_one_step_lowers_the_loss():
    from ros2_mos.training.nets import build_network

    torch.manual_seed(0)
    net = build_network("fastmos", 7)
    x = torch.randn(2, 7, 16, 64)
    y = (x[:, 5] > 0.5).long()
    y[:, 0] = -1
    loss_fn = MosLoss([1.0, 3.0])
    opt = torch.optim.SGD(net.parameters(), lr=0.05, momentum=0.0)
    net.train()
    before = loss_fn(net(x), y)[0].item()
    for _ in range(3):
        loss = loss_fn(net(x), y)[0]
        opt.zero_grad()
        loss.backward()
        opt.step()
    net.train()
    after = loss_fn(net(x), y)[0].item()
    assert after < before


def test_train_checkpoint_resume_and_export(data_root, tmp_path):
    cfg = _config(data_root, tmp_path, epochs=1, residual_max_range=40.0)
    trainer = Trainer(cfg, data_root, show_progress=False)
    history = trainer.fit()
    assert len(history) == 1 and math.isfinite(history[0].train_loss)
    run = tmp_path / "run"
    assert (run / "last.pt").is_file() and (run / "best.pt").is_file()
    lines = (run / "metrics.csv").read_text().splitlines()
    assert lines[0].startswith("epoch,train_loss") and len(lines) == 2
    state = load_checkpoint(run / "last.pt")
    assert state["epoch"] == 0 and state["class_weights"][1] > state["class_weights"][0]
    # Resume: a second trainer with more epochs starts at epoch 1 with the saved weights.
    cfg2 = _config(data_root, tmp_path, epochs=2, residual_max_range=40.0)
    resumed = Trainer(cfg2, data_root, show_progress=False)
    assert resumed.start_epoch == 1
    for k, v in resumed.model.state_dict().items():
        assert torch.equal(v, state["model"][k])
    resumed.fit()
    assert len((run / "metrics.csv").read_text().splitlines()) == 3
    report = export_checkpoint(run / "last.pt", tmp_path / "m.onnx")
    assert report.max_abs_diff < 1e-4
    from ros2_mos.training.export import read_metadata

    meta = read_metadata(tmp_path / "m.onnx")
    assert meta.network == "fastmos" and meta.input == InputSetup("residual", 2) and meta.sensor == TEST_SENSOR
    assert meta.means == tuple(state["means"]) or len(meta.means) == 5
    assert meta.residual_max_range == 40.0  # the pipeline computes residuals out to the window it was trained with


def test_connected_regions_hand_case():
    from ros2_mos.training.baselines import connected_regions

    valid = np.array([[1, 1, 0, 1], [0, 1, 0, 1], [0, 0, 0, 1]], bool)
    rng = np.array([[5.0, 5.1, 0, 9.0], [0, 5.2, 0, 9.1], [0, 0, 0, 20.0]], np.float32)
    lab = connected_regions(valid, rng, rel=0.05)
    assert lab[0, 0] == lab[0, 1] == lab[1, 1]
    assert lab[0, 3] == lab[1, 3] != lab[2, 3]  # 9.1 -> 20 m is a depth jump
    # wrap-around in azimuth: column 3 touches column 0 (5.0 vs 9.0 m: a jump, so separate)
    assert lab[0, 3] != lab[0, 0]
    assert (lab[~valid] == -1).all()


def test_baselines_find_the_moving_box(data_root, tmp_path):
    from ros2_mos.training.ablation import evaluate_point_iou
    from ros2_mos.training.baselines import ResidualRegionGrowing, ResidualThreshold

    spec = CacheSpec(sensor=TEST_SENSOR, n_residual=2, n_frames=0, with_points=True)
    cache = SequenceCache.build(data_root / "sequences" / "00", tmp_path, spec, workers=1)
    thr = evaluate_point_iou([cache], lambda c, i: ResidualThreshold(0.2).predict(c, i).astype(np.float32))
    rg = evaluate_point_iou([cache],
                            lambda c, i: ResidualRegionGrowing(0.1, 0.05, 0.1).predict(c, i).astype(np.float32))
    assert thr.tp > 0 and rg.tp > 0
    assert rg.iou > 0.2


def test_fine_tuning_starts_from_the_checkpoints_weights_and_normalisation(data_root, tmp_path):
    first = Trainer(_config(data_root, tmp_path / "a", epochs=1), data_root, show_progress=False)
    first.fit()
    base = load_checkpoint(tmp_path / "a" / "run" / "last.pt")
    cfg = _config(data_root, tmp_path / "b", epochs=1, lr=1e-3, train_sequences=["01"], valid_sequences=[],
                  init_from=str(tmp_path / "a" / "run" / "last.pt"))
    tuned = Trainer(cfg, data_root, show_progress=False)
    assert tuned.start_epoch == 0  # a new schedule, not a resume
    assert (tuned.means, tuned.stds) == (tuple(base["means"]), tuple(base["stds"]))  # not refitted on "01"
    for k, v in tuned.model.state_dict().items():
        assert torch.equal(v, base["model"][k])
    tuned.fit()
    assert load_checkpoint(tmp_path / "b" / "run" / "last.pt")["means"] == base["means"]
    # Once the run has its own last.pt, it resumes from that, not from init_from.
    again = Trainer(_config(data_root, tmp_path / "b", epochs=2, train_sequences=["01"], valid_sequences=[],
                            init_from=str(tmp_path / "a" / "run" / "last.pt")), data_root, show_progress=False)
    assert again.start_epoch == 1
    # Another network or input is refused; so is a file that is not a checkpoint.
    with pytest.raises(ConfigError, match="init_from"):
        Trainer(_config(data_root, tmp_path / "c", n_past=1, init_from=str(tmp_path / "a" / "run" / "last.pt")),
                data_root, show_progress=False)
    # The same input plus free-space images: the checkpoint's weights, zero weights for the new channels.
    wider = Trainer(_config(data_root, tmp_path / "e", free_space=True,
                            init_from=str(tmp_path / "a" / "run" / "last.pt")), data_root, show_progress=False)
    x = torch.randn(1, 5 + 2, TEST_SENSOR.height, 64)
    first.model.eval()
    wider.model.eval()
    with torch.no_grad():  # whatever the new channels hold, the output is the old network's
        torch.testing.assert_close(wider.model(torch.cat([x, torch.randn(1, 2, TEST_SENSOR.height, 64)], 1)),
                                   first.model(x))
    widened = 0
    for k, v in wider.model.state_dict().items():
        old = base["model"][k]
        if v.shape != old.shape:
            widened += 1
            assert torch.equal(v[:, : old.shape[1]], old) and (v[:, old.shape[1]:] == 0).all()
        else:
            assert torch.equal(v, old)
    assert widened >= 1
    # And one more offset (1, 2 -> 1, 2, 3, with free space), cached at the used offsets only: the old weights
    # move to their channels (z.. r1 r2 [r3] f1 f2 [f3]), and the output is still the old network's.
    wider.fit()
    longer = Trainer(_config(data_root, tmp_path / "f", free_space=True, n_past=3, past_offsets=[1, 2, 3],
                             cache_used_offsets_only=True, init_from=str(tmp_path / "e" / "run" / "last.pt")),
                     data_root, show_progress=False)
    assert longer.train_caches[0].spec.stored_offsets == (1, 2, 3)
    x = torch.randn(1, 5 + 6, TEST_SENSOR.height, 64)
    old_channels = [0, 1, 2, 3, 4, 5, 6, 8, 9]
    wider.model.eval()
    longer.model.eval()
    with torch.no_grad():
        torch.testing.assert_close(longer.model(x), wider.model(x[:, old_channels]))
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes((tmp_path / "a" / "run" / "last.pt").read_bytes()[:5000])
    with pytest.raises(ConfigError, match="not a readable checkpoint"):
        Trainer(_config(data_root, tmp_path / "d", init_from=str(truncated)), data_root, show_progress=False)


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[1] / "configs").rglob("*.yaml")),
                         ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_training_config_loads(path):
    """The shipped models' recipes in configs/ and the experiments in configs/experiments/."""
    config = TrainConfig.from_yaml(path)
    assert config.setup.channels > 0 and config.train_sequences


def test_training_config_refuses_nonsense_values(data_root, tmp_path):
    for bad in ({"lovasz_weight": -1.0}, {"drop_max": 2.0}, {"lr": float("nan")}, {"weight_decay": float("inf")},
                {"flip_y": 1.5}, {"max_minutes": 0.0}, {"residual_min_range": 60.0}, {"pose_noise": [0.1]},
                {"past_offsets": [2, 1], "n_past": 2}, {"image_channels": ["range", "speed"]},
                {"full_history_only": "yes"}, {"sim_narrow_streets": "bn00"}, {"sim_narrow_streets": [1]},
                {"sim_parked_vans": "bw00"}, {"sim_parked_vans": [None]}):
        with pytest.raises(ConfigError):
            _config(data_root, tmp_path, **bad)
