"""``sweep.txt``: whether a sequence folder's sweeps are skewed (each point measured from the pose of its firing
time) or compensated (every point in the frame of the scan's pose).

``ros2-mos simulate`` writes it (``skewed`` with ``--intra-sweep-motion``); ``autolabel --deskew auto`` deskews a
folder that says ``skewed`` and leaves the rest as they are. A folder without it (real data) says nothing; write
``skewed`` into it where a driver did not compensate the sweeps. autolabel writes one beside its labels too, saying
how it took the sweeps (``skewed``: it deskewed them), which ``ros2-mos map --labels`` follows.
"""

from __future__ import annotations

from pathlib import Path

from ros2_mos.core.errors import DatasetError

SWEEP_FILE = "sweep.txt"
SKEWED = "skewed"
COMPENSATED = "compensated"


def write_sweep_file(sequence_root: str | Path, skewed: bool) -> None:
    root = Path(sequence_root)
    root.mkdir(parents=True, exist_ok=True)
    (root / SWEEP_FILE).write_text((SKEWED if skewed else COMPENSATED) + "\n")


def read_sweep_file(sequence_root: str | Path) -> bool | None:
    """True where the folder says its sweeps are skewed, False where compensated, None where it does not say."""
    path = Path(sequence_root) / SWEEP_FILE
    if not path.is_file():
        return None
    word = path.read_text().strip()
    if word not in (SKEWED, COMPENSATED):
        raise DatasetError(f"{path}: {word!r} is neither {SKEWED!r} nor {COMPENSATED!r}")
    return word == SKEWED
