"""Moving IoU on hand-made cases, with the benchmark's ignore rule."""

import math

import numpy as np
import pytest

from ros2_mos.core.errors import DatasetError
from ros2_mos.io.labels import IGNORE, MOVING, STATIC, to_moving_classes, to_submission
from ros2_mos.scoring.metrics import MovingIoU


def test_iou_counts_tp_fp_fn_and_skips_ignored():
    gt = np.array([MOVING, MOVING, MOVING, STATIC, STATIC, IGNORE, IGNORE])
    pred = np.array([1, 1, 0, 1, 0, 1, 0])
    s = MovingIoU().update(pred, gt)
    assert (s.tp, s.fp, s.fn, s.tn) == (2, 1, 1, 1)
    assert s.iou == pytest.approx(2 / 4)


def test_counts_accumulate_over_scans_before_dividing():
    s = MovingIoU()
    s.update([1, 0], [MOVING, STATIC])  # perfect scan: 1/1
    s.update([0, 0, 0], [MOVING, MOVING, MOVING])  # 0/3
    assert s.iou == pytest.approx(1 / 4)  # not the mean of per-scan IoUs (0.5)


def test_no_moving_anywhere_is_nan_not_zero_or_one():
    assert math.isnan(MovingIoU().update([0, 0], [STATIC, STATIC]).iou)


def test_length_mismatch_raises():
    with pytest.raises(DatasetError):
        MovingIoU().update([0, 1], [STATIC])


def test_label_mapping_follows_the_benchmark():
    raw = np.array([0, 1, 10, 40, 251, 252, 259, 260, 9], np.uint32) | (np.uint32(7) << 16)
    assert to_moving_classes(raw).tolist() == [IGNORE, IGNORE, STATIC, STATIC, MOVING, MOVING, MOVING, STATIC, STATIC]
    assert to_submission(np.array([True, False])).tolist() == [251, 9]
