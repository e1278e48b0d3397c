"""The node's output topics, one entry each: what it carries, how it is built, when it is published.

Adding an output is one :class:`Output` here (with a builder in :mod:`ros2_mos.ros.messages` where it needs a
new kind of message) and a row in the README's topic table. Its parameter ``topics.<key>``, config/mos.yaml
(``ros2-mos params``), the node's publisher and the ``process`` command's bag topic all follow from the entry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ros2_mos.ros import messages as m


@dataclass(frozen=True)
class ScanContext:
    """What the builders of one scan's messages read."""

    types: m.MessageTypes
    header: Any  # stamp and the cloud's frame
    odom_header: Any  # stamp and the odometry frame
    child_frame: str  # the sensor frame the odometry and tf point to
    view: Any  # the input cloud (CloudView)
    kept: np.ndarray  # indices of the labelled points in the input cloud
    moving: np.ndarray  # bool per kept point
    result: Any  # the pipeline's MosResult


@dataclass(frozen=True)
class Output:
    """One output topic: ``key`` names it (parameter ``topics.<key>``, default ``/mos/<key>``).

    ``message_type`` is the :class:`~ros2_mos.ros.messages.MessageTypes` attribute of its message; ``lazy``
    outputs are built only while someone subscribes; ``labels`` outputs are withheld while the scan's residuals
    are incomplete and ``publish_incomplete`` is false.
    """

    key: str
    message_type: str
    description: str
    build: Callable[[ScanContext], Any]
    lazy: bool = True
    labels: bool = True


OUTPUTS: tuple[Output, ...] = (
    Output("static_points", "point_cloud2", "the input cloud's points labelled static, all fields kept",
           lambda c: m.subset_cloud(c.types, c.header, c.view, c.kept[~c.moving])),
    Output("moving_points", "point_cloud2", "the input cloud's points labelled moving, all fields kept",
           lambda c: m.subset_cloud(c.types, c.header, c.view, c.kept[c.moving])),
    Output("labels", "point_cloud2", "every labelled point with its label (0 static, 1 moving) and probability",
           lambda c: m.labels_cloud(c.types, c.header, c.view, c.kept, c.moving.astype(np.uint8),
                                    c.result.probability[c.result.valid])),
    Output("range_image", "image", "the range image (32FC1, m; 0 where empty)",
           lambda c: m.image_msg(c.types, c.header, c.result.range_image.astype(np.float32, copy=False)),
           labels=False),
    Output("mask", "image", "the moving mask of the range image (mono8, 255 = moving)",
           lambda c: m.image_msg(c.types, c.header, (c.result.mask_image > 0).astype(np.uint8) * 255)),
    Output("odometry", "odometry", "KISS-ICP's pose of the sensor in the odometry frame",
           lambda c: m.odometry_msg(c.types, c.odom_header, c.child_frame, c.result.pose), lazy=False, labels=False),
)

#: The keys of :data:`OUTPUTS`, in order.
OUTPUT_KEYS: tuple[str, ...] = tuple(o.key for o in OUTPUTS)


def build_messages(context: ScanContext, wanted: frozenset[str] | None, withhold_labels: bool,
                   publish_tf: bool) -> dict[str, Any]:
    """The messages of one scan keyed by output (plus ``tf``); ``wanted`` None builds every output."""
    out = {o.key: o.build(context) for o in OUTPUTS
           if (wanted is None or o.key in wanted) and not (withhold_labels and o.labels)}
    if publish_tf and (wanted is None or "tf" in wanted):
        tf = m.tf_msg(context.types, context.odom_header, context.child_frame, context.result.pose)
        if tf is not None:
            out["tf"] = tf
    return out
