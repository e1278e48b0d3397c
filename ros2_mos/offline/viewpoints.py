"""The pose of one scan seen from another: KISS-ICP's relative pose refined by registering the two scans.

Visibility (:mod:`~ros2_mos.offline.visibility`) asks whether scan j saw through the place a point of scan k lies
at. It needs scan j's pose relative to scan k, and KISS-ICP's drifts over seconds: on the simulated VLP-32C drive
benchmark-9102 (a terrain wave, which KISS-ICP follows with a pitch error of up to 4 degrees) its poses of scans 40
apart are 0.34 m off on average and 1.1 m at worst, and parked cars 7 m away are "seen through" by scans 20-40
away. Scans ``from_offset`` or more apart are therefore registered once more, one against the other: scan j's
points (thinned, :meth:`PairRegistrationConfig.source_voxel_for`) against a voxel map of all of scan k's, starting
from KISS-ICP's relative pose (KISS-ICP's own point-to-point ICP with its robust kernel). The refined pose serves the
pair both ways (scan k seen from j, and j from k). A refinement that moves the pose farther than ``max_shift``
metres or ``max_turn`` degrees, or that has too few points to hold it, is refused: KISS-ICP's pose stays.
Registering only the points on no object (so that a car alongside cannot pull one scan onto the other) was measured
and is worse (``benchmarks/autolabel.md``, round 28).

The pairs of a drive are registered as its scans arrive (:meth:`PairRegistration.add`): scan a against the later
scans it is paired with, once the last of them has arrived. :class:`PairRegistrationProcess` does that in a process
of its own, which runs ahead of the labelling while the labelling's Python runs on the other core (KISS-ICP's
alignment holds the GIL, so a thread would not). It registers on one thread (``threads``), so that its poses do not
depend on the order in which threads add up their sums.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ros2_mos.apps.kitti_metrics import rotation_angles
from ros2_mos.core.errors import ConfigError
from ros2_mos.core.worker import Worker
from ros2_mos.offline.objects import check_numbers


@dataclass(frozen=True)
class PairRegistrationConfig:
    #: Scans this many apart or more are registered to each other (0: none; scans nearer than this keep KISS-ICP's
    #: relative pose, which drifts little over a few scans).
    from_offset: int = 5
    voxel: float = 1.0  # m: the map's voxel
    #: m: the registered scan of a sensor with ``dense_rows`` rows or more is thinned to one point per voxel of this
    #: size (as KISS-ICP thins its source: 1.5 map voxels), a sparser sensor's to one per map ``voxel``: on a
    #: 64-beam drive the pairs take 40 % less time, their poses a few millimetres farther from the truth; a 16-beam
    #: scan thinned so far holds them worse (benchmarks/autolabel.md, round 44)
    source_voxel: float = 1.5
    dense_rows: int = 64
    max_correspondence: float = 2.0  # m: farther pairs of points are not matched
    kernel: float = 0.3  # m: the robust (Geman-McClure) kernel's scale
    #: ICP stops at this many iterations, or where a step moves the pose less than ``convergence`` (the norm of
    #: KISS-ICP's twist; 1e-3 as the online odometry's): most pairs stop within a few iterations, while a pair that
    #: KISS-ICP left far apart (a terrain wave) gets the iterations it needs (benchmarks/autolabel.md, round 31)
    iterations: int = 80
    convergence: float = 1e-3
    max_shift: float = 1.5  # m
    max_turn: float = 5.0  # degrees
    min_points: int = 100  # thinned points of either scan below which a pair is not registered
    #: points a voxel of the map keeps (as in KISS-ICP's own map; 5 is faster and lost on simulated jams:
    #: benchmarks/autolabel.md, round 28)
    map_points: int = 20
    #: KISS-ICP's threads for each pair (0: every core): on several its sums add up in an order that varies with the
    #: machine's load, and a drive labelled twice got other poses (benchmarks/autolabel.md, round 51). Two processes
    #: of one thread each, every other scan's pairs in each, were no faster than one on a 64-beam drive.
    threads: int = 1

    def __post_init__(self) -> None:
        check_numbers(self, "pair registration", zero_ok=("from_offset", "min_points", "threads"),
                      whole=("from_offset", "iterations", "min_points", "map_points", "dense_rows", "threads"))

    def source_voxel_for(self, rows: int) -> float:
        """The voxel (m) the registered scans of a sensor with ``rows`` rows are thinned with."""
        return self.source_voxel if rows >= self.dense_rows else self.voxel


def pose_change(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Metres and degrees between two 4x4 poses."""
    delta = np.linalg.inv(a) @ b
    return float(np.linalg.norm(delta[:3, 3])), math.degrees(float(rotation_angles(delta[:3, :3])))


class PairRegistration:
    """Refined relative poses of the scan pairs a sliding window asks for; built once per drive.

    ``offsets``: the scan offsets the window looks at (the pairs a, a + o for each positive one that :meth:`wants`
    are registered as the scans arrive, :meth:`add`); ``scans``: the drive's length; ``rows``: the sensor's rows
    (:meth:`PairRegistrationConfig.source_voxel_for`).
    """

    def __init__(self, config: PairRegistrationConfig = PairRegistrationConfig(), offsets: tuple[int, ...] = (),
                 scans: int = 0, rows: int = 64) -> None:
        from kiss_icp.registration import Registration

        self.config = config
        self.source_voxel = config.source_voxel_for(rows)
        self._registration = Registration(max_num_iterations=config.iterations,
                                          convergence_criterion=config.convergence, max_num_threads=config.threads)
        #: (a, b) with a < b: scan b's pose in scan a's frame
        self._relative: dict[tuple[int, int], np.ndarray] = {}
        self._thinned: dict[int, np.ndarray] = {}  # scan -> its points thinned to one per source voxel
        self.refused = 0
        self.registered = 0
        self._later = sorted({o for o in offsets if o > 0 and self.wants(o)})  # the offsets of a's later scans
        self._scans = scans
        self._arrived: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # scan -> (points, pose) until registered
        self._next = 0  # the next scan to register against its later ones

    def wants(self, offset: int) -> bool:
        """Whether a pair this many scans apart is registered."""
        return self.config.from_offset > 0 and abs(offset) >= self.config.from_offset

    @classmethod
    def for_drive(cls, config: PairRegistrationConfig, offsets: tuple[int, ...], scans: int, rows: int,
                  own_process: bool) -> "PairRegistration":
        """The registration of a drive of ``scans`` scans by a sensor of ``rows`` rows: with ``own_process`` in a
        process of its own (:class:`PairRegistrationProcess`) where some pair is registered at all, else here."""
        here = cls(config, offsets, scans, rows)
        return PairRegistrationProcess(config, offsets, scans, rows) if own_process and here._later else here

    def add(self, index: int, points: np.ndarray, pose: np.ndarray) -> list[int]:
        """Scan ``index`` (the next of the drive: sensor-frame (N, 3) points, KISS-ICP world pose) has arrived;
        register each earlier scan whose later scans have all arrived now. Returns those scans."""
        if index != self._next + len(self._arrived):
            raise ConfigError(f"pair registration: scan {index} arrived out of order")
        self._arrived[index] = (points, pose)
        reach = self._later[-1] if self._later else 0
        done = []
        while self._next < self._scans and (self._next + reach <= index or index == self._scans - 1):
            a = self._next
            points_a, pose_a = self._arrived.pop(a)
            self.register(a, points_a, pose_a, [(a + o, *self._arrived[a + o]) for o in self._later
                                                if a + o < self._scans])
            done.append(a)
            self._next += 1
        return done

    def wait_for(self, k: int) -> None:
        """Return once the pairs of scan ``k`` with its later scans are known (here: :meth:`add` registered them)."""
        if k >= self._next:
            raise ConfigError(f"pair registration: scan {k}'s later scans have not all arrived")

    def close(self) -> None:
        """Nothing to stop here (:class:`PairRegistrationProcess` stops its process)."""

    def register(self, a: int, points_a: np.ndarray, pose_a: np.ndarray,
                 later: list[tuple[int, np.ndarray, np.ndarray]]) -> dict[tuple[int, int], np.ndarray]:
        """Register each later scan (index, sensor-frame (N, 3) points, KISS-ICP world pose) against scan ``a``, in
        one voxel map of scan a's points; keep each pair's relative pose (KISS-ICP's where the refinement is
        refused) and return them."""
        from kiss_icp.mapping import VoxelHashMap
        from kiss_icp.voxelization import voxel_down_sample

        cfg = self.config
        self._thinned.pop(a, None)  # scans are registered in order: scan a is never a later scan again
        if not later:
            return {}
        voxel_map = None
        if len(points_a) >= cfg.min_points:
            voxel_map = VoxelHashMap(voxel_size=cfg.voxel, max_distance=1e9, max_points_per_voxel=cfg.map_points)
            voxel_map.add_points(np.asarray(points_a, np.float64))
        inverse_a = np.linalg.inv(pose_a)
        for b, points_b, pose_b in later:
            if b <= a:
                raise ConfigError(f"pair registration: scan {b} is not later than scan {a}")
            start = inverse_a @ pose_b
            relative = start
            if b not in self._thinned:  # scan b is registered against up to len(offsets) earlier scans
                self._thinned[b] = voxel_down_sample(np.asarray(points_b, np.float64), self.source_voxel)
            source = self._thinned[b]
            if voxel_map is not None and len(source) >= cfg.min_points:
                refined = self._registration.align_points_to_map(source, voxel_map, start, cfg.max_correspondence,
                                                                 cfg.kernel)
                shift, turn = pose_change(start, refined)
                if np.all(np.isfinite(refined)) and shift <= cfg.max_shift and turn <= cfg.max_turn:
                    relative = refined
            self.registered += relative is not start
            self.refused += relative is start
            self._relative[(a, b)] = relative
        return {(a, b): self._relative[(a, b)] for b, _, _ in later}

    def viewpoint_pose(self, k: int, pose_k: np.ndarray, j: int) -> np.ndarray | None:
        """Scan j's world pose as a viewpoint of scan k's points (scan k at ``pose_k``), or None where the pair was
        not registered."""
        if j > k:
            relative = self._relative.get((k, j))
            return None if relative is None else pose_k @ relative
        relative = self._relative.get((j, k))
        return None if relative is None else pose_k @ np.linalg.inv(relative)

    def forget_before(self, k: int) -> None:
        """Drop the pairs whose first scan is before ``k`` (out of the window)."""
        for pair in [p for p in self._relative if p[0] < k]:
            del self._relative[pair]


class PairRegistrationProcess(PairRegistration):
    """:class:`PairRegistration` in a process of its own (:class:`~ros2_mos.core.worker.Worker`): :meth:`add` hands
    the scan over and returns at once, :meth:`wait_for` collects the pairs registered meanwhile. The process runs up
    to as many scans ahead as the caller adds before waiting; an error there is raised here, in one line."""

    def __init__(self, config: PairRegistrationConfig = PairRegistrationConfig(), offsets: tuple[int, ...] = (),
                 scans: int = 0, rows: int = 64) -> None:
        super().__init__(config, offsets, scans, rows)
        self._worker = Worker("ros2_mos.offline.viewpoints:pair_server", (config, offsets, scans, rows),
                              "pair registration")
        self._added = 0
        self._known = 0  # scans whose pairs have come back

    def add(self, index: int, points: np.ndarray, pose: np.ndarray) -> list[int]:
        if index != self._added:
            raise ConfigError(f"pair registration: scan {index} arrived out of order")
        self._added += 1
        self._worker.send((index, np.asarray(points), np.asarray(pose)))
        return []

    def wait_for(self, k: int) -> None:
        last = min(self._scans - 1, k + (self._later[-1] if self._later else 0))  # the last scan k is paired with
        if self._known <= k and last >= self._added:  # the process would wait for it as this one waits for k
            raise ConfigError(f"pair registration: scan {k}'s later scans have not all arrived")
        while self._known <= k:
            done, relative, self.registered, self.refused = self._worker.receive()
            self._relative.update(relative)
            self._known = done + 1

    def close(self) -> None:
        """Stop the process: at once where its pairs are not all back (an error, Ctrl-C: they are not needed)."""
        self._worker.close(kill=self._known < self._scans)


def pair_server(setup: tuple[PairRegistrationConfig, tuple[int, ...], int, int]) -> Callable[[Any], list[Any]]:
    """The registration process's handler (:class:`~ros2_mos.core.worker.Worker`): a scan (index, points, pose) in,
    (scan registered, its pairs, registered, refused) out for each scan it let be registered."""
    pairs = PairRegistration(*setup)

    def handle(request: tuple[int, np.ndarray, np.ndarray]) -> list[Any]:
        answers = []
        for a in pairs.add(*request):
            relative = {pair: p for pair, p in pairs._relative.items() if pair[0] == a}
            pairs.forget_before(a + 1)
            answers.append((a, relative, pairs.registered, pairs.refused))
        return answers

    return handle
