"""Soak test of mos_node: a bag replayed in a loop at 10 Hz, then at a multiple of the node's capacity.

    python benchmarks/soak.py --seconds 150 [--model M.onnx] [--bag BAG] [--overload 2] [--json out.json]

Starts ``mos_node`` as a separate process (reliable input QoS, as large clouds across
processes need), publishes the bag's clouds from this process with their recorded stamps
(so every loop makes time jump backwards, as ``ros2 bag play --loop`` does), samples the
node's RSS from /proc, reads its /diagnostics (received, processed, dropped, resets,
stage timings) and measures the end-to-end latency publish -> /mos/odometry (published
last for each scan). The first half of ``--seconds`` runs at 10 Hz; the node's capacity
is then estimated (its throughput in the first half, or the inverse of its mean processing time,
whichever is larger) and the second half runs at
``--overload`` times that. Finally the node is stopped with SIGTERM.

Without ``--model`` the residual-threshold test model for the 32 x 512 test sensor is
exported (needs torch); without ``--bag`` a street sequence of ``--scans`` analytic scans
(``test/scenes.py``) is written. Prints a summary; ``--json`` writes every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BASE_STAMP = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000  # the generated bag is 10 Hz
MAX_RATE_HZ = 200.0


def rss_kb(pid: int) -> int | None:
    """Resident set size of a process (VmRSS, kB), None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def slope_per_min(samples: list[tuple[float, float]]) -> float:
    """Least-squares slope of (t seconds, value) samples, per minute."""
    if len(samples) < 2:
        return 0.0
    ts = [t for t, _ in samples]
    vs = [v for _, v in samples]
    mt, mv = statistics.fmean(ts), statistics.fmean(vs)
    den = sum((t - mt) ** 2 for t in ts)
    return 60.0 * sum((t - mt) * (v - mv) for t, v in zip(ts, vs)) / den if den > 0 else 0.0


def percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q / 100.0 * (len(s) - 1))))]


def load_average() -> list[float]:
    return list(os.getloadavg())


def make_inputs(args: argparse.Namespace, tmp: Path) -> tuple[Path, Path]:
    """The model and bag to use, generated into ``tmp`` where not given."""
    sys.path.insert(0, str(ROOT / "test"))
    model = Path(args.model) if args.model else None
    if model is None:
        from conftest import make_threshold_model  # the test suite's real ONNX model (needs torch)

        model = make_threshold_model(tmp / "threshold.onnx")
    bag = Path(args.bag) if args.bag else None
    if bag is None:
        from scenes import street_sequence

        from ros2_mos.io.bags import write_scans_bag

        bag = tmp / "street"
        seq = street_sequence(args.scans)
        write_scans_bag(bag, ((BASE_STAMP + i * PERIOD_NS, p, r) for i, (p, r, _, _) in enumerate(seq)))
    return model, bag


class Monitor:
    """This side of the soak: publisher, /diagnostics and /mos/odometry listeners, RSS sampler."""

    def __init__(self, node_pid: int, rss_period: float) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from ros2_mos.ros import messages as m

        self.m = m
        self.types = m.MessageTypes.rclpy()
        self.node = rclpy.create_node("mos_soak")
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.node.create_publisher(self.types.point_cloud2, "/points", qos)
        self.lock = threading.Lock()
        self.t0 = time.monotonic()
        self.diagnostics: list[dict[str, Any]] = []  # {"t", "level", "message", **values}
        self.published_at: dict[int, float] = {}  # stamp -> monotonic time of its latest publication
        self.latencies: list[tuple[float, float]] = []  # (t, ms)
        self.rss: list[tuple[float, int]] = []  # (t, kB)
        self.node.create_subscription(self.types.diagnostic_array, "/diagnostics", self._on_diag, 50)
        self.node.create_subscription(self.types.odometry, "/mos/odometry", self._on_odom,
                                      QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self.executor.spin, name="soak_spin", daemon=True)
        self._spin.start()
        self._stop = threading.Event()
        self._pid = node_pid
        self._sampler = threading.Thread(target=self._sample_rss, args=(rss_period,), name="soak_rss", daemon=True)
        self._sampler.start()

    def now(self) -> float:
        return time.monotonic() - self.t0

    def _sample_rss(self, period: float) -> None:
        while not self._stop.is_set():
            kb = rss_kb(self._pid)
            if kb is None:
                return
            with self.lock:
                self.rss.append((self.now(), kb))
            self._stop.wait(period)

    def _on_diag(self, msg: Any) -> None:
        for status in msg.status:
            if status.name.startswith("mos_node"):
                level = status.level if isinstance(status.level, int) else int.from_bytes(status.level, "little")
                entry = {"t": self.now(), "level": level, "message": status.message,
                         **{kv.key: kv.value for kv in status.values}}
                with self.lock:
                    self.diagnostics.append(entry)

    def _on_odom(self, msg: Any) -> None:
        arrived = time.monotonic()
        stamp = self.m.stamp_ns(msg.header.stamp)
        with self.lock:
            sent = self.published_at.get(stamp)
            if sent is not None and arrived >= sent:
                self.latencies.append((arrived - self.t0, (arrived - sent) * 1e3))

    def last_diag(self) -> dict[str, Any] | None:
        with self.lock:
            return dict(self.diagnostics[-1]) if self.diagnostics else None

    def wait_for_node(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while self.pub.get_subscription_count() == 0:
            if time.monotonic() > end:
                return False
            time.sleep(0.05)
        return True

    def publish_loop(self, clouds: list[Any], rate_hz: float, seconds: float, start_index: int) -> tuple[int, int, int]:
        """Publish ``clouds`` cyclically at ``rate_hz`` for ``seconds``; (published, wraps, next index)."""
        sent = wraps = 0
        i = start_index
        start = time.monotonic()
        while True:
            due = start + sent / rate_hz
            if due - start >= seconds:
                break
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            msg = clouds[i]
            with self.lock:
                self.published_at[self.m.stamp_ns(msg.header.stamp)] = time.monotonic()
            self.pub.publish(msg)
            sent += 1
            i += 1
            if i == len(clouds):
                i, wraps = 0, wraps + 1
        return sent, wraps, i

    def close(self) -> None:
        self._stop.set()
        self.executor.shutdown()
        self._spin.join(5)
        self._sampler.join(5)
        self.node.destroy_node()


def _int(d: dict[str, Any] | None, key: str) -> int:
    return int(d[key]) if d and key in d else 0


def _counts(d: dict[str, Any] | None) -> dict[str, int]:
    return {k: _int(d, k) for k in ("received", "processed", "dropped", "skipped", "errors", "resets",
                                    "degraded_scans")}


def run(args: argparse.Namespace) -> dict[str, Any]:
    import rclpy

    from ros2_mos.io.bags import iter_messages, pointcloud_topic
    from ros2_mos.ros import messages as m

    tmp = Path(tempfile.mkdtemp(prefix="mos_soak_"))
    model, bag = make_inputs(args, tmp)
    topic = pointcloud_topic(bag, None)
    types = m.MessageTypes.rclpy()
    clouds = [m.copy_cloud(types, msg) for _, _, msg in iter_messages(bag, [topic])]
    if not clouds:
        raise SystemExit(f"{bag}: no PointCloud2 messages")

    domain = args.domain if args.domain is not None else 100 + os.getpid() % 100
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    from ros2_mos.ros.dds import use_large_message_profile

    use_large_message_profile()  # full-size clouds across processes, as we recommend to users
    env = dict(os.environ, PYTHONUNBUFFERED="1")  # inherits both bootstrap variables or neither
    params = tmp / "params.yaml"
    params.write_text(f"mos_node:\n  ros__parameters:\n    model: {model}\n    qos:\n      reliability: reliable\n"
                      f"      depth: 5\n    diagnostics_period: {args.diagnostics_period}\n    log_period: 0.0\n")
    node_bin = Path(sys.executable).parent / "mos_node"
    log_lines: list[str] = []
    proc = subprocess.Popen([str(node_bin), "--ros-args", "--params-file", str(params)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    reader = threading.Thread(target=lambda: log_lines.extend(proc.stdout), daemon=True)  # type: ignore[arg-type]
    reader.start()
    load_before = load_average()
    rclpy.init()
    monitor: Monitor | None = None
    result: dict[str, Any] = {"bag": str(bag), "model": str(model), "scans_in_bag": len(clouds),
                              "points_per_scan": int(clouds[0].width * clouds[0].height), "domain": domain}
    try:
        started = time.monotonic()
        while not any("ready in" in line for line in log_lines):
            if proc.poll() is not None or time.monotonic() - started > 60:
                raise SystemExit("mos_node did not start:\n" + "".join(log_lines))
            time.sleep(0.05)
        monitor = Monitor(proc.pid, args.rss_period)
        if not monitor.wait_for_node(15):
            raise SystemExit("mos_node did not subscribe to /points")

        phases: list[dict[str, Any]] = []
        index = 0
        half = args.seconds / 2.0
        for name in ("10hz", "overload"):
            if name == "10hz":
                rate = 10.0
            else:
                # The node's capacity: its throughput where the 10 Hz phase already overloaded it, else the
                # inverse of its mean processing time (both noisy on a shared machine: take the larger).
                d = monitor.last_diag()
                total_ms = float(d["total_ms_mean"]) if d and "total_ms_mean" in d else 100.0
                throughput = phases[0]["processed"] / phases[0]["seconds"]
                capacity = max(1000.0 / max(total_ms, 1e-3), throughput)
                result.update(capacity_hz=capacity, capacity_from_time_hz=1000.0 / max(total_ms, 1e-3),
                              throughput_at_10hz=throughput)
                rate = min(args.overload * capacity, MAX_RATE_HZ)
            before = _counts(monitor.last_diag())
            t_start = monitor.now()
            sent, wraps, index = monitor.publish_loop(clouds, rate, half, index)
            time.sleep(max(1.5 * args.diagnostics_period, 0.5))  # the last scans and a fresh diagnostics message
            after = _counts(monitor.last_diag())
            t_end = monitor.now()
            with monitor.lock:
                lat = [ms for t, ms in monitor.latencies if t_start <= t <= t_end]
            phases.append({
                "phase": name, "rate_hz": rate, "seconds": half, "published": sent, "loop_wraps": wraps,
                **{k: after[k] - before[k] for k in after},
                "latency_ms_median": statistics.median(lat) if lat else None,
                "latency_ms_p95": percentile(lat, 95), "latency_ms_max": max(lat) if lat else None,
                "latency_samples": len(lat), "load_average": load_average(),
            })
        # Let the node settle, then every received cloud must be accounted for.
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            d = _counts(monitor.last_diag())
            if d["received"] == d["processed"] + d["dropped"] + d["skipped"] + d["errors"]:
                break
            time.sleep(0.2)
        with monitor.lock:
            diags = list(monitor.diagnostics)
            rss = list(monitor.rss)
        final = _counts(diags[-1] if diags else None)
        in_flight = [_int(d, "received") - _int(d, "processed") - _int(d, "dropped") - _int(d, "skipped")
                     - _int(d, "errors") for d in diags]
        result.update(phases=phases, final_counts=final, in_flight_max=max(in_flight, default=0),
                      unaccounted_at_end=final["received"] - final["processed"] - final["dropped"]
                      - final["skipped"] - final["errors"],
                      diagnostics_messages=len(diags),
                      dropped_reported_max=max((_int(d, "dropped") for d in diags), default=0),
                      diagnostics_levels=sorted({d["level"] for d in diags}),
                      diagnostics_warnings=sorted({d["message"] for d in diags if d["level"] != 0})[:10])
        result["rss"] = rss_summary(rss, args.warmup)
    finally:
        if monitor is not None:
            monitor.close()
        rclpy.try_shutdown()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        reader.join(5)
    log = "".join(log_lines)
    result.update(node_exit_code=proc.returncode, stopped_with="SIGTERM",
                  final_statistics=next((line.strip() for line in log_lines if "final statistics" in line), None),
                  traceback_in_log="Traceback" in log,
                  backwards_resets_logged=sum("time went backwards" in line for line in log_lines),
                  pose_jump_resets_logged=sum("pose jumped" in line for line in log_lines),
                  gap_resets_logged=sum("reset_after_gap" in line for line in log_lines),
                  load_average_before=load_before,
                  load_average_after=load_average(), node_log_tail=log_lines[-8:])
    return result


def rss_summary(samples: list[tuple[float, int]], warmup: float) -> dict[str, Any]:
    """RSS figures in MB; growth and slope are measured after ``warmup`` seconds."""
    if not samples:
        return {}
    mb = [(t, kb / 1024.0) for t, kb in samples]
    warm = [s for s in mb if s[0] >= warmup] or mb
    second_half = [s for s in mb if s[0] >= (mb[0][0] + mb[-1][0]) / 2.0]
    slope = slope_per_min(second_half)
    return {
        "samples": len(mb), "first_mb": mb[0][1], "after_warmup_mb": warm[0][1], "last_mb": mb[-1][1],
        "max_mb": max(v for _, v in mb), "growth_after_warmup_mb": warm[-1][1] - warm[0][1],
        "max_above_warmup_mb": max(v for _, v in warm) - warm[0][1],
        "second_half_slope_mb_per_min": slope, "duration_s": mb[-1][0] - mb[0][0],
        "timeline_mb": timeline(mb, 10),
    }


def timeline(samples: list[tuple[float, float]], bins: int) -> list[tuple[float, float]]:
    """(bin start s, mean value) over ``bins`` equal time bins."""
    t0, t1 = samples[0][0], samples[-1][0]
    width = (t1 - t0) / bins or 1.0
    out = []
    for b in range(bins):
        vals = [v for t, v in samples if t0 + b * width <= t < t0 + (b + 1) * width or (b == bins - 1 and t == t1)]
        if vals:
            out.append((round(t0 + b * width, 1), round(statistics.fmean(vals), 1)))
    return out


def report(r: dict[str, Any]) -> str:
    lines = [f"soak: {r['scans_in_bag']} scans x {r['points_per_scan']} points, looped; "
             f"load average before {r['load_average_before'][0]:.2f}, after {r['load_average_after'][0]:.2f}"]
    for p in r["phases"]:
        med, p95 = p["latency_ms_median"], p["latency_ms_p95"]
        lines.append(
            f"  {p['phase']:>8}: {p['rate_hz']:.1f} Hz for {p['seconds']:.0f} s: published {p['published']}, "
            f"received {p['received']}, processed {p['processed']}, dropped {p['dropped']}, skipped {p['skipped']}, "
            f"errors {p['errors']}, resets {p['resets']} ({p['loop_wraps']} loop wraps); latency median "
            + (f"{med:.0f} ms, p95 {p95:.0f} ms" if med is not None else "n/a")
            + f"; load {p['load_average'][0]:.2f}")
    if "capacity_hz" in r:
        lines.append(f"  capacity {r['capacity_hz']:.1f} Hz = max(1000 / mean processing ms = "
                     f"{r['capacity_from_time_hz']:.1f} Hz, "
                     f"throughput in the 10 Hz phase {r['throughput_at_10hz']:.1f} Hz)")
    rss = r["rss"]
    if rss:
        change = rss["second_half_slope_mb_per_min"] * rss["duration_s"] / 120.0  # over the second half
        flat = abs(change) < 5.0
        lines.append(
            f"  RSS: first {rss['first_mb']:.1f} MB, after warm-up {rss['after_warmup_mb']:.1f} MB, "
            f"last {rss['last_mb']:.1f} MB, max {rss['max_mb']:.1f} MB; growth after warm-up "
            f"{rss['growth_after_warmup_mb']:+.1f} MB; second-half slope {rss['second_half_slope_mb_per_min']:+.2f} "
            f"MB/min, i.e. {change:+.1f} MB over the second half -> {'flat' if flat else 'NOT flat'} "
            "(criterion: |change| < 5 MB)")
        lines.append("  RSS timeline (s: MB): " + ", ".join(f"{t:.0f}: {v:.1f}" for t, v in rss["timeline_mb"]))
    lost = sum(p["published"] - p["received"] for p in r["phases"])
    lines.append(f"  transport: {lost} published clouds never reached the node's callback (input QoS keep-last "
                 "history overwritten; invisible to its dropped counter)")
    lines.append(f"  queue: at most {r['in_flight_max']} clouds in flight (waiting + being processed) in any "
                 f"diagnostics sample; {r['unaccounted_at_end']} unaccounted at the end; final {r['final_counts']}")
    lines.append(f"  resets logged: {r['backwards_resets_logged']} time went backwards (loop wraps), "
                 f"{r['pose_jump_resets_logged']} pose jumps, {r['gap_resets_logged']} gaps > reset_after_gap")
    lines.append(f"  node: exit code {r['node_exit_code']} after SIGTERM; traceback in log: {r['traceback_in_log']}; "
                 f"{r['final_statistics']}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=150.0,
                        help="total publishing time (half 10 Hz, half overload)")
    parser.add_argument("--overload", type=float, default=2.0, help="second half rate = this x the node's capacity")
    parser.add_argument("--model", help="ONNX model (default: export the residual-threshold test model)")
    parser.add_argument("--bag", help="rosbag2 with one PointCloud2 topic (default: a generated street sequence)")
    parser.add_argument("--scans", type=int, default=30, help="scans of the generated sequence")
    parser.add_argument("--warmup", type=float, default=5.0, help="seconds before RSS growth is measured")
    parser.add_argument("--rss-period", type=float, default=0.5, help="seconds between RSS samples")
    parser.add_argument("--diagnostics-period", type=float, default=0.5, help="the node's diagnostics_period")
    parser.add_argument("--domain", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument("--json", help="write every figure to this file")
    args = parser.parse_args()
    result = run(args)
    print(report(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))
    if result["node_exit_code"] != 0:
        sys.exit(1)


if __name__ == "__main__":
    main()
