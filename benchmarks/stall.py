"""Issue 13 item 8: clouds of uniform random points through an in-process mos_node, and /diagnostics meanwhile.

    python benchmarks/stall.py after     # the code as it is
    python benchmarks/stall.py before    # plausibility check off, one KISS-ICP call per scan (the code before)
    python benchmarks/stall.py sliced    # plausibility check off, registration in slices (liveness alone)
    python benchmarks/stall.py sliced --no-yield  # the same without the short sleep between slices (round 13's code)

The node runs the shipped HDL-64E model with diagnostics every second (the defaults) on its own ROS domain.
It gets 3 simulated HDL-64E scans, 2 clouds of 127k points uniformly random within +-50 m (the issue's
cloud; the second registers against a map that holds the first), then 1 simulated scan, 10 Hz stamps. Prints
per cloud how long the node took and the longest gap between /diagnostics messages meanwhile.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=["after", "before", "sliced"])
    parser.add_argument("--domain", type=int, default=77)
    parser.add_argument("--no-yield", action="store_true", help="no sleep between ICP slices (ICP_YIELD_S = 0)")
    args = parser.parse_args()
    mode, domain = args.mode, args.domain

    import ros2_mos.core.odometry as odometry
    import ros2_mos.core.pipeline as pipeline

    if mode in ("before", "sliced"):
        pipeline.implausible_message = lambda image: None
    if args.no_yield:
        odometry.ICP_YIELD_S = 0.0
    if mode == "before":  # one call of up to 500 iterations, as kiss_icp's own align_points_to_map
        odometry.ICP_FIRST_SLICE = 500
    sys.path[:0] = [str(ROOT / "test" / "integration"), str(ROOT / "test")]  # the harness imports test/scenes.py
    from ros_harness import BASE_STAMP, TYPES, cloud, running_harness

    from ros2_mos.sim import SequenceSimulator

    sim = SequenceSimulator(4, "benchmark", seed=5, sensor="hdl64")
    scans = [sim.scan(k).scan.points for k in range(4)]
    rng = np.random.default_rng(0)
    scattered = [rng.uniform(-50, 50, (127_000, 3)).astype(np.float32) for _ in range(2)]
    clouds = [("scan", scans[0]), ("scan", scans[1]), ("scan", scans[2]), ("random", scattered[0]),
              ("random", scattered[1]), ("scan", scans[3])]
    with running_harness(domain, {"diagnostics_period": 1.0}) as h:
        arrivals: list[float] = []
        h.peer.create_subscription(TYPES.diagnostic_array, "/diagnostics",
                                   lambda msg: arrivals.append(time.monotonic()), 10)
        time.sleep(1.5)
        for i, (kind, points) in enumerate(clouds):
            start = time.monotonic()
            h.feed(cloud(BASE_STAMP + i * 100_000_000, points), timeout=300)
            end = time.monotonic()
            gap = np.diff([start, *[t for t in arrivals if start <= t <= end], end]).max()
            s = h.node.stats.snapshot()
            print(f"{mode}: {kind:6s} handled in {end - start:6.2f} s; longest gap between /diagnostics meanwhile "
                  f"{gap:5.2f} s; processed {s.processed}, skipped {dict(s.skipped)}", flush=True)
        time.sleep(1.2)
        print(f"{mode}: longest gap between /diagnostics over the run: {np.diff(arrivals).max():.2f} s "
              f"({len(arrivals)} messages)")


if __name__ == "__main__":
    main()
