"""How mos_node takes its parameters over real rclpy: integers for floats, params-file sections as rcl applies
them (namespaces, wildcards), and settings refused at start-up (issue 32, items 2, 6, 8)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402
from ros_harness import isolate_ros  # noqa: E402

DOMAIN = 60 + os.getpid() % 150


@contextmanager
def node_with(overrides: dict[str, Any]) -> Iterator[Any]:
    """A MosNode in its own context, with ``overrides`` as rclpy passes a params file's values (typed as given)."""
    from ros2_mos.ros.node import MosNode

    isolate_ros(DOMAIN)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = None
    try:
        node = MosNode(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        yield node
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_integers_are_taken_for_float_parameters(tiny_model_path):
    """Issue 32.6: `threshold: 1` (an INTEGER to rclpy) was refused with rclpy's type error."""
    with node_with({"model": str(tiny_model_path), "threshold": 1, "reset_after_gap": 2}) as node:
        assert node.processor.pipeline.threshold == 1.0
        assert node.get_parameter("threshold").value == 1.0
        assert node.get_parameter("threshold").type_ == Parameter.Type.DOUBLE
        assert node.settings.reset_after_gap == 2.0
