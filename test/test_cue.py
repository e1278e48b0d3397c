"""The online cue over a drive (``ros2_mos.offline.cue``): in this process and in one of its own, the same labels;
a refused scan counted; scans in order, labels asked for once."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.core.config import sensor_preset
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.inference import shipped_models
from ros2_mos.offline.cue import OnlineCue, OnlineCueProcess
from ros2_mos.offline.drives import FolderDrive


@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> list:
    root = tmp_path_factory.mktemp("cue")
    result = CliRunner().invoke(app, ["simulate", str(root), "--sequences", "00", "--scans", "6", "--preset",
                                      "easy", "--sensor", "vlp32c", "--seed", "3"])
    assert result.exit_code == 0, result.output
    drive = FolderDrive(root / "sequences" / "00")
    return [(scan, pose) for scan, pose in zip(drive, drive.poses)]


def test_the_cue_in_a_process_of_its_own_labels_as_the_one_here_and_counts_a_refused_scan(scans):
    model, sensor = shipped_models()["vlp32c"], sensor_preset("vlp32c")
    volume = np.random.default_rng(0).uniform(-20, 20, (30000, 3)).astype(np.float32)  # no scan of surfaces
    labels = {}
    for kind in (OnlineCue, OnlineCueProcess):
        cue = kind(model, sensor)
        try:
            for k, (scan, pose) in enumerate(scans):
                points = volume if k == 3 else scan.points
                cue.add(k, points, np.zeros(len(points), np.float32), scan.stamp, pose)
            labels[kind] = [cue.labels(k) for k in range(len(scans))]
            assert cue.skipped == 1 and labels[kind][3] is None
            with pytest.raises(ConfigError, match="asked for already"):
                cue.labels(0)
            with pytest.raises(ConfigError, match="out of order"):
                cue.add(9, scans[0][0].points, scans[0][0].intensity, 9.0, scans[0][1])
        finally:
            cue.close()
    for k, (scan, _) in enumerate(scans):
        if k != 3:
            here, there = labels[OnlineCue][k], labels[OnlineCueProcess][k]
            assert here.dtype == bool and len(here) == len(scan.points)
            np.testing.assert_array_equal(here, there)
    assert sum(int(m.sum()) for m in labels[OnlineCue] if m is not None) > 0  # the simulated movers
