"""Simulated training drives are written once and kept only where this simulator wrote them with the settings asked
for (their ``simulator.txt``): ``ros2-mos adapt``'s simulated drives and ``tools/train_models.py``'s training data."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from ros2_mos.core.config import sensor_preset
from ros2_mos.io.semantic_kitti import read_scan
from ros2_mos.sim.writer import SIMULATOR_FILE

REPO = Path(__file__).resolve().parent.parent


def _stamps(folder: Path) -> tuple[str, int]:
    return (folder / SIMULATOR_FILE).read_text(), (folder / "velodyne" / "000000.bin").stat().st_mtime_ns


def test_adapt_simulates_a_drive_anew_where_another_seed_length_or_an_unfinished_run_wrote_it(tmp_path):
    pytest.importorskip("torch")
    from ros2_mos.training.adapt import AdaptConfig, prepare_simulated
    from ros2_mos.training.trainer import TrainConfig

    recipe = TrainConfig.from_dict(dict(train_sequences=["a"], valid_sequences=["v"]))
    sensor = sensor_preset("vlp16")
    folder = tmp_path / "data" / "sequences" / "sim00"

    def prepare(**settings) -> None:
        config = AdaptConfig(**{"sim_drives": 1, "sim_holdout": 0, "sim_scans": 3, **settings})
        assert prepare_simulated(sensor, tmp_path, config, recipe, lambda stage, n: None) == (["sim00"], [])

    prepare()
    first = _stamps(folder)
    prepare()  # the same settings: kept as it is
    assert _stamps(folder) == first
    prepare(sim_seed=701)  # another seed: another drive
    second = _stamps(folder)
    assert second[0] != first[0] and second[1] != first[1]
    prepare(sim_scans=4)  # another length: its stamp and its scans
    assert len(list((folder / "velodyne").glob("*.bin"))) == 4
    (folder / SIMULATOR_FILE).unlink()  # cut short before its stamp was written
    (folder / "velodyne" / "000003.bin").unlink()
    prepare(sim_scans=4)
    assert (folder / SIMULATOR_FILE).is_file() and len(list((folder / "velodyne").glob("*.bin"))) == 4


def test_train_models_simulates_anew_what_another_seed_wrote_and_keeps_what_it_wrote(tmp_path):
    config = tmp_path / "recipe.yaml"
    config.write_text(yaml.safe_dump(dict(sensor="vlp16", train_sequences=["e0"], valid_sequences=["b0"])))

    def simulate(seed: int) -> str:
        run = subprocess.run([sys.executable, str(REPO / "tools" / "train_models.py"), "--config", str(config),
                              "--data", str(tmp_path / "data"), "--scans", "2", "--seed", str(seed), "--jobs", "1",
                              "--simulate-only"], capture_output=True, text=True, timeout=300, cwd=REPO)
        assert run.returncode == 0, run.stderr
        return run.stdout

    folders = [tmp_path / "data" / "sequences" / name for name in ("e0", "b0")]
    assert "simulated 2 of 2" in simulate(100)
    first = [_stamps(f) for f in folders]
    scan = read_scan(folders[0] / "velodyne" / "000001.bin")
    assert "simulated 0 of 2" in simulate(100) and [_stamps(f) for f in folders] == first
    out = simulate(101)
    assert "simulated 2 of 2" in out and "simulating anew" in out and ("e0 b0" in out or "b0 e0" in out)
    assert all(_stamps(f)[0] != s[0] for f, s in zip(folders, first))
    assert not np.array_equal(read_scan(folders[0] / "velodyne" / "000001.bin"), scan)
