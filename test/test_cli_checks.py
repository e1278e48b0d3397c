"""Command-line values refused before any work (issue 32.8)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from ros2_mos.cli import app


@pytest.mark.parametrize(("option", "value"), [("--rate", "nan"), ("--rate", "-1"), ("--rate", "inf"),
                                               ("--wait", "nan"), ("--sync-timeout", "nan")])
def test_replay_refuses_a_non_finite_or_negative_value(tmp_path, option, value):
    """`--rate nan` passed the check that refused -1 (NaN fails every comparison)."""
    result = CliRunner().invoke(app, ["replay", str(tmp_path / "no-bag"), option, value])
    assert result.exit_code == 1, result.output
    assert f"error: {option} must be a finite number >= 0, got {float(value)}" in result.output
