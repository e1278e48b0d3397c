"""Issue 31: would overlapping consecutive scans' stages on the two cores make the pipeline faster?

    python benchmarks/stage_overlap.py [--data data/bench] [--scans 45]

Two measurements on the bench drive (simulated by ``ros2-mos bench`` into ``--data``), one scan at a time:

1. Per stage of :class:`~ros2_mos.core.pipeline.MosPipeline`: median wall ms and median CPU ms (this process, every
   thread), and their ratio (how many cores the stage keeps busy). Their sum is the CPU time one scan costs: on
   2 cores no schedule of the stages labels scans faster than half of it.
2. The two largest stages, KISS-ICP (``odometry``) of scan t+1 and the network (``inference``) of scan t: their wall
   time one after the other, and both started together on two threads (what a two-stage pipeline would run), with
   ONNX Runtime on its default threads and on one thread.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from pathlib import Path

import numpy as np

import ros2_mos.core.pipeline as pipeline_module
from ros2_mos.core.config import MosConfig
from ros2_mos.core.inference import MosModel
from ros2_mos.core.odometry import KissIcpOdometry
from ros2_mos.core.pipeline import MosPipeline
from ros2_mos.io.semantic_kitti import SemanticKittiSequence

WARM_UP = 5


def stage_costs(scans: list[np.ndarray]) -> dict[str, tuple[float, float]]:
    """Stage -> (median wall ms, median CPU ms) over ``scans`` after the warm-up."""
    cpu: dict[str, list[float]] = {}
    wall: dict[str, list[float]] = {}

    class CpuStopwatch(pipeline_module._Stopwatch):
        def __init__(self) -> None:
            super().__init__()
            self._cpu = time.process_time()
            self.cpu_timings: dict[str, float] = {}

        def lap(self, stage: str) -> None:
            super().lap(stage)
            now = time.process_time()
            self.cpu_timings[stage] = self.cpu_timings.get(stage, 0.0) + (now - self._cpu) * 1e3
            self._cpu = now

    watches: list[CpuStopwatch] = []

    def make() -> CpuStopwatch:
        watches.append(CpuStopwatch())
        return watches[-1]

    original = pipeline_module._Stopwatch
    pipeline_module._Stopwatch = make  # type: ignore[assignment,misc]
    try:
        pipe = MosPipeline()
        for k, scan in enumerate(scans):
            result = pipe.process(scan[:, :3], scan[:, 3], 0.1 * k)
            if k >= WARM_UP:
                for stage, ms in result.timings.items():
                    wall.setdefault(stage, []).append(ms)
                for stage, ms in watches[-1].cpu_timings.items():
                    cpu.setdefault(stage, []).append(ms)
        pipe.close()
    finally:
        pipeline_module._Stopwatch = original  # type: ignore[misc]
    return {s: (float(np.median(wall[s])), float(np.median(cpu.get(s, [np.nan])))) for s in wall}


def overlap(scans: list[np.ndarray], model_path: Path, network_input: np.ndarray,
            ort_threads: int) -> tuple[float, float, float, float]:
    """Median ms of odometry, inference, the two in sequence, and the two started together on two threads."""
    model = MosModel(model_path, intra_op_threads=ort_threads)
    odometry = KissIcpOdometry(MosConfig().odometry)  # the pipeline's default settings
    half = len(scans) // 2
    for scan in scans[:WARM_UP]:
        odometry.register(scan[:, :3])
        model.predict(network_input)
    one_after_other = []
    for scan in scans[WARM_UP:half]:
        t0 = time.perf_counter()
        odometry.register(scan[:, :3])
        t1 = time.perf_counter()
        model.predict(network_input)
        one_after_other.append((t1 - t0, time.perf_counter() - t1))
    together = []
    for scan in scans[half:]:
        t0 = time.perf_counter()
        worker = threading.Thread(target=model.predict, args=(network_input,))
        worker.start()
        odometry.register(scan[:, :3])
        worker.join()
        together.append(time.perf_counter() - t0)
    seq = np.array(one_after_other) * 1e3
    return (float(np.median(seq[:, 0])), float(np.median(seq[:, 1])), float(np.median(seq.sum(1))),
            float(np.median(together)) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("data/bench"))
    parser.add_argument("--scans", type=int, default=45)
    args = parser.parse_args()
    from ros2_mos.cli.bench_command import BENCH_SEED, BENCH_SEQUENCE
    from ros2_mos.cli.demo_command import ensure_sequence

    folder, _ = ensure_sequence(args.data, BENCH_SEQUENCE, args.scans + WARM_UP, BENCH_SEED, sensor="hdl64")
    sequence = SemanticKittiSequence(folder)
    scans = [np.column_stack([f.points, f.remission]).astype(np.float32)
             for _, f in zip(range(args.scans + WARM_UP), sequence)]
    print(f"# stage overlap, {time.strftime('%Y-%m-%d')}: {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f}, {args.scans} scans of {folder}\n")
    costs = stage_costs(scans)
    print("| stage | wall ms (median) | CPU ms (median) | cores busy |")
    print("|---|---:|---:|---:|")
    for stage, (wall, cpu) in costs.items():
        if stage != "total":
            print(f"| {stage} | {wall:.1f} | {cpu:.1f} | {cpu / max(wall, 1e-6):.2f} |")
    cpu_sum = sum(c for s, (_, c) in costs.items() if s != "total")
    print(f"| **one scan** | **{costs['total'][0]:.1f}** | **{cpu_sum:.1f}** (sum of the medians) | "
          f"{cpu_sum / costs['total'][0]:.2f} |")
    cores = os.cpu_count() or 1
    print(f"\nOn {cores} cores no schedule labels a scan in less than {cpu_sum / cores:.1f} ms on average "
          "(CPU ms / cores).\n")

    captured: dict[str, np.ndarray] = {}
    pipe = MosPipeline()
    predict = pipe.model.predict
    pipe.model.predict = lambda x: (captured.__setitem__("input", x.copy()), predict(x))[1]  # type: ignore[method-assign]
    for k, scan in enumerate(scans[:WARM_UP + 3]):
        pipe.process(scan[:, :3], scan[:, 3], 0.1 * k)
    pipe.close()
    print("| ONNX Runtime threads | odometry ms | inference ms | one after the other ms | on two threads at once ms |"
          " gain |")
    print("|---|---:|---:|---:|---:|---:|")
    for threads in (0, 1):
        odo, inf, seq, both = overlap(scans, pipe.model.path, captured["input"], threads)
        print(f"| {threads or 'default'} | {odo:.1f} | {inf:.1f} | {seq:.1f} | {both:.1f} | {seq / both:.2f}x |")


if __name__ == "__main__":
    main()
