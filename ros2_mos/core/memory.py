"""Keeping freed heap memory inside the process, so that per-scan arrays stop page-faulting.

Every scan allocates a few dozen arrays of 0.5 MB (one float per point or per pixel) and frees them again. glibc
serves blocks that large with fresh ``mmap`` calls (its threshold starts at 128 kB) and gives the memory back on
``free``, or trims it off the top of the heap, so the next scan faults every page in again (its cost:
benchmarks/design_figures.md). Raising the mmap and trim thresholds keeps those pages mapped and reused; the
resident size then stays at its peak instead of breathing. It is a process-wide setting, hence a switch
(``tune_malloc``) on the pipeline's configuration.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

# mallopt parameters from <malloc.h>.
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: glibc's ceiling for M_MMAP_THRESHOLD on 64-bit (HEAP_MAX_SIZE / 2): larger values are refused.
MMAP_THRESHOLD = 32 * 1024 * 1024
TRIM_THRESHOLD = 512 * 1024 * 1024

_applied = False


def retain_freed_memory() -> bool:
    """Ask glibc to keep freed blocks below 32 MB for reuse; False where that is not possible.

    Not glibc (macOS, musl, Windows): nothing is changed and False is returned.
    """
    global _applied
    if _applied:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _applied
