"""``ros2-mos adapt`` end to end on tiny drives whose sensor differs from the base model's training data in a known
way (noisier upper beams), and its refusals."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from drive_scenes import SENSOR, Mover, write_drive  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from ros2_mos.cli import app  # noqa: E402
from ros2_mos.core.config import MosConfig  # noqa: E402
from ros2_mos.core.errors import ConfigError, DatasetError, ModelError  # noqa: E402
from ros2_mos.core.pipeline import MosPipeline  # noqa: E402
from ros2_mos.io.labels import to_moving_classes  # noqa: E402
from ros2_mos.io.semantic_kitti import SemanticKittiSequence  # noqa: E402
from ros2_mos.offline.drives import FolderDrive  # noqa: E402
from ros2_mos.training.adapt import (  # noqa: E402
    AdaptConfig,
    adapt,
    plan_adaptation,
    recipe_share_drives,
)
from ros2_mos.training.trainer import TrainConfig, Trainer, export_checkpoint  # noqa: E402

runner = CliRunner()
WALLS = [(-40, 80, 9, 10), (-40, 80, -10, -9), (30, 31, -9, 9)]


def _drive(root: Path, name: str, seed: int, noise: float = 0.0, n: int = 30) -> Path:
    rng = np.random.default_rng(seed)
    y, v = float(rng.uniform(3, 6)), float(rng.uniform(0.4, 0.8))
    car = Mover((4.5, 1.8, 1.5), lambda k: (2.0 + v * k, y), 3)
    person = Mover((0.5, 0.5, 1.7), lambda k: (14.0 - 0.14 * k, -6.0), 4)
    return write_drive(root, n, lambda k: 0.0, [car, person], WALLS, name=name, upper_noise=noise)


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path]:
    """(repo root with configs/ and checkpoints/, base ONNX): a small network trained on clean drives."""
    root = tmp_path_factory.mktemp("repo")
    data = root / "data"
    for i in range(3):
        _drive(data, f"c{i}", i)
    _drive(data, "cv", 9)
    recipe = dict(network="fastmos", n_past=2, sensor=SENSOR.to_dict(), train_sequences=["c0", "c1", "c2"],
                  valid_sequences=["cv"], cache_dir=str(root / "cache"), out_dir=str(root / "run"), epochs=4,
                  batch_size=4, lr=0.003, optimizer="adamw", cache_workers=1, cache_n_residual=2, cache_n_frames=1,
                  warmup_epochs=0.0, drop_max=0.0, crop_width=360, threads=2)
    (root / "configs").mkdir()
    import yaml

    (root / "configs" / "tiny.yaml").write_text(yaml.safe_dump(recipe))
    Trainer(TrainConfig.from_dict(recipe), data, show_progress=False).fit()
    (root / "checkpoints").mkdir()
    shutil.copy(root / "run" / "best.pt", root / "checkpoints" / "tiny_best.pt")
    model = root / "base.onnx"
    export_checkpoint(root / "checkpoints" / "tiny_best.pt", model, extra={"training_config": "configs/tiny.yaml"})
    return root, model


def _false_positives(model: Path, folder: Path) -> tuple[int, int, int]:
    """(static points labelled moving among the upper beams, where write_drive's noise is; among the others; moving
    points found) over a drive."""
    pipe = MosPipeline(MosConfig(model=str(model)))
    fp_upper = fp_lower = tp = 0
    for frame in SemanticKittiSequence(folder):
        labels = pipe.process(frame.points, frame.remission, frame.timestamp, pose=frame.pose).labels
        gt = to_moving_classes(frame.labels)
        upper = frame.points[:, 2] > np.linalg.norm(frame.points, axis=1) * np.sin(np.radians(-5.0))
        fp_upper += int((labels & (gt == 0) & upper).sum())
        fp_lower += int((labels & (gt == 0) & ~upper).sum())
        tp += int((labels & (gt == 1)).sum())
    pipe.close()
    return fp_upper, fp_lower, tp


def test_adapting_to_noisier_upper_beams_cuts_the_false_positives_there(base, tmp_path):
    root, model = base
    drives = [FolderDrive(_drive(tmp_path / "real", f"n{i}", 20 + i, noise=0.15, n=40)) for i in range(2)]
    plan = plan_adaptation(drives, model, SENSOR, AdaptConfig(epochs=3, sim_drives=0, holdout=0.25, batch_size=4,
                                                              crop_width=360, lr=0.003, sim_holdout=0), root=root)
    assert [d.train for d in plan.drives] == [30, 30] and "n0: 40 scans" in plan.describe()
    assert "warning: only 80 real scans" in plan.describe()  # under RECOMMENDED_REAL_SCANS
    out = tmp_path / "adapted.onnx"
    result = adapt(drives, out, plan, tmp_path / "work", show_progress=False)
    assert out.is_file() and not out.with_name(out.name + ".partial").exists()
    assert 0.05 <= result.threshold <= 0.95
    test_drive = _drive(tmp_path / "test", "t", 40, noise=0.15, n=30)
    upper_base, lower_base, tp_base = _false_positives(model, test_drive)
    upper_adapted, lower_adapted, tp_adapted = _false_positives(out, test_drive)
    assert upper_base > 100, (upper_base, tp_base)  # the noise does fool the base model
    counts = (upper_base, lower_base, upper_adapted, lower_adapted, tp_base, tp_adapted)
    assert upper_adapted + lower_adapted < 0.5 * (upper_base + lower_base), counts
    # Fewer where the noise is; not many more elsewhere (what autolabel labels moving, the adapted model learns)
    assert upper_adapted < upper_base and lower_adapted < 1.5 * lower_base, counts
    assert tp_adapted > 0.5 * tp_base
    from ros2_mos.core.metadata import read_training_config
    from ros2_mos.training.export import read_metadata

    assert read_training_config(out) == "configs/tiny.yaml"
    assert "n0" in read_metadata(out).extra["adaptation"]
    # resumes: a second run finds the labels, data and checkpoints and trains no further epoch
    again = adapt(drives, tmp_path / "again.onnx", plan, tmp_path / "work", show_progress=False)
    assert again.minutes < result.minutes
    # ... but not from labels of another drive of the same name (or made by other rules)
    other = [FolderDrive(_drive(tmp_path / "other", "n0", 30, noise=0.15, n=40)), drives[1]]
    with pytest.raises(DatasetError, match="n0 were made from another drive"):
        adapt(other, tmp_path / "other.onnx", plan, tmp_path / "work", show_progress=False)
    assert not (tmp_path / "other.onnx").exists()
    deskewed = plan_adaptation(drives, model, SENSOR, dataclasses.replace(plan.config, deskew="on"), root=root)
    with pytest.raises(DatasetError, match="by other autolabel rules"):  # labels made without deskewing
        adapt(drives, tmp_path / "deskewed.onnx", deskewed, tmp_path / "work", show_progress=False)


def test_adapt_refuses_too_few_scans_another_sensor_s_base_and_mixed_sensors(base, tmp_path):
    root, model = base
    few = [FolderDrive(_drive(tmp_path, "few", 1, n=10))]
    with pytest.raises(DatasetError, match="at least"):
        plan_adaptation(few, model, SENSOR, AdaptConfig(), root=root)
    from ros2_mos.core.config import sensor_preset

    with pytest.raises(ModelError, match="is for the"):
        plan_adaptation(few, model, sensor_preset("vlp16"), AdaptConfig(), root=root)
    result = runner.invoke(app, ["adapt", str(tmp_path / "sequences" / "few"), "--out", str(tmp_path / "x.onnx"),
                                 "--sensor", "vlp16", "--dry-run"])
    assert result.exit_code != 0 and "at least" in str(result.exception) + result.output
    result = runner.invoke(app, ["adapt", str(tmp_path / "sequences" / "few"), "--out", str(tmp_path / "x.txt")])
    assert result.exit_code != 0 and "must end in .onnx" in result.output
    result = runner.invoke(app, ["adapt", str(tmp_path / "sequences" / "few"), "--out", str(tmp_path / "x.onnx"),
                                 "--holdout", "nan"])
    assert result.exit_code != 0 and "--holdout" in result.output
    result = runner.invoke(app, ["adapt", str(tmp_path / "sequences" / "few"), "--out", str(tmp_path / "x.onnx"),
                                 "--deskew", "yes"])
    assert result.exit_code != 0 and "unknown --deskew 'yes'" in result.output
    with pytest.raises(ConfigError, match="deskew"):
        AdaptConfig(deskew="sometimes")


def test_simulated_drives_lie_on_narrow_streets_in_the_share_the_base_recipe_trained_on():
    def recipe(train, narrow):
        return TrainConfig.from_dict(dict(train_sequences=train, valid_sequences=["v"], sim_narrow_streets=narrow))

    def narrow(config, count):
        return recipe_share_drives(config, config.sim_narrow_streets, count)

    # None narrow: none; 3 of 7 trained on (0.43; "v" and "x" are not trained on): drives 2 and 4 of 6 (floor of
    # 1.29 and 2.14 step up); half: every other drive, the second first; all: all.
    assert narrow(recipe(["a", "b"], []), 4) == [False] * 4
    seven = ["a", "b", "c", "d", "e", "f", "g"]
    assert narrow(recipe(seven, ["a", "b", "c", "v", "x"]), 6) == [False, False, True, False, True,
                                                                                  False]
    assert narrow(recipe(["a", "b"], ["b"]), 4) == [False, True, False, True]
    assert narrow(recipe(["a", "b"], ["a", "b"]), 3) == [True, True, True]
    # Parked vans: the same rule over sim_parked_vans (1 of 4 trained on: every fourth drive).
    vans = TrainConfig.from_dict(dict(train_sequences=["a", "b", "c", "d"], valid_sequences=["v"],
                                      sim_parked_vans=["c", "v"]))
    assert recipe_share_drives(vans, vans.sim_parked_vans, 8) == [False, False, False, True] * 2
