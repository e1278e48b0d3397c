"""The two meanings of "moving" a label folder can carry, and where a sequence keeps each.

- ``semantickitti``: an object that moves at any time while it is observed is moving in *every* scan in which it is
  seen, also while it waits at a light (the SemanticKITTI maintainers' rule, semantic-kitti-api issue #80; the MOS
  benchmark and every published MOS model use it).
- ``instant``: moving in a scan when it moved since the previous scan (what a motion-only online segmenter can see).

A sequence folder keeps its main labels in ``labels/`` and, where it has them, the other convention's in
``labels_<convention>/``; ``label_convention.txt`` names the convention of ``labels/``. A folder without that file
(real SemanticKITTI data) holds SemanticKITTI's convention.
"""

from __future__ import annotations

from pathlib import Path

from ros2_mos.core.errors import ConfigError, DatasetError

SEMANTICKITTI = "semantickitti"
INSTANT = "instant"
CONVENTIONS = (SEMANTICKITTI, INSTANT)
#: What ``simulate`` and ``autolabel`` write to ``labels/`` unless told otherwise: the convention of SemanticKITTI,
#: of its benchmark and of every published model, so that simulated figures compare with theirs.
DEFAULT_CONVENTION = SEMANTICKITTI
CONVENTION_FILE = "label_convention.txt"


def check_convention(name: str) -> str:
    """``name`` if it is a known convention, else a ConfigError naming the known ones."""
    if name not in CONVENTIONS:
        raise ConfigError(f"unknown label convention {name!r}: use one of {', '.join(CONVENTIONS)}")
    return name


def other_convention(name: str) -> str:
    return INSTANT if check_convention(name) == SEMANTICKITTI else SEMANTICKITTI


def main_convention(sequence_root: str | Path) -> str:
    """The convention of a sequence's ``labels/`` (SemanticKITTI's where the folder does not say)."""
    path = Path(sequence_root) / CONVENTION_FILE
    if not path.is_file():
        return SEMANTICKITTI
    name = path.read_text().strip()
    if name not in CONVENTIONS:
        raise DatasetError(f"{path}: unknown label convention {name!r} (known: {', '.join(CONVENTIONS)})")
    return name


def label_dirs(sequence_root: str | Path) -> dict[str, Path]:
    """Every convention a sequence has labels in, main convention first: {convention: folder of .label files}."""
    root = Path(sequence_root)
    main = main_convention(root)
    found = {main: root / "labels"} if (root / "labels").is_dir() else {}
    for name in CONVENTIONS:
        folder = root / f"labels_{name}"
        if name not in found and folder.is_dir():
            found[name] = folder
    return found


def write_convention_file(sequence_root: str | Path, convention: str) -> None:
    Path(sequence_root).mkdir(parents=True, exist_ok=True)
    (Path(sequence_root) / CONVENTION_FILE).write_text(check_convention(convention) + "\n")
