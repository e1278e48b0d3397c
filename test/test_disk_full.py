"""A full disk while a command writes: one line, an exit code, and no partial output (issue 32.5).

The disk is filled by a stand-in for ``open``: files written under the output folder take ``budget`` bytes, then
the write fails with ENOSPC after writing what fitted, as the kernel does.
"""

from __future__ import annotations

import builtins
import errno
import os
from pathlib import Path

import numpy as np
import pytest
from scenes import street_sequence, write_sequence
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.core.errors import OutputError

REPO = Path(__file__).resolve().parents[1]
STAMP0, PERIOD = 1_700_000_000_000_000_000, 100_000_000


class _FullFile:
    """A file whose writes fail with ENOSPC once ``disk["budget"]`` bytes are spent, after a partial write."""

    def __init__(self, f, disk: dict) -> None:
        self._f, self._disk = f, disk

    def write(self, data):
        size = len(memoryview(data).cast("B")) if not isinstance(data, str) else len(data)
        if size > self._disk["budget"]:
            self._f.write(data[: self._disk["budget"]] if isinstance(data, (str, bytes)) else bytes(data)[:1])
            self._disk["budget"] = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._disk["budget"] -= size
        return self._f.write(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()

    def __getattr__(self, name):
        return getattr(self._f, name)


@pytest.fixture
def full_disk(monkeypatch):
    """``full_disk(folder, budget)``: from now on, files opened for writing under ``folder`` fill up."""
    real_open = builtins.open

    def install(folder: Path, budget: int) -> None:
        disk = {"budget": budget}

        def fake_open(file, mode="r", *args, **kwargs):
            f = real_open(file, mode, *args, **kwargs)
            if any(c in mode for c in "wax") and isinstance(file, (str, os.PathLike)) \
                    and Path(file).resolve().is_relative_to(folder.resolve()):
                return _FullFile(f, disk)
            return f

        monkeypatch.setattr(builtins, "open", fake_open)

    return install


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_write_label_leaves_no_partial_file(tmp_path, full_disk):
    from ros2_mos.io.semantic_kitti import write_label

    write_label(tmp_path / "old.label", np.arange(4))
    full_disk(tmp_path, budget=1000)
    with pytest.raises(OutputError, match=r"^cannot write .*a\.label: No space left on device$"):
        write_label(tmp_path / "a.label", np.zeros(30921, np.uint32))  # the 123684 bytes
    with pytest.raises(OutputError, match="No space left"):
        write_label(tmp_path / "old.label", np.zeros(1000, np.uint32))
    assert _files(tmp_path) == ["old.label"]
    assert np.fromfile(tmp_path / "old.label", np.uint32).tolist() == [0, 1, 2, 3]  # the old file kept whole


def test_infer_on_a_full_disk_is_one_error_and_no_truncated_label(tmp_path, tiny_model_path, full_disk):
    """The issue: `OSError: 123684 requested and 29696 written` and a truncated label file left behind."""
    write_sequence(tmp_path / "data", "00", n_scans=4)
    out = tmp_path / "out"
    full_disk(out, budget=2 * 4 * len(street_sequence(1)[0][0]) + 100)  # two label files fit, the third does not
    result = CliRunner().invoke(app, ["infer", str(tmp_path / "data" / "sequences" / "00"), "--out", str(out),
                                      "--model", str(tiny_model_path)])
    assert result.exit_code == 1 and isinstance(result.exception, OutputError), result.output
    assert "No space left on device" in str(result.exception) and "\n" not in str(result.exception)
    written = _files(out)
    assert written[:1] == ["sequences/00/predictions/000000.label"] and len(written) < 4, written
    for name in written:  # each one whole, no temporary file beside them
        scan = tmp_path / "data" / "sequences" / "00" / "velodyne" / Path(name).with_suffix(".bin").name
        assert (out / name).stat().st_size == scan.stat().st_size // 4, name


def test_process_on_a_full_disk_is_one_line_and_no_bag(tmp_path, tiny_model_path, monkeypatch):
    """The issue: two chained tracebacks ending in ENOSPC."""
    from rosbags.rosbag2 import Writer

    from ros2_mos.io.bags import write_scans_bag

    seq = street_sequence(3)
    write_scans_bag(tmp_path / "in", iter([(STAMP0 + i * PERIOD, p, r) for i, (p, r, _, _) in enumerate(seq)]))
    calls = {"n": 0}
    real_write, real_close = Writer.write, Writer.close

    def write(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 5:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(self, *args, **kwargs)

    def close(self):  # the close after it fails as well on a full disk
        real_close(self)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Writer, "write", write)
    monkeypatch.setattr(Writer, "close", close)
    result = CliRunner().invoke(app, ["process", str(tmp_path / "in"), str(tmp_path / "out"),
                                      "--model", str(tiny_model_path)])
    assert result.exit_code == 1, result.output
    assert f"error: cannot write {tmp_path / 'out'}: No space left on device; the partial output was removed" \
        in result.output
    assert "Traceback" not in result.output and sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_export_on_a_full_disk_is_one_error_and_no_model(tmp_path, full_disk):
    pytest.importorskip("torch")
    full_disk(tmp_path, budget=10_000)
    result = CliRunner().invoke(app, ["export", str(REPO / "checkpoints/fastmos_beams_free16_best.pt"),
                                      "--out", str(tmp_path / "m.onnx")])
    assert result.exit_code == 1 and isinstance(result.exception, OutputError), result.output
    assert str(result.exception) == f"cannot write {tmp_path / 'm.onnx'}: No space left on device"
    assert _files(tmp_path) == []


def test_map_and_tables_on_a_full_disk_leave_nothing(tmp_path, full_disk):
    from ros2_mos.apps.mapping import write_map
    from ros2_mos.core.atomic import write_text_atomically

    full_disk(tmp_path, budget=100)
    points = np.random.default_rng(0).uniform(-10, 10, (1000, 3))
    for path in (tmp_path / "m.pcd", tmp_path / "m.ply"):
        with pytest.raises(OutputError, match="No space left on device"):
            write_map(path, points)
    with pytest.raises(OutputError, match="No space left on device"):
        write_text_atomically(tmp_path / "table.md", "x" * 1000)
    assert _files(tmp_path) == []
    # into folders made for it: they go too (a folder that was there stays)
    with pytest.raises(OutputError, match=r"cannot write .*maps/new/m\.ply: No space left on device"):
        write_map(tmp_path / "maps" / "new" / "m.ply", points)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_the_console_script_prints_one_line(tmp_path, tiny_model_path, full_disk, monkeypatch, capsys):
    """What the user sees: `error: ...` on stderr, exit code 1, no traceback; also for an OSError no library
    code wrapped."""
    import sys

    from ros2_mos.cli import main

    write_sequence(tmp_path / "data", "00", n_scans=2)
    full_disk(tmp_path / "out", budget=0)
    monkeypatch.setattr(sys, "argv", ["ros2-mos", "infer", str(tmp_path / "data" / "sequences" / "00"), "--out",
                                      str(tmp_path / "out"), "--model", str(tiny_model_path)])
    with pytest.raises(SystemExit) as info:
        main()
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line.lower()]  # beside tqdm's progress bar
    assert info.value.code == 1 and "Traceback" not in err and len(errors) == 1, err
    assert errors[0].startswith("error: cannot write ") and errors[0].endswith("000000.label: No space left on device")

    def unwrapped(*_args, **_kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "x"))

    monkeypatch.setattr("ros2_mos.ros.params.params_file_text", unwrapped)
    monkeypatch.setattr(sys, "argv", ["ros2-mos", "params"])
    with pytest.raises(SystemExit) as info:
        main()
    err = capsys.readouterr().err
    assert info.value.code == 1 and err == f"error: {tmp_path / 'x'}: No space left on device\n"


def test_a_failed_block_removes_the_folders_it_made_and_keeps_the_rest(tmp_path):
    from ros2_mos.core.atomic import folder_kept_on_success

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "other.txt").write_text("a user's file")
    with pytest.raises(RuntimeError), folder_kept_on_success(tmp_path / "out" / "sequences" / "a") as folder:
        assert folder.is_dir()
        raise RuntimeError("stage failed")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["other.txt"]  # its own, made before: kept
    # a folder that something else filled meanwhile stays, and so does everything above it
    with pytest.raises(RuntimeError), folder_kept_on_success(tmp_path / "new" / "sequences") as folder:
        (folder / "kept.label").write_bytes(b"")
        raise RuntimeError("stage failed")
    assert (tmp_path / "new" / "sequences" / "kept.label").exists()
    with folder_kept_on_success(tmp_path / "ok" / "sequences") as folder:  # success: everything stays
        pass
    assert folder.is_dir()
    with pytest.raises(OutputError, match="cannot write"):  # a file where a folder must go: one line
        with folder_kept_on_success(tmp_path / "out" / "other.txt" / "sequences"):
            pass
