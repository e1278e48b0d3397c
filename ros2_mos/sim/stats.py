"""Statistics of simulated sequences, to compare a preset with SemanticKITTI.

Counted from what the scans contain (labels), not from what the world holds:
an object counts as moving when some of its points carry a moving label, a
parked car when some of its points were seen at all.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ros2_mos.io.labels import MOVING_IDS
from ros2_mos.sim.lidar import LidarScan
from ros2_mos.sim.traffic import Agent

_MOVING_IDS = np.array(MOVING_IDS)


@dataclass
class SequenceStats:
    """What one simulated sequence contains."""

    name: str
    n_scans: int = 0
    points: list[int] = field(default_factory=list)
    moving_points: list[int] = field(default_factory=list)
    moving_objects: dict[str, set[int]] = field(default_factory=dict)
    parked_cars: set[int] = field(default_factory=set)
    standing_objects: set[int] = field(default_factory=set)
    speeds: dict[str, list[float]] = field(default_factory=dict)
    ego_speeds: list[float] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def moving_fraction(self) -> float:
        """Moving points over all points of the sequence."""
        total = sum(self.points)
        return sum(self.moving_points) / total if total else 0.0

    @property
    def ego_standing_scans(self) -> int:
        return int(np.sum(np.asarray(self.ego_speeds) < 0.01))

    @property
    def n_moving_objects(self) -> int:
        return sum(len(v) for v in self.moving_objects.values())

    def add_scan(self, scan: LidarScan, agents_by_inst: dict[int, Agent], parked: set[int], k: int,
                 ego_speed: float, period: float) -> None:
        """Account for scan k: its points, which objects it saw moving, their speeds."""
        self.n_scans += 1
        self.points.append(len(scan.points))
        moving = np.isin(scan.sem, _MOVING_IDS)
        self.moving_points.append(int(moving.sum()))
        self.ego_speeds.append(ego_speed)
        seen = np.unique(scan.inst[scan.inst > 0])
        seen_moving = set(np.unique(scan.inst[moving]).tolist())
        for inst in seen.tolist():
            if inst in parked:
                self.parked_cars.add(inst)
                continue
            agent = agents_by_inst.get(inst)
            if agent is None:
                continue
            if inst in seen_moving:
                self.moving_objects.setdefault(agent.kind.name, set()).add(inst)
                self.speeds.setdefault(agent.kind.name, []).append(float(agent.step[k] / period))
            elif not agent.moving.any():
                self.standing_objects.add(inst)


def _quantiles(values: list[float]) -> str:
    if not values:
        return "-"
    q = np.percentile(values, [5, 25, 50, 75, 95])
    return " / ".join(f"{v:.1f}" for v in q)


def format_stats(stats: list[SequenceStats]) -> str:
    """A short plain-text report of one or more sequences and their total."""
    lines = []
    rows = list(stats)
    if len(rows) > 1:
        total = SequenceStats("all")
        for s in rows:
            total.n_scans += s.n_scans
            total.points += s.points
            total.moving_points += s.moving_points
            for kind, ids in s.moving_objects.items():
                total.moving_objects.setdefault(kind, set()).update((s.name, i) for i in ids)  # type: ignore[misc]
            total.parked_cars.update((s.name, i) for i in s.parked_cars)  # type: ignore[misc]
            total.standing_objects.update((s.name, i) for i in s.standing_objects)  # type: ignore[misc]
            for kind, v in s.speeds.items():
                total.speeds.setdefault(kind, []).extend(v)
            total.ego_speeds += s.ego_speeds
            total.seconds += s.seconds
        rows.append(total)
    for s in rows:
        pts = np.asarray(s.points) if s.points else np.zeros(1)
        frac = np.asarray(s.moving_points) / np.maximum(pts, 1)
        lines.append(f"sequence {s.name}: {s.n_scans} scans"
                     + (f", {s.n_scans / s.seconds:.1f} scans/s" if s.seconds > 0 else ""))
        lines.append(f"  points/scan        mean {pts.mean():.0f}  min {pts.min():.0f}  max {pts.max():.0f}")
        lines.append(f"  moving points      {100 * s.moving_fraction:.2f} % overall; per scan median "
                     f"{100 * np.median(frac):.2f} %, max {100 * frac.max():.2f} %, "
                     f"{100 * np.mean(frac > 0):.0f} % of scans have some")
        kinds = ", ".join(f"{k} {len(v)}" for k, v in sorted(s.moving_objects.items())) or "none"
        lines.append(f"  objects seen       moving {s.n_moving_objects} ({kinds}); parked cars {len(s.parked_cars)}; "
                     f"standing people/vehicles {len(s.standing_objects)}")
        for kind, v in sorted(s.speeds.items()):
            slow = 100 * np.mean(np.asarray(v) < 2.0)
            lines.append(f"  speed {kind:<11}  m/s p5/p25/p50/p75/p95 {_quantiles(v)}  "
                         f"({slow:.0f} % of sightings < 2 m/s)")
        ego = np.asarray(s.ego_speeds) if s.ego_speeds else np.zeros(1)
        lines.append(f"  ego                mean {ego.mean():.1f} m/s, max {ego.max():.1f} m/s, "
                     f"standing still in {100 * np.mean(ego < 0.01):.0f} % of scans")
    return "\n".join(lines)
