"""A driver and a SLAM stack in one process with default ROS settings (no DDS profile): run as a script.

Publishes ``--scans`` full-size HDL-64-like clouds (64 x 2048 rays cast analytically into a street
canyon, ~120k points, the sensor moving 1 m per scan) on /points at 10 Hz and subscribes to
/mos/static_points, /mos/moving_points and /mos/labels, all with the same QoS (``--qos sensor``:
best effort, keep last 5, as SLAM stacks subscribe; ``--qos reliable``). Prints one JSON line with
the stamps received per topic. ``--min-outputs N``: after the ``--scans`` clouds, go on publishing (up to
``--max-scans``) until N clouds have arrived on /mos/labels: a best-effort publisher with Fast DDS's default
settings loses most large clouds on the way in (benchmarks/transport.md), and a test needs the node to have had
some work.
"""

from __future__ import annotations

import argparse
import json
import threading
import time

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from ros2_mos.io.pointcloud2 import fill_xyzi
from ros2_mos.ros import messages as m

TYPES = m.MessageTypes.rclpy()
TOPICS = ("static_points", "moving_points", "labels")
BASE_STAMP = 1_700_000_000_000_000_000


def _directions(rows: int = 64, cols: int = 2048) -> np.ndarray:
    el = np.radians(np.linspace(2.0, -24.8, rows, dtype=np.float32))[:, None]
    az = np.linspace(np.pi, -np.pi, cols, endpoint=False, dtype=np.float32)[None, :]
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el) + 0 * az], -1).reshape(-1, 3)


DIRECTIONS = _directions()


def canyon_scan(x0: float, car_x: float) -> np.ndarray:
    """Points of one sweep from (x0, 0, 0): ground at -1.7 m, facades at y = +-9 m with recesses, a car."""
    d = DIRECTIONS
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < -1e-6, -1.7 / dz, np.inf)
        tw = np.where(np.abs(dy) > 1e-6, 9.0 / np.abs(dy), np.inf)
        recess = (np.floor(np.nan_to_num((x0 + tw * dx) / 7.0, posinf=0.0, neginf=0.0)) % 3) == 0
        t = np.minimum(t, np.where(recess, tw * 1.15, tw))  # recessed doorways every 21 m
        # A car (box 4 x 2 x 1.5 m) at (car_x, 3) in the world, i.e. (car_x - x0, 3) from the sensor: slabs.
        lo = np.array([car_x - x0 - 2.0, 2.0, -1.7], np.float32)
        hi = np.array([car_x - x0 + 2.0, 4.0, -0.2], np.float32)
        t1, t2 = lo / d, hi / d
        near = np.max(np.minimum(t1, t2), 1)
        far = np.min(np.maximum(t1, t2), 1)
    t = np.where((near <= far) & (near > 0), np.minimum(t, near), t)
    ok = np.isfinite(t) & (t < 80.0)
    return d[ok] * t[ok, None]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scans", type=int, default=40)
    parser.add_argument("--qos", choices=("sensor", "reliable"), default="sensor")
    parser.add_argument("--wait", type=float, default=20.0, help="seconds to wait for the node's subscription")
    parser.add_argument("--min-outputs", type=int, default=0, help="publish on until this many labels arrived")
    parser.add_argument("--max-scans", type=int, default=400, help="... but never more clouds than this")
    args = parser.parse_args()

    rclpy.init()
    node = rclpy.create_node("transport_peer")
    qos = (qos_profile_sensor_data if args.qos == "sensor"
           else QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    got: dict[str, list[int]] = {t: [] for t in TOPICS}
    lock = threading.Lock()

    def on(topic: str):
        def callback(msg) -> None:
            with lock:
                got[topic].append(m.stamp_ns(msg.header.stamp))
        return callback

    for topic in TOPICS:
        node.create_subscription(TYPES.point_cloud2, f"/mos/{topic}", on(topic), qos)
    pub = node.create_publisher(TYPES.point_cloud2, "/points", qos)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    deadline = time.monotonic() + args.wait
    while time.monotonic() < deadline and not (
            pub.get_subscription_count() > 0 and all(node.count_publishers(f"/mos/{t}") > 0 for t in TOPICS)):
        time.sleep(0.05)
    time.sleep(1.0)  # let the node's publishers match our subscriptions too
    def cloud(i: int) -> tuple[object, int]:
        pts = canyon_scan(float(i), 20.0 + 1.5 * i)
        msg = fill_xyzi(m.empty_cloud(TYPES, m.make_header(TYPES, BASE_STAMP + i * 100_000_000, "velodyne")),
                        pts, np.full(len(pts), 0.3, np.float32), field_factory=TYPES.point_field)
        return msg, len(pts)

    clouds = [cloud(i) for i in range(args.scans)]  # made before the clock starts: 10 Hz without gaps

    def enough() -> bool:
        with lock:
            return len(got["labels"]) >= args.min_outputs

    sizes = []
    start = time.monotonic()
    i = 0
    while i < args.scans or (i < args.max_scans and not enough()):  # 10 Hz on the wall clock
        msg, size = clouds[i] if i < len(clouds) else cloud(i)
        delay = start + 0.1 * i - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        pub.publish(msg)
        sizes.append(size)
        i += 1
        if i == args.scans and not enough():
            time.sleep(1.0)  # the outputs still on their way before publishing more
            start = time.monotonic() - 0.1 * i
    time.sleep(3.0)  # the last outputs
    with lock:
        result = {"sent": i, "points": int(np.median(sizes)), **{t: sorted(v) for t, v in got.items()}}
    print(json.dumps(result), flush=True)
    executor.shutdown(timeout_sec=5.0)
    spin.join(timeout=5.0)  # a spin thread still inside rcl at exit aborts the process ("terminate called ...")
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
