"""The ego vehicle and the traffic around it: trajectories over the scan times, never overlapping.

Lanes along the ego route are filled by *columns* (copies of one speed profile,
each shifted by a headway in time and a car length plus gap in space), so cars
in one lane queue at the same stops and never run into each other or into the
ego vehicle.  Independent participants (cross traffic on other streets, slow
cars, cyclists, pedestrians) are drawn at random and rejected when their
collision circles would overlap anyone accepted before at any scan time, or when
they never come within sensor range.

An agent is *moving* at scan k when its pose changed since scan k-1 (more than
:data:`EPS_MOVE` metres or :data:`EPS_YAW` radians): the ``instant`` convention, in
which a car waiting at a light is static while it waits.  Under SemanticKITTI's
convention (:mod:`ros2_mos.io.conventions`) an agent that moves at any scan while it
is within the sensor's range is moving in every scan of the drive
(:meth:`Traffic.observed_movers`, :func:`relabel_movers`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ros2_mos.sim import objects as ob
from ros2_mos.sim.geometry import TriangleSoup, place
from ros2_mos.sim.motion import SpeedProfile, Stop, random_stops, simulate_profile
from ros2_mos.sim.presets import SimPreset
from ros2_mos.sim.road import Path, random_route
from ros2_mos.sim.scene import Ground

EPS_MOVE = 1e-3
EPS_YAW = 1e-4
# Seconds of simulated history before the first scan and after the last one,
# so that time-shifted columns and agents are already under way.
_PRE, _POST = 15.0, 15.0
_MAX_COLUMN = 400


@dataclass
class Ego:
    """The ego vehicle: its lane of the route driven with a speed profile; s = s_start + profile(t).

    ``route`` is the street centre line the other participants' lanes are offsets of,
    ``path`` the ego lane (its own arc length); ``s_start`` is where the ego vehicle
    was on it when its profile began, before the first scan.
    """

    route: Path
    path: Path
    s_start: float
    profile: SpeedProfile

    def s_at(self, t: np.ndarray | float) -> np.ndarray:
        return self.s_start + self.profile.at(t)

    def pose_at(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground pose (x, y, yaw) of the ego vehicle at times ``t``."""
        return self.path.pose(self.s_at(t))

    def route_s_at(self, t: np.ndarray | float) -> np.ndarray:
        """Where the ego vehicle is at times ``t``, as arc length of the centre line."""
        return np.interp(self.s_at(t), self.path.s, self.route.s)


@dataclass
class Agent:
    """One traffic participant's shape and its poses at the times t_{-1}, t_0, ..., t_{n-1}."""

    kind: ob.ObjectKind
    inst: int
    tris: np.ndarray
    remission: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    role: str = ""
    z: np.ndarray | None = None  # ground height under the agent; None: 0

    @property
    def step(self) -> np.ndarray:
        """Displacement (m) between consecutive scans, one per scan."""
        return np.hypot(np.diff(self.x), np.diff(self.y))

    @property
    def moving(self) -> np.ndarray:
        """Per scan: did the pose change since the previous scan (the MOS ground truth)?"""
        dyaw = np.abs(np.angle(np.exp(1j * np.diff(self.yaw))))
        return (self.step > EPS_MOVE) | (dyaw > EPS_YAW)

    def circles(self) -> np.ndarray:
        """Collision circle centres (times, C, 2)."""
        off = np.asarray(self.kind.circle_offsets)
        cx = self.x[:, None] + np.cos(self.yaw)[:, None] * off[None]
        cy = self.y[:, None] + np.sin(self.yaw)[:, None] * off[None]
        return np.stack([cx, cy], axis=-1)

    def soup(self, i: int) -> TriangleSoup:
        """Triangles at pose index ``i`` (scan k is i = k + 1), labelled moving or static for that scan."""
        moving = i > 0 and bool(self.moving[i - 1])
        z = 0.0 if self.z is None else self.z[i]
        tris = place(self.tris, self.x[i], self.y[i], self.yaw[i], z)[0]
        sem = self.kind.moving_id if moving else self.kind.static_id
        soup = TriangleSoup.labelled(tris, sem, self.inst)
        soup.remission[:] = self.remission
        return soup


@dataclass
class Traffic:
    """The ego vehicle and all accepted agents of a sequence."""

    ego: Ego
    times: np.ndarray  # t_{-1}, t_0, ..., t_{n-1}
    agents: list[Agent] = field(default_factory=list)
    ego_x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ego_y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ego_yaw: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def dynamic_soup(self, k: int, reach: float) -> TriangleSoup:
        """All agents within ``reach`` of the ego vehicle at scan k, labelled for that scan."""
        i = k + 1
        parts = [
            a.soup(i) for a in self.agents
            if (a.x[i] - self.ego_x[i]) ** 2 + (a.y[i] - self.ego_y[i]) ** 2 < reach**2
        ]
        return TriangleSoup.concat(parts)

    def observed_movers(self, reach: float) -> dict[int, int]:
        """{instance: moving id} of the agents that move at some scan while within ``reach`` of the sensor.

        SemanticKITTI's convention labels these moving in every scan in which they are seen, also while they wait.
        """
        ego_x, ego_y = self.ego_x[1:], self.ego_y[1:]
        movers = {}
        for a in self.agents:
            in_range = (a.x[1:] - ego_x) ** 2 + (a.y[1:] - ego_y) ** 2 < reach**2
            if (a.moving & in_range).any():
                movers[a.inst] = a.kind.moving_id
        return movers


def relabel_movers(labels: np.ndarray, movers: dict[int, int]) -> np.ndarray:
    """SemanticKITTI uint32 labels with every point of an instance in ``movers`` given that instance's moving id."""
    labels = np.asarray(labels, np.uint32)
    if not movers:
        return labels.copy()
    inst = labels >> np.uint32(16)
    lookup = np.zeros(max(movers) + 1, np.uint32)
    lookup[list(movers)] = list(movers.values())
    new_sem = lookup[np.minimum(inst, len(lookup) - 1)] * (inst < len(lookup))
    return np.where(new_sem > 0, (inst << np.uint32(16)) | new_sem, labels).astype(np.uint32)


class _TrafficBuilder:
    """Draws candidates and keeps those that are visible and collide with nobody."""

    def __init__(self, rng: np.random.Generator, preset: SimPreset, ground: Ground, ego: Ego,
                 times: np.ndarray, reach: float, first_instance: int) -> None:
        self.rng, self.preset, self.ego, self.times, self.reach = rng, preset, ego, times, reach
        self.ground, self.grid = ground, ground.grid
        self.next_instance = first_instance
        self.accepted: list[Agent] = []
        ex, ey, eyaw = ego.pose_at(times)
        self.ego_xy = np.stack([ex, ey], axis=-1)
        ego_agent = Agent(ob.CAR_KIND, 0, np.zeros((0, 3, 3)), np.zeros(0, np.float32), ex, ey, eyaw)
        self._circles: list[tuple[np.ndarray, float]] = [(ego_agent.circles(), ob.CAR_KIND.circle_radius)]
        self.t0, self.t1 = times[0] - _PRE, times[-1] + _POST
        self._lanes: dict[float, Path] = {}

    # -- acceptance -------------------------------------------------------------------
    def visible(self, x: np.ndarray, y: np.ndarray) -> bool:
        d2 = (x - self.ego_xy[:, 0]) ** 2 + (y - self.ego_xy[:, 1]) ** 2
        return bool(d2.min() < self.reach**2)

    def collides(self, agent: Agent) -> bool:
        mine = agent.circles()
        r = agent.kind.circle_radius
        for other, r_other in self._circles:
            d = np.linalg.norm(mine[:, :, None, :] - other[:, None, :, :], axis=-1)
            if (d < r + r_other).any():
                return True
        return False

    def offer(self, kind: ob.ObjectKind, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, role: str,
              check_collisions: bool = True) -> bool:
        """Accept the candidate if it is ever in range and overlaps nobody; gives it an instance id."""
        if not self.visible(x, y):
            return False
        tris, remission = ob.SHAPES[kind.name](self.rng)
        agent = Agent(kind, self.next_instance, tris, remission, x, y, yaw, role)
        if check_collisions and self.collides(agent):
            return False
        self.next_instance += 1
        agent.z = self.ground.height(x, y)
        self.accepted.append(agent)
        self._circles.append((agent.circles(), kind.circle_radius))
        return True

    # -- helpers ----------------------------------------------------------------------
    def count(self, per_100m: float) -> int:
        """A Poisson count for a density per 100 m of the visible route."""
        ego_s = self.ego.s_at(self.times)
        length = float(ego_s[-1] - ego_s[0]) + 2.0 * self.reach
        return int(self.rng.poisson(per_100m * length / 100.0))

    def profile(self, speed: tuple[float, float], stop_and_go: bool, stop_every: tuple[float, float],
                stop_for: tuple[float, float], extra_stops: list[Stop] | None = None,
                hold_until: float | None = None,
                speed_limit: Callable[[float], float] | None = None, margin: float = 0.0) -> SpeedProfile:
        """A profile over the simulated window, widened by ``margin`` s on both sides for time-shifted copies."""
        t0, t1 = self.t0 - margin, self.t1 + margin
        cruise = float(self.rng.uniform(*speed))
        stops = list(extra_stops or [])
        if stop_and_go:
            stops += random_stops(self.rng, cruise * (t1 - t0) + 50.0, stop_every, stop_for)
        return simulate_profile(t0, t1, cruise, stops, speed_limit=speed_limit,
                                hold_until=hold_until, v0=None if hold_until is None else 0.0)

    def lane(self, lateral: float) -> Path:
        """The ego route's parallel at ``lateral`` (cached)."""
        key = round(float(lateral), 6)
        if key not in self._lanes:
            self._lanes[key] = self.ego.route.offset(key)
        return self._lanes[key]

    def along_ego_route(self, kind: ob.ObjectKind, s_route: float, travelled: np.ndarray, lateral: float,
                        direction: int, role: str, check_collisions: bool = True) -> bool:
        """Offer an agent on the route's parallel at ``lateral``: at centre-line position ``s_route`` when
        ``travelled`` is 0, moving ``travelled`` metres along its own curve in ``direction``."""
        lane = self.lane(lateral)
        s = float(np.interp(s_route, self.ego.route.s, lane.s)) + direction * travelled
        if s.min() <= 0.0 or s.max() >= lane.length:
            return False  # it would stand frozen at an end of the route: not a participant
        x, y, yaw = lane.pose(s)
        if direction < 0:
            yaw = yaw + np.pi
        return self.offer(kind, x, y, yaw, role, check_collisions)

    def random_ego_s(self) -> float:
        """The ego's centre-line position at a random scan time, where someone should be met."""
        return float(self.ego.route_s_at(self.rng.uniform(self.times[0], self.times[-1])))

    # -- participants -----------------------------------------------------------------
    def ego_lane_queue(self) -> None:
        """Cars ahead of and behind the ego vehicle in its lane: its own profile shifted in time."""
        tr = self.preset.traffic
        for sign, (lo, hi) in ((1, tr.lead_cars), (-1, tr.follow_cars)):
            n = int(self.rng.integers(lo, hi + 1))
            shift = np.cumsum(self.rng.uniform(*tr.headway, n))
            dist = np.cumsum(4.9 + self.rng.uniform(*tr.gap, n))
            for k in range(n):
                s = self.ego.s_at(self.times + sign * shift[k]) + sign * dist[k]
                x, y, yaw = self.ego.path.pose(s)
                self.offer(ob.CAR_KIND, x, y, yaw, "queue", check_collisions=False)

    def column(self, lateral: float, direction: int, speed: tuple[float, float], density: float,
               anchor_s: float, role: str, stop_and_go: bool) -> None:
        """A lane full of cars sharing one (stop-and-go) profile, kept with probability from ``density``."""
        tr = self.preset.traffic
        n = _MAX_COLUMN
        headway = self.rng.uniform(*tr.headway, n)
        kinds = np.where(self.rng.random(n) < tr.heavy_vehicle_prob, "bus", "car")
        lengths = np.array([ob.LENGTH[k] for k in kinds])
        # Slot i is this far behind slot i - 1: half of each length plus a gap (slot 0's entry is unused).
        gaps = 0.5 * (lengths + np.roll(lengths, 1)) + self.rng.uniform(*tr.gap, n)
        # Every slot's time-shifted copy must lie inside the simulated profile, or it would freeze.
        prof = self.profile(speed, stop_and_go, (30.0, 120.0), (2.0, 8.0), margin=0.5 * headway.sum() + 5.0)
        slot = float(np.mean(gaps) + np.mean(headway) * (prof.s[-1] - prof.s[0]) / (prof.t[-1] - prof.t[0]))
        keep_p = min(1.0, density * slot / 100.0)
        keep = self.rng.random(n) < keep_p
        # Slot n/2 sits at the anchor; higher slots follow it, lower ones lead it.
        shift = np.cumsum(headway) - np.cumsum(headway)[n // 2]
        dist = np.cumsum(gaps) - np.cumsum(gaps)[n // 2]
        base = prof.at(0.0)
        for i in np.nonzero(keep)[0]:
            travelled = prof.at(self.times - shift[i]) - base - dist[i]
            self.along_ego_route(ob.KINDS[str(kinds[i])], anchor_s, travelled, lateral, direction, role,
                                 check_collisions=False)

    def lanes(self) -> None:
        """The oncoming lanes, and in a traffic jam the lane left of the ego vehicle."""
        tr, st = self.preset.traffic, self.preset.street
        ego_s0 = float(self.ego.route_s_at(0.0))
        for lane in range(st.lanes_per_direction):
            self.column(-st.lane_offset(lane), -1, tr.oncoming_speed, tr.oncoming_per_100m,
                        ego_s0 + self.rng.uniform(-20.0, 20.0), "oncoming", self.rng.random() < tr.stop_and_go_prob)
        if tr.side_column:
            # It crawls on without stopping: the ego vehicle standing while the next lane moves
            # is exactly the case where unmasked moving points drag the odometry along.
            self.column(st.lane_offset(st.ego_lane - 1), 1, tr.side_column_speed, 100.0,
                        ego_s0 + self.rng.uniform(-5.0, 5.0), "side-column", False)

    def cross_traffic(self) -> None:
        """Cars on their own random routes through nearby streets, some waiting at a junction first."""
        tr, st = self.preset.traffic, self.preset.street
        for _ in range(self.count(tr.cross_cars_per_100m)):
            for _attempt in range(tr.max_attempts):
                t_meet = self.rng.uniform(self.times[0], self.times[-1])
                ex, ey = self.ego.pose_at(t_meet)[:2]
                i = int(np.argmin(np.abs(self.grid.xs - ex + self.rng.uniform(-60, 60))))
                j = int(np.argmin(np.abs(self.grid.ys - ey + self.rng.uniform(-60, 60))))
                i = int(np.clip(i, 1, len(self.grid.xs) - 2))
                j = int(np.clip(j, 1, len(self.grid.ys) - 2))
                length = tr.car_speed[1] * (self.t1 - self.t0) + 100.0
                path = random_route(self.rng, self.grid, st, length, start=(i, j))
                hold = t_meet - self.rng.uniform(0.0, 12.0)
                prof = self.profile(tr.car_speed, self.rng.random() < tr.stop_and_go_prob, (40.0, 150.0),
                                    (2.0, 8.0), hold_until=hold if hold > self.t0 else None,
                                    speed_limit=path.speed_limit(self.preset.ego.turn_speed, 2.5))
                lane = int(self.rng.integers(st.lanes_per_direction))
                x, y, yaw = path.offset(st.lane_offset(lane)).pose(prof.at(self.times))
                if self.offer(ob.CAR_KIND, x, y, yaw, "cross"):
                    break

    def independent_on_ego_path(self, kind: ob.ObjectKind, per_100m: float, speed: tuple[float, float],
                                lateral: float, role: str, standing_prob: float = 0.0,
                                lateral_jitter: float = 0.0, same_side_rule: bool = True) -> None:
        """Participants along the ego route: slow cars, cyclists, pedestrians (direction at random)."""
        tr = self.preset.traffic
        for _ in range(self.count(per_100m)):
            for _attempt in range(tr.max_attempts):
                direction = 1 if self.rng.random() < 0.5 else -1
                # Vehicles keep to the right of their own direction; people use either sidewalk.
                side = direction if same_side_rule else (1 if self.rng.random() < 0.5 else -1)
                lat = side * lateral + self.rng.uniform(-lateral_jitter, lateral_jitter)
                s0 = self.random_ego_s() + self.rng.uniform(-60.0, 60.0)
                if self.rng.random() < standing_prob:
                    travelled = np.zeros(len(self.times))
                else:
                    prof = self.profile(speed, self.rng.random() < tr.stop_and_go_prob, (10.0, 60.0), (2.0, 10.0))
                    travelled = prof.at(self.times) - prof.at(self.rng.uniform(self.times[0], self.times[-1]))
                if self.along_ego_route(kind, s0, travelled, lat, direction, role):
                    break


def build_traffic(rng: np.random.Generator, preset: SimPreset, ground: Ground, ego: Ego, times: np.ndarray,
                  reach: float, first_instance: int) -> Traffic:
    """Every participant of a sequence, standing on ``ground``; instance ids are given from ``first_instance`` on."""
    tr, st = preset.traffic, preset.street
    b = _TrafficBuilder(rng, preset, ground, ego, times, reach, first_instance)
    b.ego_lane_queue()
    b.lanes()
    b.cross_traffic()
    # Slow cars crawl in the lanes of either direction; they must fit between the columns.
    b.independent_on_ego_path(ob.CAR_KIND, tr.slow_cars_per_100m, tr.slow_speed, st.lane_offset(0), "slow")
    b.independent_on_ego_path(ob.CYCLIST_KIND, tr.cyclists_per_100m, tr.cyclist_speed, st.bike_offset, "cyclist")
    b.independent_on_ego_path(ob.PEDESTRIAN_KIND, tr.pedestrians_per_100m, tr.pedestrian_speed,
                              st.sidewalk_offset, "pedestrian", tr.standing_pedestrian_prob, 0.25,
                              same_side_rule=False)
    ex, ey, eyaw = ego.pose_at(times)
    return Traffic(ego, times, b.accepted, ex, ey, eyaw)


def build_ego(rng: np.random.Generator, preset: SimPreset, route: Path, s_start: float, t_end: float) -> Ego:
    """The ego vehicle's drive: one cruise speed, slower in corners, stops at some junctions, maybe a standing start.

    ``s_start`` is the centre-line position where its profile begins (``_PRE`` s before the first scan).
    """
    eg, st = preset.ego, preset.street
    lane = route.offset(st.lane_offset(st.ego_lane))
    start = float(np.interp(s_start, route.s, lane.s))
    cruise = float(rng.uniform(*eg.speed))
    stop_line = st.half_road_width + st.sidewalk_width + 2.0
    stops = [
        Stop(float(s - stop_line - start), float(rng.uniform(*eg.stop_duration)))
        for s in lane.nodes_s
        if s - stop_line > start and rng.random() < eg.stop_prob
    ]
    hold = float(rng.uniform(1.0, 6.0)) if rng.random() < eg.start_stopped_prob else None
    limit = lane.speed_limit(eg.turn_speed, eg.decel)
    profile = simulate_profile(
        -_PRE, t_end + _POST, cruise, stops, speed_limit=lambda s: limit(s + start),
        accel=eg.accel, decel=eg.decel, hold_until=hold, v0=0.0 if hold is not None else None,
    )
    return Ego(route, lane, start, profile)
