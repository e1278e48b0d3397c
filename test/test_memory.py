"""The glibc heap setting the pipeline applies (process-wide, so it must be safe to repeat)."""

import platform
import sys

import pytest

from ros2_mos.core import memory


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_retain_freed_memory_applies_on_glibc_and_is_idempotent():
    assert memory.retain_freed_memory() is True
    assert memory.retain_freed_memory() is True


def test_retain_freed_memory_is_a_no_op_off_linux(monkeypatch):
    monkeypatch.setattr(memory, "_applied", False)
    monkeypatch.setattr(memory.sys, "platform", "darwin")
    assert memory.retain_freed_memory() is False
