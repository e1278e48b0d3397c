"""Issue 32 ("also seen"): does the pipeline's memory flatten over a long run, as `infer` uses it?

    python benchmarks/infer_rss.py SEQUENCE_DIR --scans 1500 [--model M.onnx] [--every 100]

Feeds the sequence's scans to one MosPipeline in a loop (stamps kept increasing; each loop's jump back in space is a
pose jump the pipeline recovers from, as after a relocalisation) and prints the process's resident memory (VmRSS,
/proc/self/status) every ``--every`` scans, then the growth between the first printed sample after warm-up and the end.
"""

from __future__ import annotations

import argparse
import gc
from pathlib import Path


def rss_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def main() -> None:
    from ros2_mos.core.config import MosConfig
    from ros2_mos.core.pipeline import MosPipeline
    from ros2_mos.io.semantic_kitti import SemanticKittiSequence

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--scans", type=int, default=1500)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--model", type=Path)
    args = parser.parse_args()
    seq = SemanticKittiSequence(args.sequence)
    frames = [seq[i] for i in range(len(seq))]
    pipe = MosPipeline(MosConfig(model=str(args.model)) if args.model else MosConfig())
    samples = []
    for k in range(args.scans):
        frame = frames[k % len(frames)]
        pipe.process(frame.points, frame.remission, 0.1 * k)
        if (k + 1) % args.every == 0:
            gc.collect()
            samples.append((k + 1, rss_mb()))
            print(f"scan {k + 1:>6}: RSS {samples[-1][1]:8.1f} MB", flush=True)
    base = samples[min(2, len(samples) - 1)]
    print(f"growth from scan {base[0]} to {samples[-1][0]}: {samples[-1][1] - base[1]:+.1f} MB "
          f"({(samples[-1][1] - base[1]) / max(samples[-1][0] - base[0], 1) * 1000:+.1f} MB per 1000 scans)")


if __name__ == "__main__":
    main()
