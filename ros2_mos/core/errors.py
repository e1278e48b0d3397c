"""Typed errors of the core.

Library code raises these; only the CLI and the node's ``main()`` turn them into
messages and exit codes, so every caller can tell bad input from a bug.
"""


class MosError(Exception):
    """Base class of every error the ros2_mos core raises on purpose."""


class ScanError(MosError, ValueError):
    """A scan is malformed: wrong shape, empty, or without any finite point."""


def scan_refused(exc: ScanError, where: str) -> ScanError:
    """``exc`` for an offline run over a sequence, with the scan it is about (``where``: the sequence, the scan and
    its file): the run stops there, where a skipped scan would leave a hole that gives the next scans residuals
    against the wrong past scans (the node, which cannot stop, skips and counts such clouds)."""
    return ScanError(f"{where}: {exc}; fix or remove that scan and run again")


class ImplausibleScanError(ScanError):
    """A well-formed cloud that is no LiDAR scan (points scattered through a volume): refused before odometry."""


class ConfigError(MosError, ValueError):
    """A configuration value is invalid (unknown preset, negative range, N < 0, ...)."""


class ModelError(MosError):
    """A model file is missing, unreadable, or does not fit the configured setup."""


class WorkerError(MosError):
    """A process the library started ended without its result (killed, out of memory), or failed there."""


class DatasetError(MosError):
    """A dataset folder or file is missing or does not follow the expected format."""


class OutputError(MosError):
    """An output could not be written (disk full, no permission, ...); no partial file is left behind.

    ``path`` is the file that could not be written and ``reason`` the system's words for why, where known.
    """

    path: object = None
    reason: str = ""
