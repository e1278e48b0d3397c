"""How long KISS-ICP's registration takes in the pipeline, sliced and in one call (benchmarks/design_figures.md).

    python benchmarks/odometry_profile.py [--scans 40] [--preset benchmark] [--seed 5]

Simulates a drive, registers every scan with :class:`~ros2_mos.core.odometry.KissIcpOdometry` twice (the shipped
slices, and one call of up to 500 iterations), and prints the median milliseconds per scan after 5 warm-up scans,
how many slices the scans took, and the ICP iterations and milliseconds per iteration of one scan.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import ros2_mos.core.odometry as odometry_module
from ros2_mos.core.config import OdometryConfig
from ros2_mos.core.odometry import KissIcpOdometry
from ros2_mos.sim import SequenceSimulator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=40)
    parser.add_argument("--preset", default="benchmark")
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()
    scans = [item.scan.points.astype(np.float32) for item in SequenceSimulator(args.scans, args.preset, seed=args.seed)]
    shipped = odometry_module.ICP_FIRST_SLICE
    for label, first in (("sliced", shipped), ("one call", 500)):
        odometry_module.ICP_FIRST_SLICE = first
        odometry = KissIcpOdometry(OdometryConfig())
        times, slices = [], []
        for points in scans:
            start = time.perf_counter()
            odometry.register(points)
            times.append((time.perf_counter() - start) * 1e3)
            slices.append(len(odometry.last_slice_seconds))
        counts = {int(k): int(n) for k, n in zip(*np.unique(slices[5:], return_counts=True))}
        print(f"{label}: median {statistics.median(times[5:]):.1f} ms per scan over {len(times) - 5} scans; "
              f"scans per number of slices {counts}")
    odometry_module.ICP_FIRST_SLICE = shipped
    _iterations(scans)


def _iterations(scans: list[np.ndarray]) -> None:
    """ICP iterations and ms per iteration of the scan after the first twelve."""
    from kiss_icp.pybind import kiss_icp_pybind

    odometry = KissIcpOdometry(OdometryConfig())
    for points in scans[:12]:
        odometry.register(points)
    kiss = odometry._kiss
    frame = kiss.preprocessor.preprocess(np.asarray(scans[12][:: odometry.config.point_stride], np.float64),
                                         np.array([]), kiss.last_delta)
    source, _ = kiss.voxelize(frame)
    sigma = kiss.adaptive_threshold.get_threshold()
    pose = kiss.last_pose @ kiss.last_delta
    one = kiss_icp_pybind._Registration(max_num_iterations=1, max_num_threads=0, convergence_criterion=1e-4)
    points = kiss_icp_pybind._Vector3dVector(source)
    iterations, start = 0, time.perf_counter()
    while iterations < 500:
        new = one._align_points_to_map(points=points, voxel_map=kiss.local_map._internal_map, initial_guess=pose,
                                       max_correspondance_distance=3 * sigma, kernel=sigma)
        iterations += 1
        if odometry_module._step(pose, new) < 1e-4:
            break
        pose = new
    print(f"one scan: {iterations} ICP iterations, {(time.perf_counter() - start) * 1e3 / iterations:.2f} ms each, "
          f"{len(source)} source points")


if __name__ == "__main__":
    main()
