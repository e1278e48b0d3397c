"""The ament layout, tested: colcon builds the package and `ros2 run`'s lookup finds its executables."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COLCON = Path(sys.executable).parent / "colcon"


def _copy_package(dest: Path) -> None:
    """Copy the tracked files (what a clone has), not the venv or generated data."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for rel in files:
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


@pytest.mark.skipif(not COLCON.exists(), reason="colcon is installed by requirements.txt")
def test_colcon_build_installs_executables_where_ros2_run_looks(tmp_path):
    pkg = tmp_path / "ws" / "src" / "ros2_mos"
    _copy_package(pkg)
    ws = tmp_path / "ws"
    proc = subprocess.run([str(COLCON), "build"], cwd=ws, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    prefix = ws / "install" / "ros2_mos"
    lib = prefix / "lib" / "ros2_mos"
    assert (lib / "mos_node").is_file(), sorted(p.name for p in lib.iterdir()) if lib.exists() else "no lib/ros2_mos"
    assert (lib / "ros2-mos").is_file()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "ros2_mos").is_file()
    assert (prefix / "share" / "ros2_mos" / "package.xml").is_file()
    assert (prefix / "share" / "ros2_mos" / "config" / "mos.yaml").is_file()
    assert (prefix / "share" / "ros2_mos" / "config" / "fastdds_large_messages.xml").is_file()
    assert (prefix / "share" / "ros2_mos" / "launch" / "mos.launch.py").is_file()
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix))
    lookup = subprocess.run(
        [sys.executable, "-c", "from ament_index_python.packages import get_package_prefix as g; print(g('ros2_mos'))"],
        env=env, capture_output=True, text=True, timeout=60,
    )
    assert lookup.returncode == 0, lookup.stderr
    assert Path(lookup.stdout.strip()) == prefix
