"""ONNX Runtime latency of exported MOS models on this CPU (median / p95 of 20 runs after 3 warm-ups).

    python benchmarks/cnn_latency.py ros2_mos/models/default.onnx [more.onnx ...] [--threads 2]

Only the CNN: the input is random (1, C, H, W) of the model's own shape.  The whole
pipeline is timed by ``ros2-mos bench``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import onnxruntime as ort


def measure(path: str, threads: int, runs: int = 20) -> tuple[float, float]:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    session = ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])
    shape = session.get_inputs()[0].shape
    x = np.random.default_rng(0).standard_normal(shape).astype(np.float32)
    for _ in range(3):
        session.run(None, {"input": x})
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        session.run(None, {"input": x})
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times)), float(np.percentile(times, 95))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    for path in args.models:
        median, p95 = measure(path, args.threads)
        print(f"{path}: median {median:.1f} ms, p95 {p95:.1f} ms ({args.threads} threads)")


if __name__ == "__main__":
    main()
