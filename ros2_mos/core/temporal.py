"""Temporal fusion: a recursive Bayes filter over the range image's moving belief.

The network labels each scan on its own. A surface that it has called static for a while (a parked car,
a wall) should not turn moving for one scan because a pose error or a depth edge gave it a residual, and a
surface it called moving a moment ago (a slow car) should not drop out when one scan's residual is weak.
4DMOS and MapMOS fuse their predictions over time for the same reason.

Each scan's belief is a log-odds image ``b_t``. For a pixel whose network probability is at least
:data:`CANDIDATE_PROBABILITY` (all others are static beyond doubt and keep their own log-odds), the
pixel's point is moved into the previous scan's frame and looked up in the previous range image. Where
the previous scan saw the same surface there (ranges within :data:`MATCH_ABSOLUTE` m or
:data:`MATCH_RELATIVE` of the range), the previous belief is its prior::

    b_t = logit(p_t) + weight * b_{t-1}(matching pixel),   clipped to +-MAX_BELIEF

and elsewhere (the space was free a scan ago: something moved in) the prior is 0, so the network's own
word stands. ``weight`` in [0, 1] is how much of the past belief survives one scan; 0 turns fusion off.
The cost is one projection of the candidate pixels, not of the whole scan.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.projection import RangeImage, pixel_index_columns
from ros2_mos.core.residuals import relative_pose, transform_columns

#: Pixels with a lower moving probability keep their own belief (no lookup in the previous scan).
CANDIDATE_PROBABILITY = 0.05
#: Beliefs are clipped to +-this log-odds (p = 0.018 .. 0.982), so that no history is unshakeable.
MAX_BELIEF = 4.0
#: Same surface as a scan ago when the ranges differ by at most this many metres ...
MATCH_ABSOLUTE = 0.3
#: ... or by this share of the range, whichever is larger (odometry errors grow with range).
MATCH_RELATIVE = 0.05


def logit(p: np.ndarray) -> np.ndarray:
    """log(p / (1 - p)), clipped to +-MAX_BELIEF (float32)."""
    eps = np.float32(1e-6)
    q = np.clip(p.astype(np.float32, copy=False), eps, 1 - eps)
    return np.clip(np.log(q / (1 - q)), -MAX_BELIEF, MAX_BELIEF).astype(np.float32, copy=False)


def sigmoid(b: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-b))).astype(np.float32, copy=False)


class BeliefFilter:
    """The fusion stage: :meth:`fuse` one scan's probability image with the last scan's belief.

    The belief is kept as a probability image (``sigmoid(b)``): only the candidate pixels are ever converted to
    log-odds, so the stage costs in proportion to them, not to the image.
    """

    def __init__(self, sensor: SensorConfig, weight: float) -> None:
        if not 0.0 <= weight <= 1.0:
            raise ValueError(f"temporal weight must be in [0, 1], got {weight}")
        self.sensor = sensor
        self.weight = float(weight)
        self._range: np.ndarray | None = None  # (H, W) previous range image
        self._probability: np.ndarray | None = None  # (H, W) previous fused probability, sigmoid(b_{t-1})
        self._pose: np.ndarray | None = None

    def reset(self) -> None:
        self._range = self._probability = self._pose = None

    def fuse(self, probability: np.ndarray, image: RangeImage, pose: np.ndarray) -> np.ndarray:
        """The fused (H, W) moving probability of this scan; remembers it for the next one."""
        if self.weight == 0.0:
            return probability
        fused = probability
        if self._probability is not None:
            rows, cols = np.nonzero((probability >= CANDIDATE_PROBABILITY) & image.mask)
            if len(rows):
                prior = self.prior(image.xyz[rows, cols], image.range[rows, cols], pose)
                belief = np.clip(logit(probability[rows, cols]) + self.weight * prior, -MAX_BELIEF, MAX_BELIEF)
                fused = probability.copy()
                fused[rows, cols] = sigmoid(belief)
        self._range, self._probability, self._pose = image.range, fused, np.asarray(pose, np.float64)
        return fused

    def prior(self, xyz: np.ndarray, ranges: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The previous belief (log-odds) of the surface each point (current frame) lies on; 0 where none matches."""
        assert self._range is not None and self._probability is not None and self._pose is not None
        x, y, z = transform_columns(xyz, relative_pose(self._pose, np.asarray(pose, np.float64)))
        pixels = pixel_index_columns(x, y, z, self.sensor)
        previous_range = self._range[pixels.v, pixels.u]
        tolerance = np.maximum(MATCH_ABSOLUTE, MATCH_RELATIVE * ranges)
        same = pixels.in_image & (previous_range > 0) & (np.abs(pixels.range - previous_range) <= tolerance)
        return np.where(same, logit(self._probability[pixels.v, pixels.u]), 0.0).astype(np.float32)
