"""SemanticKITTI label ids and the MOS benchmark's binary mapping.

The benchmark ignores 0 (unlabeled) and 1 (outlier), calls every id in 251..259
moving and every other id static; submissions write 9 (static) and 251 (moving).
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.errors import DatasetError

IGNORE = -1
STATIC = 0
MOVING = 1

SUBMISSION_STATIC_ID = 9
SUBMISSION_MOVING_ID = 251

MOVING_IDS = tuple(range(251, 260))
IGNORED_IDS = (0, 1)

# Semantic ids used by the simulator and understood by the tools (SemanticKITTI's own; 9 and 251 are the MOS
# benchmark's static and moving).
SEMANTIC_NAMES: dict[int, str] = {
    0: "unlabeled", 1: "outlier", 9: "static", 10: "car", 11: "bicycle", 13: "bus", 15: "motorcycle",
    18: "truck", 20: "other-vehicle", 30: "person", 31: "bicyclist", 32: "motorcyclist",
    40: "road", 44: "parking", 48: "sidewalk", 49: "other-ground", 50: "building",
    51: "fence", 52: "other-structure", 60: "lane-marking", 70: "vegetation", 71: "trunk",
    72: "terrain", 80: "pole", 81: "traffic-sign", 99: "other-object",
    16: "on-rails",
    251: "moving", 252: "moving-car", 253: "moving-bicyclist", 254: "moving-person", 255: "moving-motorcyclist",
    256: "moving-on-rails", 257: "moving-bus", 258: "moving-truck", 259: "moving-other-vehicle",
}


def semantic_ids(raw_labels: np.ndarray) -> np.ndarray:
    """The semantic id (low 16 bits) of SemanticKITTI uint32 labels."""
    return (np.asarray(raw_labels).astype(np.uint32) & 0xFFFF).astype(np.int32)


def instance_ids(raw_labels: np.ndarray) -> np.ndarray:
    """The instance id (upper 16 bits) of SemanticKITTI uint32 labels."""
    return (np.asarray(raw_labels).astype(np.uint32) >> 16).astype(np.int32)


def to_moving_classes(raw_labels: np.ndarray) -> np.ndarray:
    """Map raw labels to IGNORE (-1), STATIC (0) or MOVING (1) as the MOS benchmark does."""
    sem = semantic_ids(raw_labels)
    out = np.full(sem.shape, STATIC, dtype=np.int8)
    out[(sem >= 251) & (sem <= 259)] = MOVING
    out[(sem == 0) | (sem == 1)] = IGNORE
    return out


def check_prediction_ids(raw_labels: np.ndarray, where: str) -> None:
    """Raise a DatasetError when predictions are not in SemanticKITTI ids (e.g. binary 0/1 or class indices).

    The benchmark would silently score such a file as all static (0 and 1 are 'unlabeled' and 'outlier').
    """
    present = np.unique(semantic_ids(raw_labels))
    unknown = [int(i) for i in present if int(i) not in SEMANTIC_NAMES]
    if unknown:
        shown = ", ".join(str(i) for i in unknown[:5]) + (" ..." if len(unknown) > 5 else "")
        raise DatasetError(f"{where}: ids {shown} are no SemanticKITTI ids (write 9 static / 251 moving, or any "
                         "of 251-259 for moving)")
    if len(present) and set(present.tolist()) <= {0, 1} and 1 in present:
        raise DatasetError(f"{where}: only ids 0 and 1, which SemanticKITTI reads as 'unlabeled' and 'outlier': "
                         "binary predictions? write 9 static / 251 moving")


def to_submission(moving: np.ndarray) -> np.ndarray:
    """Binary per-point labels (bool or 0/1) to the benchmark's uint32 submission ids."""
    moving = np.asarray(moving).astype(bool)
    return np.where(moving, SUBMISSION_MOVING_ID, SUBMISSION_STATIC_ID).astype(np.uint32)
