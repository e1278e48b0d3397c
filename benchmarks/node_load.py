"""Issue 31: a driver, mos_node and a subscriber as three processes on this machine, full-size clouds at 10 Hz.

    python benchmarks/node_load.py [--runs 5] [--scans 40] [--rate 10] [--busy 1] [--node-param NAME:=VALUE]...
                                   [--ab NAME:=VALUE]...

Per run: a fresh ``mos_node`` (the shipped default model, its own large-message DDS profile); this process is the
driver (publishes the bench bag's clouds, reliable, restamped at publication, in a loop if ``--scans`` is longer
than the bag); a third process subscribes to ``/mos/labels`` with default settings (reliable, depth 10) and notes
when each labelled cloud arrives. 5 warm-up clouds go first at 2 Hz, then a pause longer than ``reset_after_gap``;
they are not counted, and the timed clouds continue the bag after them. ``--busy K`` keeps K more processes
spinning on the CPU during the runs (another program on the robot). Prints one Markdown row per run: clouds
published, labels the subscriber got (and which clouds got none), latency stamp ->
/mos/labels, what the node's /diagnostics said (dropped, capacity, mean and median ms of the main stages), and the
CPU time each of the three processes spent per published cloud while the clouds were sent (from /proc). ``--ab``
alternates the runs between the node's settings (A) and these changed (B): a same-run A/B.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Clouds sent at 2 Hz before the timed ones (not counted); the timed clouds continue the bag after them.
WARM_UP = 5


def subscriber(out: str) -> None:
    """The third process: /mos/labels with default QoS; appends "stamp_ns receive_ns" per labelled cloud to ``out``
    (flushed at once: the process is ended with SIGTERM)."""
    import rclpy
    from rclpy.qos import QoSProfile

    from ros2_mos.ros.messages import MessageTypes, stamp_ns

    rclpy.init()
    node = rclpy.create_node("mos_load_subscriber")
    clock = node.get_clock()
    sink = open(out, "a", buffering=1)

    def on_labels(msg) -> None:
        sink.write(f"{stamp_ns(msg.header.stamp)} {clock.now().nanoseconds}\n")

    node.create_subscription(MessageTypes.rclpy().point_cloud2, "/mos/labels", on_labels, QoSProfile(depth=10))
    from rclpy.executors import ExternalShutdownException

    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):  # SIGTERM/SIGINT at the end of a run
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds a process has used so far (Linux /proc; its threads included)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(bag: Path, scans: int, rate: float, node_params: list[str]) -> dict:
    from ros2_mos.io.bags import pointcloud_topic
    from ros2_mos.ros.replayer import Replayer
    from ros2_mos.tools.harness import NodeProcess

    params = {"qos.reliability": "reliable", "qos.depth": "1"}
    params.update(dict(p.split(":=", 1) for p in node_params))
    with tempfile.TemporaryDirectory() as tmp, NodeProcess(params) as node:
        out = Path(tmp) / "labels.txt"
        sub = subprocess.Popen([sys.executable, __file__, "--subscriber", str(out)])
        topic = pointcloud_topic(bag, None)
        replayer = Replayer(topic, reliable=True)
        try:
            if not replayer.wait_for_subscriber(60.0):
                raise RuntimeError("mos_node did not subscribe in 60 s:\n" + "".join(node.log[-20:]))
            time.sleep(2.0)  # the subscriber's discovery
            replayer.play(bag, topic, rate=0.2, max_messages=WARM_UP, restamp=True)  # warm-up at 2 Hz (rate x 10 Hz)
            time.sleep(2.5)
            replayer.published_stamps.clear()
            pids = {"node": node.process.pid, "subscriber": sub.pid, "driver": os.getpid()}
            cpu0 = {k: cpu_seconds(v) for k, v in pids.items()}
            # The timed clouds go on from where the warm-up stopped (the odometry is kept over the pause, so a jump
            # back to the bag's start would cost the first scans extra ICP iterations); a longer run loops the bag.
            sent = replayer.play(bag, topic, rate=rate / 10.0, restamp=True, max_messages=scans, start=WARM_UP)
            while sent < scans:
                sent += replayer.play(bag, topic, rate=rate / 10.0, restamp=True, max_messages=scans - sent)
            time.sleep(0.3)  # the last cloud's labels
            cpu_ms = {k: (cpu_seconds(v) - cpu0[k]) * 1e3 / max(sent, 1) for k, v in pids.items()}
            order = list(replayer.published_stamps)
            stamps = set(order)
            time.sleep(3.0)  # the last labels, and one more diagnostics period
            diag = dict(replayer.last_diagnostic_values)
        finally:
            replayer.close()
            sub.terminate()
            sub.wait(timeout=10)
        got = [tuple(map(int, line.split())) for line in out.read_text().splitlines()] if out.is_file() else []
    latency = [(t - s) * 1e-6 for s, t in got if s in stamps]
    labelled = {s for s, _ in got}
    missed = [i for i, s in enumerate(order) if s not in labelled]
    return {"sent": len(stamps), "labels": len(latency), "latency": latency, "diag": diag, "cpu_ms": cpu_ms,
            "missed": missed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--scans", type=int, default=40)
    parser.add_argument("--rate", type=float, default=10.0, help="input rate (Hz)")
    parser.add_argument("--busy", type=int, default=0, help="processes kept spinning during the runs")
    parser.add_argument("--bag", type=Path, default=ROOT / "data/bench/bags/bench")
    parser.add_argument("--node-param", action="append", default=[], help="NAME:=VALUE for mos_node")
    parser.add_argument("--ab", action="append", default=[],
                        help="NAME:=VALUE: every second run (B) also sets it; the table then says which run was which")
    parser.add_argument("--subscriber", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        subscriber(args.subscriber)
        return
    import rclpy

    from ros2_mos.tools.harness import isolate_ros_domain

    isolate_ros_domain()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    rows = []
    try:
        for run in range(args.runs):
            rclpy.init()
            try:
                b = bool(args.ab) and run % 2 == 1
                r = one_run(args.bag, args.scans, args.rate, args.node_param + (args.ab if b else []))
            finally:
                rclpy.try_shutdown()
            lat = np.array(r["latency"]) if r["latency"] else np.zeros(1)
            d = r["diag"]
            stages = ", ".join(f"{k} {float(d[f'{k}_ms_mean']):.0f} / {float(d.get(f'{k}_ms_median', 'nan')):.0f}"
                               for k in ("odometry", "residuals", "inference", "total") if f"{k}_ms_mean" in d)
            tag = " B" if b else (" A" if args.ab else "")
            share = 100 * r["labels"] / max(r["sent"], 1)
            missed = (f" (missed: {', '.join(map(str, r['missed'][:8]))}{' ...' if len(r['missed']) > 8 else ''})"
                      if r["missed"] else "")
            rows.append(f"| {run + 1}{tag} | {r['sent']} | **{r['labels']}** ({share:.0f} %){missed} | "
                        f"{np.median(lat):.0f} / {np.percentile(lat, 95):.0f} | {d.get('dropped', '?')} | "
                        f"{d.get('capacity_hz', '?')} | {stages} | "
                        + " / ".join(f"{r['cpu_ms'][k]:.0f}" for k in ("driver", "node", "subscriber")) + " |")
            print(rows[-1], file=sys.stderr, flush=True)
    finally:
        for p in busy:
            p.kill()
            p.wait()
    print(f"{args.runs} runs, {args.scans} clouds at {args.rate:g} Hz, {args.busy} busy processes, node params "
          f"{args.node_param or 'defaults'}{f'; B runs also {args.ab}' if args.ab else ''}; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}")
    print("| run | published | labels at the subscriber | latency stamp -> /mos/labels median / p95 (ms) | "
          "node dropped (incl. warm-up) | node capacity (Hz) | node ms, mean / median | CPU ms per cloud: driver / "
          "node / subscriber |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
