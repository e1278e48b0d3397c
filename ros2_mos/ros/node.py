"""``mos_node``: moving object segmentation between a LiDAR driver and a SLAM stack.

The subscription callback only hands the newest cloud to a worker thread
(:class:`~ros2_mos.ros.latest_queue.LatestQueue`, size 1, oldest dropped and
counted), so the executor stays free for timers and other callbacks while a scan
is labelled. The worker runs :class:`~ros2_mos.ros.processor.ScanProcessor` (the
same code as the offline ``process`` command) and publishes the results. Bad
clouds are logged, counted and skipped; unexpected failures reset the pipeline
and the node keeps running. This module is the only one that imports rclpy; it
never imports torch.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ros2_mos.core import kernels
from ros2_mos.core.errors import ConfigError, ModelError, MosError, ScanError
from ros2_mos.io.pointcloud2 import fill_xyzi
from ros2_mos.ros import messages as m
from ros2_mos.ros.dds import transport_summary, use_large_message_profile
from ros2_mos.ros.diagnostics import DIAGNOSTIC_NAME, node_status
from ros2_mos.ros.latest_queue import LatestQueue
from ros2_mos.ros.outputs import OUTPUT_KEYS, OUTPUTS
from ros2_mos.ros.params import (
    NODE_NAME,
    PARAMS,
    ParamSpec,
    fully_qualified_name,
    mos_config,
    node_settings,
    read_params_file,
)
from ros2_mos.ros.processor import ScanOutput, ScanProcessor, SkippedScan
from ros2_mos.ros.stats import NodeStats, summary_line


def _descriptor(spec: ParamSpec) -> Any:
    """A read-only ParameterDescriptor with the spec's documentation, choices and bounds."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    desc = ParameterDescriptor(name=spec.name, description=spec.description,
                               additional_constraints=spec.constraints, read_only=True)
    if spec.min is not None and spec.max is not None:
        low: float = spec.min
        if spec.knob.above and spec.knob.unset != spec.min:  # ROS ranges are inclusive: the first value above min
            low = math.nextafter(float(low), math.inf) if spec.type is float else int(low) + 1
        if spec.type is float:
            desc.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(spec.max))]
        elif spec.type is int:
            desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(spec.max), step=1)]
    return desc


def sensor_qos(reliable: bool, depth: int) -> QoSProfile:
    """Input QoS: best effort + keep last ``depth`` (sensor data) or reliable."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, durability=DurabilityPolicy.VOLATILE,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
    )


class MosNode(Node):
    """The MOS node; construct after ``rclpy.init``. Raises ConfigError/ModelError on bad settings."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__(NODE_NAME, **node_kwargs)
        self._worker: threading.Thread | None = None
        self._queue: LatestQueue[tuple[Any, float]] = LatestQueue(1)
        self._stopped = False
        try:
            self._setup()
        except BaseException:
            self.destroy_node()
            raise

    # ------------------------------------------------------------------ set-up
    def _declare(self) -> dict[str, Any]:
        from rclpy.exceptions import ParameterException

        values: dict[str, Any] = {}
        overrides = getattr(self, "_parameter_overrides", {})  # rclpy keeps no public list of them
        for spec in PARAMS:
            default, ignore_override = spec.default, False
            given = overrides.get(spec.name)
            if spec.type is float and given is not None and type(given.value) is int:
                # `threshold: 1` in a params file: rclpy would refuse an INTEGER for a DOUBLE; the package takes it
                # (check_value does the same for the commands).
                default, ignore_override = float(given.value), True
            try:
                param = self.declare_parameter(spec.name, default, _descriptor(spec), ignore_override=ignore_override)
            except ParameterException as exc:
                raise ConfigError(f"parameter {spec.name!r}: {exc}") from None
            values[spec.name] = param.value
        unknown = sorted(n for n in overrides if n not in self._parameters and not n.startswith("qos_overrides."))
        if unknown:
            raise ConfigError(f"unknown parameters {unknown} (typo?); see config/mos.yaml for the known ones")
        return values

    def _setup(self) -> None:
        from ros2_mos.core.pipeline import MosPipeline

        t0 = time.perf_counter()
        values = self._declare()
        self.settings = node_settings(values)
        self.stats = NodeStats(max_gap_s=self.settings.reset_after_gap)  # longer gaps: paused input, not losses
        pipeline = MosPipeline(mos_config(values))
        self.types = m.MessageTypes.rclpy()
        self.processor = ScanProcessor(pipeline, self.settings, self.types)
        s = self.settings
        out_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.publish_depth,
                             reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        self._pubs = {o.key: self.create_publisher(getattr(self.types, o.message_type), s.topics[o.key], out_qos)
                      for o in OUTPUTS}
        if s.publish_tf and self.types.tf_message is not None:
            tf_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
            self._pubs["tf"] = self.create_publisher(self.types.tf_message, "/tf", tf_qos)
        elif s.publish_tf:
            self.get_logger().warning("tf2_msgs is not installed (e.g. PyPI wheels): the odom -> sensor transform is "
                                      f"not published on /tf; {s.topics['odometry']} carries the same pose")
        self._diag_pub = self.create_publisher(self.types.diagnostic_array, "/diagnostics", 10)
        self._map: Any = None
        if s.static_map is not None:
            from ros2_mos.ros.static_map import StaticMap

            sm = s.static_map
            self._map = StaticMap(sm)
            map_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE)
            self._map_pub = self.create_publisher(self.types.point_cloud2, sm.topic, map_qos)
            self._map_timer = self.create_timer(sm.publish_period, self._publish_map)
        self._sub = self.create_subscription(self.types.point_cloud2, s.input_topic, self._on_cloud,
                                             sensor_qos(s.reliable, s.depth))
        self._diag_timer = self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        self._log_timer = self.create_timer(s.log_period, self._log_stats) if s.log_period > 0 else None
        self._last_output: ScanOutput | None = None
        self._sensor_mismatch = ""  # the last mismatch logged (ros2_mos.core.sensor_check)
        self._stream_problem = ""  # the last stream problem logged (ScanProcessor.stream_problem)
        self._worker = threading.Thread(target=self._work, name="mos_worker", daemon=True)
        self._worker.start()
        p = pipeline
        outputs = ", ".join(self._pubs[key].topic_name for key in OUTPUT_KEYS)  # as resolved, remappings included
        self.get_logger().info(
            f"ready in {time.perf_counter() - t0:.2f} s: model {p.model.path.name} ({p.model.metadata.network}, "
            f"{p.setup.label}, threshold {p.threshold:.2f}, residuals to {p.residual_window.upper:g} m, "
            f"{p.model.provider}), sensor {p.sensor.name} "
            f"{p.sensor.height}x{p.sensor.width}, geometry {p.config.geometry_backend}"
            f"{f' ({kernels.status()})' if p.config.geometry_backend == 'numpy' else ''}; {self._sub.topic_name} "
            f"({'reliable' if s.reliable else 'best effort'}) -> {outputs}")
        # Discovery takes a moment: look for a namesake once it had time to be seen.
        self._namesake_timer = self.create_timer(2.0, self._warn_about_namesakes)

    def _warn_about_namesakes(self) -> None:
        self._namesake_timer.cancel()
        me = (self.get_name(), self.get_namespace())
        if sum(1 for entry in self.get_node_names_and_namespaces() if tuple(entry) == me) > 1:
            self.get_logger().warning(
                f"another node named {self.get_fully_qualified_name()} is running: both answer to the same "
                "parameters and services; give this one another name (--ros-args -r __node:=NAME)")

    # ------------------------------------------------------------------ executor side
    def _on_cloud(self, msg: Any) -> None:
        """Hand the cloud to the worker; never blocks (the oldest waiting cloud is dropped)."""
        self.stats.on_received(m.stamp_ns(msg.header.stamp) * 1e-9)
        if self._queue.put((msg, time.monotonic())):
            self.stats.on_dropped()

    # ------------------------------------------------------------------ worker side
    def _work(self) -> None:
        while not self._queue.closed:
            item = self._queue.get(timeout=0.5)
            if item is None:
                continue
            msg, received = item
            try:
                self._handle(msg, received)
            except Exception as exc:  # a bug or a failing library: log, reset, keep running
                if self._stopped or not self.context.ok():
                    return
                self.stats.on_error(f"{type(exc).__name__}: {exc}")
                self.get_logger().error(f"processing failed, pipeline reset: {type(exc).__name__}: {exc}")
                try:
                    self.processor.reset()
                except Exception as reset_exc:  # pragma: no cover - nothing sensible left to do
                    self.get_logger().error(f"reset failed too: {reset_exc}")

    def _handle(self, msg: Any, received: float) -> None:
        try:
            self._process(msg, received)
        finally:
            problem = self.processor.stream_problem
            if problem != self._stream_problem:  # one line when it starts (or ends)
                self._stream_problem = problem
                if problem:
                    self.get_logger().error(problem)
                else:
                    self.get_logger().info("one sensor on the input topic again")

    def _process(self, msg: Any, received: float) -> None:
        log = self.get_logger()
        try:
            out = self.processor.process(msg, self._wanted())
        except SkippedScan as exc:
            self.stats.on_skipped(exc.reason, str(exc))
            log.warning(str(exc), throttle_duration_sec=1.0)
            return
        except ScanError as exc:
            self.stats.on_skipped("bad_cloud", str(exc))
            log.warning(f"bad PointCloud2 skipped: {exc}", throttle_duration_sec=1.0)
            return
        for note in out.notes:
            log.warning(note)
        if out.result.sensor_mismatch != self._sensor_mismatch:  # one line when it starts (or ends)
            self._sensor_mismatch = out.result.sensor_mismatch
            if self._sensor_mismatch:
                log.error(f"{self._sensor_mismatch}; labels are flagged degraded until the sensor matches")
        if out.reset:
            self.stats.on_reset("; ".join(out.notes) or "scan buffer reset")
        if self._stopped:
            return
        for key, message in out.messages.items():
            pub = self._pubs.get(key)
            if pub is not None:
                pub.publish(message)
        self._last_output = out
        if self._map is not None:
            self._map.add(out)
        self.stats.on_processed(out.timings, (time.monotonic() - received) * 1e3, out.result.degraded)

    def _wanted(self) -> frozenset[str]:
        """The outputs to build: clouds and images only while someone subscribes to them.

        Each full-size cloud costs time to build and more to serialise (benchmarks/design_figures.md),
        on a CPU the pipeline needs; odometry and tf are tiny and always published (tf has no subscriber
        count that means anything).
        """
        lazy = {o.key for o in OUTPUTS if o.lazy}
        return frozenset(key for key, pub in self._pubs.items()
                         if key not in lazy or pub.get_subscription_count() > 0)

    # ------------------------------------------------------------------ reporting
    def _publish_map(self) -> None:
        snapshot = self._map.snapshot()
        if snapshot is None:
            return
        points, stamp = snapshot
        header = m.make_header(self.types, stamp, self.settings.odom_frame)
        cloud = fill_xyzi(m.empty_cloud(self.types, header), points, field_factory=self.types.point_field)
        self._map_pub.publish(cloud)

    def _publish_diagnostics(self) -> None:
        level, message, values = node_status(self.stats.snapshot(), self._last_output, self.processor.stream_problem)
        header = m.make_header(self.types, self.get_clock().now().nanoseconds, "")
        self._diag_pub.publish(m.diagnostics_msg(self.types, header, DIAGNOSTIC_NAME, self.get_name(), level,
                                                 message, values))

    def _log_stats(self) -> None:
        self.get_logger().info(summary_line(self.stats.snapshot()))

    # ------------------------------------------------------------------ shutdown
    def stop(self, timeout: float = 5.0) -> None:
        """Stop the worker (finishing the scan in hand) and log the final statistics; idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._queue.close()
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join(timeout)

    def destroy_node(self) -> None:
        """Stop the worker, destroy the node, then log the final statistics.

        Logged after destruction through a plain logger: after Ctrl-C the context is
        already shut down and the node's /rosout publisher could not carry the line.
        """
        started = self._worker is not None
        self.stop()
        name, logger = self.get_fully_qualified_name(), self.get_logger().name  # robot1.mos_node for /robot1/mos_node
        super().destroy_node()
        if started:
            rclpy.logging.get_logger(logger).info(f"final statistics: {summary_line(self.stats.snapshot())} "
                                                  f"(node {name})")


def _params_files(argv: list[str]) -> list[str]:
    """The ``--params-file`` paths of a ROS command line."""
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == "--params-file"]


def _node_fqn(argv: list[str]) -> str:
    """The node's fully qualified name on a ROS command line: ``-r __node:=NAME`` and ``-r __ns:=/NS`` remap it
    (also as ``-r mos_node:__ns:=/NS``, for this node alone), as a launch file's ``name=`` and ``namespace=`` do."""
    name, namespace = NODE_NAME, "/"
    for flag, rule in zip(argv, argv[1:]):
        target, sep, value = rule.partition(":=")
        if flag not in ("-r", "--remap") or not sep:
            continue
        node, _, key = target.rpartition(":")
        if node and node != NODE_NAME:
            continue
        if key in ("__node", "__name"):
            name = value
        elif key == "__ns":
            namespace = value
    return fully_qualified_name(name, namespace)


def main(args: list[str] | None = None) -> None:
    """Console entry ``mos_node`` (also ``ros2 run ros2_mos mos_node`` on a ROS install)."""
    # Before rclpy.init: DDS reads the profile when the participant is created.
    transport = transport_summary(os.environ, use_large_message_profile())
    argv = sys.argv if args is None else args
    try:
        # Read as the commands read it (a missing, broken or foreign file is one line, not rcl's traceback), with the
        # sections rcl gives this node's full name.
        fqn = _node_fqn(argv)
        for params_file in _params_files(argv):
            _, missed = read_params_file(params_file, fqn)
            if missed:
                rclpy.logging.get_logger(NODE_NAME).warning(
                    f"{params_file}: section{'s' if len(missed) > 1 else ''} {missed} not applied to {fqn} (rcl "
                    f"gives a section to the node whose full name it matches): key it {fqn!r} or '/**/"
                    f"{fqn.rsplit('/', 1)[1]}'")
        rclpy.init(args=args)
    except (ConfigError, RuntimeError) as exc:  # rcl's own argument errors are RuntimeErrors (RCLError)
        first = (str(exc).splitlines() or [""])[0]
        rclpy.logging.get_logger(NODE_NAME).fatal(f"cannot start: {first}")
        sys.exit(1)
    node: MosNode | None = None
    executor: SingleThreadedExecutor | None = None
    code = 0
    try:
        # The executor is built before the node says it is ready: a SIGINT that lands while rclpy.spin() would build
        # it leaves a half-made executor whose __del__ prints a traceback ('_sigint_gc') on the way out.
        executor = SingleThreadedExecutor()
        node = MosNode()
        node.get_logger().info(transport)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigError, ModelError) as exc:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"cannot start: {exc}")
        code = 1
    except MosError as exc:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"stopped: {exc}")
        code = 1
    except RuntimeError:
        # A SIGINT that shuts the context down while spin() sets up its wait set makes rclpy raise RCLError
        # ("the given context is not valid") instead of ExternalShutdownException: a normal stop all the same.
        if rclpy.ok():
            raise
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)


if __name__ == "__main__":
    main()
