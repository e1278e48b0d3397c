"""Visibility evidence: was the place where a point lies seen empty by another scan of the drive?

A point ``p`` of scan k (world frame) is *seen through* by scan j when scan j's rays around the direction of ``p``
all returned from beyond it: every range of the 3 x 5 pixels (rows x columns) around ``p``'s pixel in scan j exceeds
the distance from scan j's sensor to ``p`` by a margin (:data:`FREE_MARGIN_M`, or :data:`FREE_MARGIN_RELATIVE` of
it). Then the surface at ``p`` was not there at time j: whatever stands there now moved, before or after. The
minimum over the neighbourhood keeps thin poles, trunks and object edges from being seen through by a neighbouring
ray that passed beside them (or by a small pose error), and a pixel without a return (sky, a black car) counts as
not seen through.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.config import SensorConfig
from ros2_mos.core.projection import pixel_index_columns, project_range
from ros2_mos.core.residuals import transform_columns

FREE_MARGIN_M = 0.5
FREE_MARGIN_RELATIVE = 0.04


def neighbourhood_min(range_image: np.ndarray, columns: int = 2) -> np.ndarray:
    """The minimum range of each pixel's neighbourhood: +-1 row, +-``columns`` columns (wrapping in azimuth; 0, no
    return, wins)."""
    out = range_image.copy()
    for shift in [s for c in range(1, columns + 1) for s in (-c, c)]:
        np.minimum(out, np.roll(range_image, shift, axis=1), out=out)
    rows = out.copy()
    np.minimum(out[1:], rows[:-1], out=out[1:])
    np.minimum(out[:-1], rows[1:], out=out[:-1])
    return out


class SeenScan:
    """One scan as a viewpoint: its world pose and its 3x3-minimum range image."""

    def __init__(self, points: np.ndarray, pose: np.ndarray, sensor: SensorConfig) -> None:
        self.pose = np.asarray(pose, np.float64)
        self.inverse = np.linalg.inv(self.pose)
        self.min_range = neighbourhood_min(project_range(points, sensor))
        self.sensor = sensor

    def seen_through(self, world_points: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray:
        """Per (N, 3) world point: did this scan see beyond it (the place was empty)? Seen from ``pose`` (4x4
        world) instead of the scan's own where given (a pose refined for the points' scan)."""
        inverse = self.inverse if pose is None else np.linalg.inv(pose)
        x, y, z = transform_columns(world_points, inverse)
        pixels = pixel_index_columns(x, y, z, self.sensor)
        measured = self.min_range[pixels.v, pixels.u]
        margin = np.maximum(FREE_MARGIN_M, FREE_MARGIN_RELATIVE * pixels.range)
        return pixels.in_image & (measured > pixels.range + margin)
