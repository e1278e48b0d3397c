"""Same-run A/B of pipeline settings: configurations interleaved, each run in a fresh process.

    python benchmarks/ab_pipeline.py --config base: --config ort1:intra_op_threads=1 [--reps 3] [--scans 30]
    python benchmarks/ab_pipeline.py --config base: --config icp1:@icp_threads=1,@env:OMP_NUM_THREADS=1

A configuration is ``NAME:SETTING,SETTING,...``: ``key=value`` sets a node parameter (YAML value), ``@icp_threads=N``
KISS-ICP's TBB threads, ``@env:VAR=VALUE`` an environment variable of the run's process. The runs go A B A B ...
(``--reps`` rounds), each over the bench bag's clouds through :class:`~ros2_mos.ros.processor.ScanProcessor` (the
node's code, as ``ros2-mos bench``); printed: per configuration the median over all its timed scans of each stage
and of the end-to-end time, its p95, and each configuration's ratio to the first. On a shared machine only the
ratios of one invocation mean anything.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

STAGES = ("decode", "odometry", "registration", "residuals", "inference", "postprocess", "encode")


def worker(bag: str, scans: int, warmup: int, settings: list[str]) -> None:
    import yaml

    values: dict = {}
    icp_threads = None
    for s in settings:
        key, _, raw = s.partition("=")
        if key == "@icp_threads":
            icp_threads = int(raw)
        elif not key.startswith("@env:"):
            values[key] = yaml.safe_load(raw)
    if icp_threads is not None:
        import kiss_icp.config as kc

        load = kc.load_config

        def patched(*args, **kwargs):
            cfg = load(*args, **kwargs)
            cfg.registration.max_num_threads = icp_threads
            return cfg

        kc.load_config = patched
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.bags import iter_pointclouds
    from ros2_mos.ros.messages import MessageTypes
    from ros2_mos.ros.params import load_params, mos_config, node_settings
    from ros2_mos.ros.processor import ScanProcessor

    params = load_params(None, None, "hdl64")
    params.update(values)
    pipeline = MosPipeline(mos_config(params))
    processor = ScanProcessor(pipeline, node_settings(params), MessageTypes.rosbags())
    out = []
    for i, (_, msg) in enumerate(iter_pointclouds(bag)):
        if i >= scans + warmup:
            break
        timings = processor.process(msg).timings
        if i >= warmup:
            out.append(timings)
    print(json.dumps(out))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", action="append", required=True, help="NAME:SETTING,SETTING,... (see above)")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--scans", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--bag", default="data/bench/bags/bench")
    parser.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        worker(args.bag, args.scans, args.warmup, args.worker)
        return
    configs = []
    for spec in args.config:
        name, _, rest = spec.partition(":")
        configs.append((name, [s for s in rest.split(",") if s]))
    runs: dict[str, list[list[dict]]] = {name: [] for name, _ in configs}
    for rep in range(args.reps):
        for name, settings in configs:
            env = dict(os.environ)
            for s in settings:
                if s.startswith("@env:"):
                    key, _, value = s[5:].partition("=")
                    env[key] = value
            cmd = [sys.executable, __file__, "--bag", args.bag, "--scans", str(args.scans), "--warmup",
                   str(args.warmup), "--config", "x:", "--worker", *settings]
            res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
            timings = json.loads(res.stdout.strip().splitlines()[-1])
            runs[name].append(timings)
            total = np.median([t["total"] for t in timings])
            print(f"rep {rep + 1} {name}: total median {total:.1f} ms", file=sys.stderr, flush=True)
    print(f"{args.reps} rounds of {args.scans} scans per configuration, interleaved; load average "
          f"{os.getloadavg()[0]:.1f}")
    head = "| config | " + " | ".join(STAGES) + " | total median | total p95 | per-run medians | ratio to first |"
    print(head)
    print("|---" * (len(STAGES) + 5) + "|")
    first = None
    for name, _ in configs:
        pooled = [t for run in runs[name] for t in run]
        total = float(np.median([t["total"] for t in pooled]))
        first = first or total
        cells = [f"{np.median([t.get(s, 0.0) for t in pooled]):.1f}" for s in STAGES]
        per_run = "/".join(f"{np.median([t['total'] for t in run]):.0f}" for run in runs[name])
        p95 = float(np.percentile([t["total"] for t in pooled], 95))
        print(f"| {name} | " + " | ".join(cells) + f" | {total:.1f} | {p95:.1f} | {per_run} | {total / first:.2f} |")


if __name__ == "__main__":
    main()
