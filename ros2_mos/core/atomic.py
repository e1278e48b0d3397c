"""Outputs written whole or not at all: to a temporary name beside the target, renamed when complete.

A full disk, a quota or a vanished folder is one :class:`~ros2_mos.core.errors.OutputError` line naming the
file and the reason, and leaves neither a truncated file nor the temporary one behind. Every command that
writes files goes through here (bags have their own partial folder: ``process``).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from ros2_mos.core.errors import OutputError


def output_error(path: str | Path, exc: OSError) -> OutputError:
    """The one-line error for an OSError while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    error = OutputError(f"cannot write {path}: {reason}")
    error.path, error.reason = Path(path), reason
    return error


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block completes, removed when
    it raises (with the folders made for it, where still empty). An OSError (in the block, or creating the folder,
    or renaming) becomes an :class:`OutputError`."""
    path = Path(path)
    with folder_kept_on_success(path.parent, named=path):
        try:
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
            os.close(fd)
        except OSError as exc:
            raise output_error(path, exc) from None
        tmp = Path(name)
        try:
            try:
                yield tmp
                os.chmod(tmp, 0o644)  # mkstemp makes 0600 files; outputs are meant to be read by others
                tmp.replace(path)
            except OSError as exc:
                raise output_error(path, exc) from None
        finally:
            tmp.unlink(missing_ok=True)


@contextmanager
def folder_kept_on_success(folder: str | Path, named: str | Path | None = None) -> Iterator[Path]:
    """``folder``, made with its missing parents; where the block raises, the folders it made are removed again
    (those still empty), so that a failed command leaves no empty ``OUT/sequences/`` behind. An error making it
    names ``named`` (the file to be written there), else the folder."""
    folder = Path(folder)
    made: list[Path] = []
    p = folder
    while not p.exists() and p != p.parent:
        made.append(p)  # deepest first
        p = p.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(folder if named is None else named, exc) from None
    try:
        yield folder
    except BaseException:
        for p in made:
            try:
                p.rmdir()
            except OSError:  # not empty (or gone): keep it and what is above it
                break
        raise


@contextmanager
def atomic_open(path: str | Path, mode: str = "wb", **kwargs: Any) -> Iterator[IO[Any]]:
    """``open(path, mode)`` for writing, atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as f:
        yield f


def write_bytes_atomically(path: str | Path, data: bytes | memoryview) -> None:
    with atomic_open(path, "wb") as f:
        f.write(data)


def write_text_atomically(path: str | Path, text: str) -> None:
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write(text)


__all__ = ["atomic_open", "atomic_path", "output_error", "write_bytes_atomically", "write_text_atomically"]
