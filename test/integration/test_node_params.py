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
from ros_harness import child_env, isolate_ros, run_node_until_ready  # noqa: E402

from ros2_mos.core.errors import ConfigError  # noqa: E402

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


def _rcl_applies(path, node: str) -> dict[str, Any]:
    """What rclpy gives the node ``node`` (fully qualified) out of the params file ``path``."""
    from rclpy.node import Node

    namespace, _, name = node.rpartition("/")
    isolate_ros(DOMAIN)
    context = rclpy.Context()
    rclpy.init(context=context, args=["probe", "--ros-args", "--params-file", str(path)])
    try:
        probe = Node(name, namespace=namespace or "/", context=context)
        try:
            return {k: p.value for k, p in probe._parameter_overrides.items()}
        finally:
            probe.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_sections_reach_the_node_exactly_as_rcl_applies_them(tmp_path):
    """Issue 32.2: the package's reading of a params file is rclpy's, for every key form and namespace."""
    from test_params_sections import KEYS

    from ros2_mos.ros.params import read_params_file

    def section(key: str, threshold: float) -> str:
        return f"{key}:\n  ros__parameters:\n    threshold: {threshold}\n"

    files = [section(key, 0.5) for key, _, _ in KEYS] + [
        section("/robot1/mos_node", 0.1) + section("/**", 0.2),
        section("/**", 0.2) + section("/robot1/mos_node", 0.1),
        section("/**/mos_node", 0.3) + section("/robot1/mos_node", 0.1) + section("/**/mos_node", 0.4),
        section("robot1/mos_node", 0.1) + section("/**", 0.2) + section("/robot1/mos_node", 0.3),
        section("/robot1/*", 0.4) + section("/*/mos_node", 0.3) + section("mos_node", 0.6),
    ]
    nodes = ["/mos_node", "/robot1/mos_node", "/robot2/mos_node", "/a/b/mos_node", "/robot1/other"]
    for k, text in enumerate(files):
        path = tmp_path / f"p{k}.yaml"
        path.write_text(text)
        for node in nodes:
            expected = _rcl_applies(path, node)
            if expected:
                assert read_params_file(path, node)[0] == expected, (text, node)
            else:
                with pytest.raises(ConfigError, match="no parameters for node"):
                    read_params_file(path, node)


def _run_node(args: list[str], domain: int) -> tuple[int, str]:
    return run_node_until_ready(args, child_env(domain))


def test_a_namespaced_node_reads_its_section_and_names_itself(tmp_path, tiny_model_path):
    """Issue 32.2: `--params-file f.yaml -r __ns:=/robot1` with `/robot1/mos_node:` was refused; `mos_node:` was
    taken by the check but not applied by rcl (defaults, silently). The final statistics name the node."""
    good = tmp_path / "good.yaml"
    good.write_text(f"/robot1/mos_node:\n  ros__parameters:\n    model: {tiny_model_path}\n    threshold: 1\n")
    code, out = _run_node(["--params-file", str(good), "-r", "__ns:=/robot1"], DOMAIN + 1)
    assert code == 0 and "threshold 1.00" in out and "Traceback" not in out, out
    assert "final statistics: " in out and "(node /robot1/mos_node)" in out, out
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(f"mos_node:\n  ros__parameters:\n    model: {tiny_model_path}\n")
    code, out = _run_node(["--params-file", str(wrong), "-r", "__ns:=/robot1"], DOMAIN + 1)
    assert code == 1 and "cannot start" in out and "no parameters for node '/robot1/mos_node'" in out, out
    assert "Traceback" not in out
    # Beside a catch-all section the node starts, and says which section it does not get.
    both = tmp_path / "both.yaml"
    both.write_text(f"/**:\n  ros__parameters:\n    model: {tiny_model_path}\n"
                    "mos_node:\n  ros__parameters:\n    threshold: 0.3\n")
    code, out = _run_node(["--params-file", str(both), "-r", "__ns:=/robot1"], DOMAIN + 1)
    assert code == 0 and "section ['mos_node'] not applied to /robot1/mos_node" in out, out


def test_a_sensor_frame_equal_to_the_odom_frame_is_refused(tiny_model_path):
    """Issue 32.8: a self-transform started silently."""
    code, out = _run_node(["-p", f"model:={tiny_model_path}", "-p", "sensor_frame:=odom"], DOMAIN + 2)
    assert code == 1 and "cannot start: parameters 'sensor_frame' and 'odom_frame' are both 'odom'" in out, out
    assert "Traceback" not in out


def test_the_descriptor_ranges_are_the_checked_ranges():
    """Issue 32.6: the range a descriptor advertises (`ros2 param describe`) is the one the node checks; ROS ranges
    are inclusive, so a bound that must be exceeded starts at the first value above it."""
    from ros2_mos.ros.node import _descriptor
    from ros2_mos.ros.params import PARAMS, check_value

    for spec in PARAMS:
        desc = _descriptor(spec)
        ranges = list(desc.floating_point_range) + list(desc.integer_range)
        if not ranges:
            continue
        low, high = ranges[0].from_value, ranges[0].to_value
        assert check_value(spec, spec.type(low)) == low and check_value(spec, spec.type(high)) == high, spec.name
        if spec.knob.above and spec.knob.unset != spec.min:
            with pytest.raises(ConfigError, match=spec.name):
                check_value(spec, spec.type(spec.min))
