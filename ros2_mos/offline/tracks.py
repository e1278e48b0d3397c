"""Objects followed through the drive (world frame), and which of them move.

Each scan's objects are observations: centroid, point count, extent, and how much of each was seen through by
nearby scans (``near``: a few scans away, motion now) and by any scan of the window (``far``). Observations are
chained into tracks by nearest centroid to a constant-velocity prediction within a gate; a track ends after
``max_missed`` scans without an observation. When the drive is over, a track is cut where it jumped from one object
to another of a different size (:meth:`Tracker.cut_jumps`).

A track is a *mover* (:meth:`Tracker.movers`) when enough of its observations were seen through: the place where it
stood was empty at another time, so it moved while the sensor watched, and under SemanticKITTI's convention every
scan of it is moving, also those where it waits. A parked car passed closely keeps its place: its points are never
seen through, however much its visible centroid slides as the view changes. A track that is not seen through
often enough is still a mover when the online model labelled it moving in enough of its observations
(``Observation.online``): a car queueing in a jam, whose place the next car fills, is never seen through.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ros2_mos.core.errors import ConfigError

#: The evidence that makes a track a mover (:meth:`Tracker.movers`).
SEEN_THROUGH = "seen through"
ONLINE_MODEL = "online model"
#: A track that stood where a mover's track began as it ended (:meth:`Tracker.handovers`): the same object, which
#: waited, then left; its track broke as it moved off (its cluster split, or its centroid jumped).
WAITED = "waited, then left"
#: A track that began where a mover's track ended standing, soon after it ended (:meth:`Tracker.resumptions`): the
#: same object, seen again after something passed between it and the sensor.
RESUMED = "seen again where it stood"
#: A track that the online model saw pull away as the drive ended (:meth:`Tracker.pulling_away`).
PULLED_AWAY = "pulling away as the drive ended"
#: A track that was seen through in its last observations as it travelled on (:meth:`Tracker.seen_leaving`).
SEEN_LEAVING = "seen through as it left"
#: How far apart seen-through observations lie (:func:`evidence_travel`).
EVIDENCE_TRAVEL = ("box", "centroid")
#: The :class:`TrackConfig` settings read while tracks are built (:meth:`Tracker.add_scan`); every other one is read
#: only when the tracks are judged afterwards, and can change between judging the same tracks twice
#: (:meth:`~ros2_mos.offline.autolabel.AutoLabeler.decide`).
TRACKING_FIELDS = ("gate", "gate_per_speed", "max_missed", "max_speed", "max_area_ratio")


@dataclass(frozen=True)
class TrackConfig:
    gate: float = 1.5  # m around the predicted centroid
    gate_per_speed: float = 0.15  # s: the gate grows with the track's speed (m/s) times this
    max_missed: int = 5  # scans
    max_speed: float = 40.0  # m/s: faster velocity estimates are clipped
    seen_through: float = 0.3  # share of an observation's points seen through that makes it moving evidence
    #: ... where it has this many points or more: an object of fewer returns (a car 30-40 m away seen by a sparse
    #: sensor: ``ObjectConfig.min_points``) moves with its track, but the share of a handful seen through swings
    evidence_points: int = 8
    #: m: an observation farther from the sensor than this (its centroid, seen from above) counts in the shares of a
    #: track's observations that must be moving evidence (``moving_share``, ``cue_track_share``) only where it is
    #: evidence: out there a move must outrun the visibility margin (4 % of the range) and the online model's
    #: residuals (50 m) to show, so no evidence is no word against it. Objects are found to
    #: ``ObjectConfig.max_range`` (100 m); a car that moved near, then waited 60-100 m away, is a mover by what it did
    #: near (HDL-64E suite easy-9301: 5 of 25 observations seen through within 60 m, 5 of 67 out to 98 m;
    #: benchmarks/autolabel.md, round 50)
    evidence_range: float = 60.0
    min_moving_observations: int = 2
    moving_share: float = 0.2  # ... and at least this share of the track's observations,
    #: m: or fewer seen-through observations that lie this far apart (it waited long, then left) ...
    min_evidence_travel: float = 1.5
    evidence_travel: str = "box"  # ... measured by their boxes (box_shift) or centroids (:func:`evidence_travel`)
    #: m: a track made mostly of parts cut off an object for being seen through (:class:`Observation`'s ``cut``) is a
    #: mover only where its seen-through observations travelled this far: a thin pole cut off a hedge is seen through
    #: round its edges and stays put, a cyclist cut off the parked car he passes travels on (VLP-16 narrow streets:
    #: 1.0-1.3 m in 0.3-0.4 s; every such track of 0.5 m or more on the validation and narrow-street drives of the
    #: VLP-16, VLP-32C and HDL-64E moved; benchmarks/autolabel.md, round 55)
    cut_travel: float = 0.5
    #: ... but not where one step between observations of consecutive scans made most of that travel (this share of
    #: it or more, the other steps together less than the rest) with two observations or more on either side: the box
    #: stood, jumped within 0.1 s, and stood again, which no vehicle does. A ring on a parked car's roof slides along
    #: it as the sensor nears (VLP-32C suite easy-9301: a roof seen by one ring, 1.5 m in one scan and still before
    #: and after, 157 false moving points; benchmarks/autolabel.md, round 48); a car that moved while hidden, its
    #: observations scans apart, is not held to it (0: off)
    travel_jump: float = 0.75
    #: An observation whose footprint (box area) is this many times larger or smaller than the track's last one
    #: does not continue it: a track that lost its mover must not jump onto the hedge or the row of cars beside it.
    max_area_ratio: float = 4.0
    #: A track that is a mover only by its share of seen-through observations (they travelled less than
    #: ``min_evidence_travel``) is none where the online model, when there is one, labelled at most ``cue_veto_share``
    #: of its observations' points moving on average: foliage, poles and parked cars are seen through now and then by
    #: scans far apart, and the model knows them for static (VLP-32C suite easy-9301: trees 30-45 m away) ...
    cue_veto: bool = True
    cue_veto_share: float = 0.05
    #: ... and no observation of it had more than this share of its points seen through by a near scan
    #: (``Observation.near``; 1: whatever the near scans saw): a walker whom the model misses is seen through by the
    #: scans just before and after (the real 08a's track 97, which SemanticKITTI's people label moving; the veto
    #: without this removed him, round 39), a tree or a parked car seen through by far scans only is not
    #: (benchmarks/autolabel.md, round 41). Without it the veto was off since round 30: on the real r2 of then it
    #: unlabelled a third of the moving points
    cue_veto_near: float = 0.0
    #: A track that visibility does not make a mover is one on the online model's word (``Observation.online``) when
    #: at least ``cue_observations`` of its observations, and ``cue_track_share`` of them, had ``cue_share`` of their
    #: points labelled moving by it: queueing cars whose place the next car fills are never seen through.
    cue_share: float = 0.6
    cue_observations: int = 5
    cue_track_share: float = 0.5
    #: m: ... and whose boxes travelled this far (:func:`evidence_travel` over all its observations): queueing cars
    #: creep on, while the online model's errors stand (it labels parked cars within ~3 m of a narrow street
    #: moving, all the way along them) (0: no check)
    cue_travel: float = 1.5
    #: m: ... and that stood at least this far from the sensor (median over its observations, seen from above): the
    #: model labels a parked car that the sensor passes at arm's length moving, and its box slides as the sensor
    #: passes (VLP-16 unseen7 narrow_street-10312: 2.9 m away, 1.9 m of box travel, 66,874 false moving points);
    #: the 338 other movers on the model's word surveyed on simulated drives stood 6.8 m away or more (0: no check;
    #: benchmarks/autolabel.md, round 31)
    cue_min_distance: float = 4.0
    #: A track whose observations the model labelled moving are too few a share of it (it drove up, then waited long:
    #: SemanticKITTI's mover throughout) is one on the model's word where ``cue_observations`` consecutive ones were
    #: labelled moving and travelled ``cue_travel`` among themselves, ``cue_min_distance`` or farther from the sensor
    #: (VLP-32C unseen7 benchmark-10321 74.4 -> 92.3; 7 new movers on 112 VLP-32C and VLP-16 drives, one of them
    #: false: benchmarks/autolabel.md, round 32)
    cue_run: bool = True
    #: m: a track, a mover by no other evidence, still live as the drive ended (its last observation within
    #: ``max_missed`` scans of the last scan) whose last ``cue_observations`` or more observations the model labelled
    #: moving is a mover where the last of their boxes lies this far on from the first (``cue_min_distance`` or farther
    #: from the sensor): a car that pulls away as the drive ends has no later scan to see its place empty, nor time to
    #: travel ``cue_travel`` (VLP-16 unseen8 narrow_street-10412: a car that waited ahead of the sensor for 90 scans,
    #: 0.35 m on when the drive ends; under SemanticKITTI's convention it moved while observed). Under the instant
    #: convention it moves now by the rules for every mover (:meth:`Tracker.pulling_away`) (0: off)
    cue_end_travel: float = 0.25
    #: m: ... where the sensor moved at most this far over those observations: a moving sensor's view of a parked car
    #: slides its box's edges (HDL-64E unseen8 easy-10431: two parked cars passed as the drive ends, that the model
    #: labels moving, 0.28 and 0.49 m of box while the sensor drove 3.6 and 5.0 m)
    cue_end_still: float = 1.0
    #: m: a track, a mover by no other evidence, whose last ``cue_observations`` or more observations were seen through
    #: is a mover where the last of their boxes lies this far on from the first: a car that waited long, then drove
    #: off and was lost soon after (VLP-32C unseen8 benchmark-10421: 83 observations, the last 9 seen through, 0.85 m
    #: of box travel before its track ended) is too little of its track, and travelled too little, for
    #: ``moving_share`` and ``min_evidence_travel`` (:meth:`Tracker.seen_leaving`) (0: off)
    leave_travel: float = 0.25
    #: m: ... where the longer side of its median box is this long or longer: a vehicle, seen from any side (a car's
    #: front seen as a sliver 1.8 m wide), not a pole, whose edges are seen through as the sensor nears it, nor a
    #: person, whose box jitters by as much (HDL-64E suite benchmark-9102: a pole 0.2 m across, its last 5 boxes
    #: seen through and 0.5 m on, 3,373 false moving points). A track made mostly of parts cut off for being seen
    #: through is never one (it must travel ``min_evidence_travel``, as for :meth:`seen_moving`)
    leave_min_length: float = 1.0
    #: scans: a track that ends within this many scans of where a mover's track begins (their boxes, grown by
    #: ``handover_margin`` metres, overlapping from above) is that mover, waiting (:meth:`Tracker.handovers`)
    handover_scans: int = 3
    handover_margin: float = 0.3
    #: ... when its last box's footprint (or, where that is smaller, the stub of a car moving off, the track's
    #: median footprint) is at most this many times the mover's first box (a car that waited is larger than the
    #: first glimpse of it moving off: 4.2-4.8 times on the simulated jams; 5.6 for a car queued behind the sensor,
    #: whose first glimpse is its front seen end-on, VLP-32C narrow_street-9913; 5 until round 55) ...
    handover_larger: float = 7.0
    #: ... and at least this share of it (a pole, or a parked car that a passer-by walked past, is smaller) ...
    handover_smaller: float = 0.5
    #: ... and at most this many square metres: a car (larger clusters that a passer-by left, on sparse sensors
    #: above all, are not it)
    handover_max_area: float = 9.0
    #: ... and at least this many: a car, even seen only from behind (poles, signs and pedestrians beside the
    #: real r2's passers-by are not)
    handover_min_area: float = 0.75
    #: m: a mover whose boxes travelled less than this (:func:`evidence_travel` over all its observations) hands
    #: nothing over: it cannot have left a place it waited at (a hedge or a kerb seen through now and then is a mover
    #: by its share of seen-through observations, and stays where it is)
    handover_travel: float = 1.5
    #: A track whose last ``min_moving_observations`` observations were seen through (it was moving as it ended) is
    #: the mover that begins where it ended, whatever its size and whatever else began there: a cyclist who waited,
    #: rode off and broke his track is no parked car that a passer-by merged with
    handover_seen_moving: bool = True
    #: A track at most twice the first glimpse of two or more movers that begin in its place together (``_glimpse``)
    #: is them, however large (``handover_max_area`` is for clusters that a lone passer-by left): a car and a cyclist
    #: that waited side by side, one cluster, and left together
    handover_filled: bool = True
    #: scans: a track that begins within this many scans after a mover's track ended standing (its boxes over its last
    #: ``resume_stood_observations`` full views travelled ``resume_stood`` m or less, and over the whole track
    #: ``resume_travel`` m or more: it moved, then stood), its first ``resume_observations`` boxes within the box where
    #: the mover stood (grown by ``handover_margin``) from above and at its heights, is that mover seen again:
    #: something passed between it and the sensor, and its track broke (0: off; only a mover by visibility;
    #: :meth:`Tracker.resumptions`)
    resume_scans: int = 20
    resume_stood: float = 0.3
    resume_travel: float = 1.0
    resume_stood_observations: int = 5
    resume_observations: int = 3
    #: scans: a track is cut where it jumped from one object to another (:meth:`Tracker.cut_jumps`): its observations
    #: lie this many scans apart or more (it was missed in between), the later box lies apart from the earlier one
    #: (grown by ``jump_margin`` m), its moving evidence breaks there (the ``min_moving_observations`` observations
    #: before were seen through and none of the ``jump_evidence`` after, or the other way round), and its observations
    #: before and after (up to the gaps around) differ in median footprint by ``max_area_ratio`` or more. A pedestrian
    #: hidden for a scan or two as he walks past a parked car's corner, whose track takes the car on (VLP-16 unseen6
    #: narrow_street-10211); a car that waited, then drove off while hidden, is neither cut nor two sizes (0: never cut)
    jump_gap: int = 2
    jump_margin: float = 0.2
    jump_evidence: int = 5
    #: m/s: a track is also cut where it jumped without a missed scan (:meth:`Tracker.cut_jumps`): its moving evidence
    #: stops there (seen through before, not after, as for ``jump_gap``), its box (both edges, :func:`box_shift`)
    #: travelled this fast or faster over the ``jump_window`` observations before and ``jump_still`` or slower over
    #: those from there on, what stands is ``jump_area`` times larger in median footprint than what moved, and the
    #: sensor's own speed (its poses) over the same observations changed by less than ``jump_sensor`` m/s. No
    #: vehicle stops from 3 m/s within a scan: a passer-by seen through beside a parked car merges with it and the
    #: track follows the car as it comes into view (VLP-32C unseen4 narrow_street-10013: 29,000 false moving points).
    #: Where the poses say that the sensor itself halted so, the odometry slipped, and the boxes' speeds with it
    #: (HDL-64E unseen8 traffic_jam-10402: KISS-ICP's sensor went 4.4 m/s, then 0.6, behind a car it followed at 2).
    #: Not the other way round (:meth:`Tracker._halts`). 0: never
    jump_speed: float = 3.0
    jump_still: float = 0.5
    jump_area: float = 2.0
    jump_window: int = 3
    jump_sensor: float = 1.5

    def __post_init__(self) -> None:
        from ros2_mos.offline.objects import check_numbers

        check_numbers(self, "autolabel tracks",
                      zero_ok=("moving_share", "cut_travel", "handover_scans", "handover_margin", "handover_min_area",
                               "handover_travel", "cue_travel", "cue_veto_share", "cue_veto_near", "cue_min_distance",
                               "resume_scans", "resume_stood", "resume_travel", "jump_gap", "jump_margin",
                               "jump_speed", "jump_still", "jump_sensor",
                               "cue_end_travel", "cue_end_still", "leave_travel", "leave_min_length", "travel_jump"),
                      at_most_one=("seen_through", "moving_share", "cue_share", "cue_track_share", "handover_smaller",
                                   "cue_veto_share", "cue_veto_near", "travel_jump"))
        if self.evidence_travel not in EVIDENCE_TRAVEL:
            raise ConfigError(f"autolabel tracks: evidence_travel must be one of {', '.join(EVIDENCE_TRAVEL)}, got "
                              f"{self.evidence_travel!r}")
        for name in ("max_area_ratio", "handover_larger", "jump_area"):
            if getattr(self, name) < 1.0:
                raise ConfigError(f"autolabel tracks: {name} must be >= 1, got {getattr(self, name)!r}")
        if self.jump_window < 2:
            raise ConfigError(f"autolabel tracks: jump_window must be >= 2, got {self.jump_window!r}")


@dataclass
class Observation:
    scan: int
    obj: int
    centroid: np.ndarray
    points: int
    lo: np.ndarray  # (3,) world bounding box
    hi: np.ndarray
    near: float
    far: float
    online: float = 0.0  # share of its points the online model labelled moving (0 without the online cue)
    cut: bool = False  # the seen-through part cut off an object (autolabel's ``split_seen_apart``)
    distance: float = float("inf")  # m from the sensor to its centroid, seen from above (inf: not known)
    #: (2, 2) m per edge of its box ([lower, upper] x [x, y]): how far from the sensor its points along that edge lie
    #: (:func:`~ros2_mos.offline.autolabel.edge_reach`); an edge at the drive's blind radius is where the vehicle's
    #: shadow cut the object, no edge of it (a bus alongside is two objects, each with one edge pinned there)
    edge_reach: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.inf))

    @property
    def size(self) -> np.ndarray:
        return self.hi - self.lo


@dataclass
class Track:
    id: int
    observations: list[Observation] = field(default_factory=list)
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @property
    def last(self) -> Observation:
        return self.observations[-1]

    def path_length(self) -> float:
        c = np.array([o.centroid[:2] for o in self.observations])
        return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0

    def peak_speed(self, stamps: np.ndarray, window: int = 5) -> float:
        """The largest centroid displacement over ``window`` observations, per second (a robust peak)."""
        obs = self.observations
        if len(obs) <= window:
            if len(obs) < 2:
                return 0.0
            window = len(obs) - 1
        c = np.array([o.centroid[:2] for o in obs])
        t = stamps[[o.scan for o in obs]]
        dt = np.maximum(t[window:] - t[:-window], 1e-3)
        return float((np.linalg.norm(c[window:] - c[:-window], axis=1) / dt).max())


def box_shift(lo0: np.ndarray, hi0: np.ndarray, lo1: np.ndarray, hi1: np.ndarray,
              cut_lo: np.ndarray | None = None, cut_hi: np.ndarray | None = None) -> np.ndarray:
    """(M, D) how far boxes moved from (lo0, hi0) to (lo1, hi1), per axis, counting only what both edges agree on.

    A standing object's visible box grows or shrinks as the view changes, one edge at a time, and its centroid
    slides with it; a moving one carries both edges along. Per axis: where both edges moved the same way, the
    smaller of the two moves; where they moved apart (or one stayed), nothing. An edge that is a cut (``cut_lo``,
    ``cut_hi``: the vehicle's shadow, in either box) does not count: the other edge's move is the box's; with both
    cut, nothing.
    """
    d_lo = lo1 - lo0
    d_hi = hi1 - hi0
    same_way = np.sign(d_lo) == np.sign(d_hi)
    shift = np.where(same_way, np.where(np.abs(d_lo) < np.abs(d_hi), d_lo, d_hi), 0.0)
    if cut_lo is None or cut_hi is None:
        return shift
    return np.where(cut_lo, np.where(cut_hi, 0.0, d_hi), np.where(cut_hi, d_lo, shift))


def _moved_on(observations: list[Observation]) -> float:
    """How far (m, seen from above) the last of ``observations``' boxes lies on from the first (:func:`box_shift`)."""
    first, last = observations[0], observations[-1]
    return float(np.linalg.norm(box_shift(first.lo[:2], first.hi[:2], last.lo[:2], last.hi[:2])))


#: :func:`evidence_travel` compares at most about this many observations, evenly spread over the track (and its last):
#: the pairs of a track thousands of scans long would take gigabytes.
TRAVEL_MAX_BOXES = 256


def evidence_travel(observations: list[Observation], measure: str = "box") -> float:
    """How far apart (m, seen from above) ``observations`` of one track lie (its seen-through ones, or all of them).

    ``measure='box'``: the largest :func:`box_shift` between two of them. A parked car that a passer-by merged with
    for a few scans is seen through there (the passer-by's share), and it grows and shrinks: its centroid slides by
    metres, its box edges do not travel together. ``'centroid'``: the diagonal of their centroids' extent.
    """
    if len(observations) < 2:
        return 0.0
    if len(observations) > TRAVEL_MAX_BOXES:  # pairs grow with the square: a car followed through a long drive
        observations = observations[:: -(-len(observations) // TRAVEL_MAX_BOXES)] + [observations[-1]]
    if measure == "centroid":
        centroids = np.array([o.centroid[:2] for o in observations])
        return float(np.hypot(*(centroids.max(axis=0) - centroids.min(axis=0))))
    lo = np.array([o.lo[:2] for o in observations])
    hi = np.array([o.hi[:2] for o in observations])
    shift = box_shift(lo[:, None, :], hi[:, None, :], lo[None, :, :], hi[None, :, :])
    return float(np.linalg.norm(shift, axis=-1).max())


#: Footprints are measured from this size up (m per side): a pole's or a flat object's box has next to no area.
MIN_FOOTPRINT_SIDE = 0.5
#: s between scans where a drive's stamps are not given (:meth:`Tracker.cut_jumps`)
SCAN_PERIOD = 0.1


def overlap_from_above(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> np.ndarray:
    """Whether top-view boxes a and b (``(..., 2)`` corners, broadcast against each other) overlap."""
    return ((lo_a <= hi_b) & (hi_a >= lo_b)).all(axis=-1)


def footprint(obs: Observation) -> float:
    """The area (m^2) of an observation's box seen from above, each side at least ``MIN_FOOTPRINT_SIDE``."""
    side = np.maximum(obs.size[:2], MIN_FOOTPRINT_SIDE)
    return float(side[0] * side[1])


def median_footprint(track: Track) -> float:
    """The :func:`footprint` of a track's median observation."""
    return float(np.median([footprint(o) for o in track.observations]))


class Tracker:
    """Greedy nearest-neighbour association of each scan's observations to the live tracks."""

    def __init__(self, config: TrackConfig = TrackConfig()) -> None:
        self.config = config
        self.tracks: list[Track] = []
        self._live: list[Track] = []
        #: (scan, object) -> track id
        self.track_of: dict[tuple[int, int], int] = {}
        #: the last scan added (-1: none)
        self.last_scan = -1

    def add_scan(self, scan: int, stamp: float, last_stamp: float | None, observations: list[Observation]) -> None:
        cfg = self.config
        self.last_scan = max(self.last_scan, scan)
        dt = 0.1 if last_stamp is None else max(stamp - last_stamp, 1e-3)
        live = [t for t in self._live if scan - t.last.scan <= cfg.max_missed]
        matched_obs: set[int] = set()
        if live and observations:
            predicted = np.array([t.last.centroid[:2] + t.velocity * (scan - t.last.scan) * dt for t in live])
            gates = np.array([cfg.gate + cfg.gate_per_speed * float(np.linalg.norm(t.velocity)) for t in live])
            cents = np.array([o.centroid[:2] for o in observations])
            dist = np.linalg.norm(predicted[:, None, :] - cents[None, :, :], axis=-1)
            dist[dist > gates[:, None]] = np.inf
            areas = np.array([footprint(o) for o in observations])
            last_areas = np.array([footprint(t.last) for t in live])
            ratio = np.maximum(areas[None, :], last_areas[:, None]) / np.minimum(areas[None, :], last_areas[:, None])
            dist[ratio > cfg.max_area_ratio] = np.inf
            used_tracks: set[int] = set()
            for flat in np.argsort(dist, axis=None):
                ti, oi = divmod(int(flat), len(observations))
                if not np.isfinite(dist[ti, oi]):
                    break
                if ti in used_tracks or oi in matched_obs:
                    continue
                used_tracks.add(ti)
                matched_obs.add(oi)
                track, obs = live[ti], observations[oi]
                gap = max(obs.scan - track.last.scan, 1) * dt
                v = (obs.centroid[:2] - track.last.centroid[:2]) / gap
                speed = float(np.linalg.norm(v))
                if speed > cfg.max_speed:
                    v *= cfg.max_speed / speed
                track.velocity = 0.5 * track.velocity + 0.5 * v
                self._append(track, obs)
        for oi, obs in enumerate(observations):
            if oi not in matched_obs:
                track = Track(len(self.tracks))
                self.tracks.append(track)
                live.append(track)
                self._append(track, obs)
        self._live = live

    def _append(self, track: Track, obs: Observation) -> None:
        track.observations.append(obs)
        self.track_of[(obs.scan, obs.obj)] = track.id

    def cut_jumps(self, stamps: np.ndarray | None = None, sensor_xy: np.ndarray | None = None) -> int:
        """Cut each track where it jumped from one object to another (see ``TrackConfig.jump_gap`` and
        ``jump_speed``): the pieces after each cut become tracks of their own (new ids, ``track_of`` follows them).
        ``stamps``: seconds per scan of the drive (None: :data:`SCAN_PERIOD` apart); ``sensor_xy``: (scans, 2) the
        sensor's world positions (None: not checked). Call it once, after the last scan, before the movers are
        judged. Returns how many cuts it made."""
        cfg = self.config
        if cfg.jump_gap == 0 and cfg.jump_speed == 0:
            return 0
        cuts = 0
        for track in list(self.tracks):
            at = self._jumps(track, stamps, sensor_xy)
            if not at:
                continue
            cuts += len(at)
            observations = track.observations
            track.observations = observations[:at[0]]
            for a, b in zip(at, [*at[1:], len(observations)]):
                piece = Track(len(self.tracks), observations[a:b])
                self.tracks.append(piece)
                for obs in piece.observations:
                    self.track_of[(obs.scan, obs.obj)] = piece.id
        self._live = []  # the drive is over: nothing continues
        return cuts

    def _jumps(self, track: Track, stamps: np.ndarray | None = None, sensor_xy: np.ndarray | None = None) -> list[int]:
        """The indices of ``track``'s observations where it jumped to another object (:meth:`cut_jumps`)."""
        cfg = self.config
        obs = track.observations
        gaps = [i for i in range(1, len(obs)) if obs[i].scan - obs[i - 1].scan >= cfg.jump_gap] if cfg.jump_gap else []
        if not gaps and (cfg.jump_speed == 0 or len(obs) < 2 * cfg.jump_window):
            return []  # most tracks: never missed, and too short to halt
        seen = np.array([self.seen_through(o) for o in obs])
        area = np.array([footprint(o) for o in obs])
        out = []
        for g, i in enumerate(gaps):
            if overlap_from_above(obs[i - 1].lo[:2] - cfg.jump_margin, obs[i - 1].hi[:2] + cfg.jump_margin,
                                  obs[i].lo[:2], obs[i].hi[:2]):
                continue
            if self._evidence_breaks(seen, i) is None:
                continue
            # the observations between this gap and the ones around it: two objects of different sizes
            a = float(np.median(area[gaps[g - 1] if g else 0:i]))
            b = float(np.median(area[i:gaps[g + 1] if g + 1 < len(gaps) else len(obs)]))
            if max(a, b) >= cfg.max_area_ratio * min(a, b):
                out.append(i)
        if cfg.jump_speed > 0:
            out.extend(self._halts(obs, seen, area, stamps, sensor_xy))
        return sorted(set(out))

    def _evidence_breaks(self, seen: np.ndarray, i: int) -> str | None:
        """'stopped' where the ``min_moving_observations`` observations before index ``i`` were seen through and none
        of the ``jump_evidence`` from it on, 'started' the other way round, else None."""
        before, after = self.config.min_moving_observations, self.config.jump_evidence
        if i >= before and seen[i - before:i].all() and i + after <= len(seen) and not seen[i:i + after].any():
            return "stopped"
        if i >= after and not seen[i - after:i].any() and i + before <= len(seen) and seen[i:i + before].all():
            return "started"
        return None

    def _halts(self, obs: list[Observation], seen: np.ndarray, area: np.ndarray, stamps: np.ndarray | None,
               sensor_xy: np.ndarray | None) -> list[int]:
        """The indices where a track's box halted from ``jump_speed`` to ``jump_still`` between two observations
        while its moving evidence stopped there, what stands is ``jump_area`` times larger than what moved, and the
        sensor (``sensor_xy``) kept its speed (:meth:`cut_jumps`; ``TrackConfig.jump_speed``). Not the other way
        round (a standing track that goes on as a mover): that is what a mover merged with the static points around
        it does as it drives out of them, and the merged part holds most of its points (real r1: an oncoming car,
        its first 5 scans)."""
        cfg = self.config
        w, e = cfg.jump_window, cfg.jump_evidence
        scans = np.array([o.scan for o in obs])
        times = scans * SCAN_PERIOD if stamps is None else np.asarray(stamps, np.float64)[scans]

        def seconds(a: int, b: int) -> float:  # from observation a to b - 1
            return max(float(times[b - 1] - times[a]), 1e-3)

        def speed(a: int, b: int) -> float:  # m/s of the box (both edges), its first to its last
            return _moved_on(obs[a:b]) / seconds(a, b)

        def sensor_speed(xy: np.ndarray, a: int, b: int) -> float:  # m/s of the sensor between those scans
            step = np.asarray(xy[scans[b - 1]], np.float64) - np.asarray(xy[scans[a]], np.float64)
            return float(np.linalg.norm(step)) / seconds(a, b)

        out = []
        for i in range(w, len(obs) - w + 1):
            if self._evidence_breaks(seen, i) != "stopped":
                continue
            if speed(i - w, i) < cfg.jump_speed or speed(i, i + w) > cfg.jump_still:
                continue
            if sensor_xy is not None and \
                    abs(sensor_speed(sensor_xy, i - w, i) - sensor_speed(sensor_xy, i, i + w)) >= cfg.jump_sensor:
                continue  # the odometry slipped: the boxes' speeds are the poses'
            if float(np.median(area[i:i + e])) >= cfg.jump_area * float(np.median(area[max(0, i - e):i])):
                out.append(i)
        return out

    def seen_through(self, obs: Observation) -> bool:
        """Whether ``obs`` is moving evidence: at least ``seen_through`` of its points (``evidence_points`` or
        more) were seen through by a scan of the window (its ``far`` share)."""
        return obs.far >= self.config.seen_through and self._judged(obs)

    def seen_moving(self, track: Track, cue: bool = False) -> bool:
        """Enough of the track's observations were seen through: a share of them, or fewer that lie apart (a car
        that waited most of the drive and then left; a static object seen through now and then stays in place). A
        track made mostly of parts cut off an object for being seen through (:class:`Observation`'s ``cut``) must
        travel ``cut_travel``: a thin pole beside a hedge is seen through around its edges, and cut off it. With
        ``cue`` (the observations carry the online model's labels) and ``cue_veto``, one that did not travel must not
        be one the model calls static."""
        cfg = self.config
        seen = [self.seen_through(o) for o in track.observations]
        evidence = [o for o, s in zip(track.observations, seen) if s]
        if len(evidence) < cfg.min_moving_observations:
            return False
        travel = evidence_travel(evidence, cfg.evidence_travel)
        cut = self._mostly_cut(track)  # parts cut off for being seen through (a pole beside a hedge): if they travel
        travelled = travel >= (cfg.cut_travel if cut else cfg.min_evidence_travel) and not self._one_jump(track, travel)
        if cut:
            return travelled
        if travelled:
            return True
        if cue and cfg.cue_veto and np.mean([o.online for o in track.observations]) <= cfg.cue_veto_share \
                and max(o.near for o in track.observations) <= cfg.cue_veto_near:
            return False  # seen through now and then where it stands, the online model calls it static, and no
            # scan just before or after saw through it
        return len(evidence) >= cfg.moving_share * self._counted(track.observations, seen)

    def labelled_moving(self, track: Track) -> bool:
        """The online model labelled enough of the track's observations moving (see ``TrackConfig.cue_share``), its
        boxes travelled ``cue_travel``, and it stood ``cue_min_distance`` or farther from the sensor; or (``cue_run``)
        a run of ``cue_observations`` consecutive ones did all that among themselves."""
        cfg = self.config
        obs = track.observations
        hit = np.array([o.online >= cfg.cue_share for o in obs])
        if hit.sum() < cfg.cue_observations:
            return False
        if hit.sum() >= cfg.cue_track_share * self._counted(obs, hit) and self._labelled_moving_along(obs):
            return True
        if not cfg.cue_run:
            return False
        edges = np.flatnonzero(np.diff(np.concatenate([[0], hit.astype(np.int8), [0]])))
        return any(self._labelled_moving_along(obs[a:b])
                   for a, b in zip(edges[::2], edges[1::2]) if b - a >= cfg.cue_observations)

    def pulling_away(self, movers: dict[int, str], sensor_xy: np.ndarray) -> dict[int, str]:
        """{track id: PULLED_AWAY} for the tracks, movers by no other evidence, that the online model saw pull away
        as the drive ended (``TrackConfig.cue_end_travel``): still live at the drive's last scan (within
        ``max_missed`` scans of it), their last ``cue_observations`` or more observations labelled moving
        (``cue_share``), ``cue_min_distance`` or farther from the sensor, the last of those boxes ``cue_end_travel``
        m on from the first (:func:`box_shift`: both edges; from the first to the last, not between any two: the
        boxes of a parked car seen as 10 points jitter by more), while the sensor (``sensor_xy``, (scans, 2) world
        positions) moved ``cue_end_still`` m or less. Such a car has no later scan to see its place empty, nor time
        to travel ``cue_travel``. Call it after :meth:`handovers` and :meth:`resumptions`: a track
        that is their mover keeps their evidence."""
        cfg = self.config
        if cfg.cue_end_travel == 0:
            return {}
        out = {}
        live_until = self.last_scan - cfg.max_missed
        for track in self.tracks:
            if track.id in movers or track.last.scan < live_until:
                continue
            run = self._final_run(track)
            if len(run) < cfg.cue_observations or not self._far_from_sensor(run):
                continue
            path = sensor_xy[[o.scan for o in run]]
            if np.linalg.norm(path - path[0], axis=1).max() > cfg.cue_end_still:
                continue  # the sensor moved: the view of a standing car changes, and its box slides
            if _moved_on(run) >= cfg.cue_end_travel:  # from where it began to pull away to where the drive left it
                out[track.id] = PULLED_AWAY
        return out

    def seen_leaving(self, movers: dict[int, str]) -> dict[int, str]:
        """{track id: SEEN_LEAVING} for the tracks, movers by no other evidence, whose last ``cue_observations`` or
        more observations were all seen through (:meth:`seen_through`; those of too few returns to say are passed
        over, :meth:`_final_run`) and the last of whose boxes lies
        ``leave_travel`` m on from the first of them (:func:`box_shift`: both edges): it was leaving as its track
        ended. Only vehicles (``leave_min_length``) and tracks not made mostly of parts cut off for being seen through
        (:class:`Observation`'s ``cut``). Call it last: a track that is a mover by other evidence keeps that."""
        cfg = self.config
        if cfg.leave_travel == 0:
            return {}
        out = {}
        for track in self.tracks:
            obs = track.observations
            if track.id in movers or self._mostly_cut(track) or \
                    float(np.median([o.size[:2].max() for o in obs])) < cfg.leave_min_length:
                continue
            run = self._final_run(track, seen_through=True)
            if len(run) >= cfg.cue_observations and _moved_on(run) >= cfg.leave_travel:
                out[track.id] = SEEN_LEAVING
        return out

    def _one_jump(self, track: Track, travel: float) -> bool:
        """Whether ``travel`` (m, its seen-through observations') came mostly from one step of ``track``'s boxes
        between consecutive scans, with two observations or more before and after it (``TrackConfig.travel_jump``)."""
        share = self.config.travel_jump
        obs = track.observations
        if share == 0 or len(obs) < 4:
            return False
        lo = np.array([o.lo[:2] for o in obs])
        hi = np.array([o.hi[:2] for o in obs])
        steps = np.linalg.norm(box_shift(lo[:-1], hi[:-1], lo[1:], hi[1:]), axis=1)
        i = int(np.argmax(steps))
        return 1 <= i <= len(steps) - 2 and obs[i + 1].scan - obs[i].scan == 1 and steps[i] >= share * travel \
            and steps.sum() - steps[i] < (1 - share) * travel

    @staticmethod
    def _mostly_cut(track: Track) -> bool:
        """Whether most of ``track``'s observations are parts cut off an object for being seen through."""
        return 2 * sum(o.cut for o in track.observations) > len(track.observations)

    def _final_run(self, track: Track, seen_through: bool = False) -> list[Observation]:
        """The observations at the end of ``track`` that the online model labelled moving (``cue_share``), or with
        ``seen_through`` that were seen through (:meth:`seen_through`), back to the last one that was not. With
        ``seen_through``, observations of fewer than ``evidence_points`` returns are no evidence either way: they
        neither end the run nor join it (a cyclist riding off, 7 returns in its last observation, was seen through in
        the 7 before)."""
        obs = track.observations
        start = len(obs)
        if not seen_through:
            while start > 0 and obs[start - 1].online >= self.config.cue_share:
                start -= 1
            return obs[start:]
        judged = self._judged
        while start > 0 and (self.seen_through(obs[start - 1]) or not judged(obs[start - 1])):
            start -= 1
        return [o for o in obs[start:] if judged(o)]

    def _judged(self, obs: Observation) -> bool:
        """Whether ``obs`` has enough returns (``evidence_points``) for its seen-through share to say anything."""
        return obs.points >= self.config.evidence_points

    def _counted(self, observations: list[Observation], evidence: list[bool] | np.ndarray) -> int:
        """How many of ``observations`` count in a share of them that must be evidence (``evidence``: per
        observation, whether it is): those within ``evidence_range``, and those farther that are evidence."""
        return sum(1 for o, e in zip(observations, evidence) if e or self._within_range(o))

    def _within_range(self, obs: Observation) -> bool:
        """Whether ``obs`` lies within ``evidence_range`` of the sensor (or its distance is not known)."""
        return not (np.isfinite(obs.distance) and obs.distance > self.config.evidence_range)

    def _labelled_moving_along(self, observations: list[Observation]) -> bool:
        return evidence_travel(observations, self.config.evidence_travel) >= self.config.cue_travel and \
            self._far_from_sensor(observations)

    def _far_from_sensor(self, observations: list[Observation]) -> bool:
        """Whether ``observations`` stood ``cue_min_distance`` or farther from the sensor (their median)."""
        return float(np.median([o.distance for o in observations])) >= self.config.cue_min_distance

    def _car_sized_as_it_ended(self, track: Track, beside: float, together: int = 1) -> bool:
        """Whether ``track``'s last box is ``handover_smaller`` to ``handover_larger`` times the footprint ``beside``
        (of ``together`` movers) and ``handover_min_area`` to ``handover_max_area`` (with ``handover_filled`` and two
        or more movers, up to twice ``beside`` however large); or, where it is smaller than that (the stub of a car
        moving off), whether the track's median footprint is."""
        cfg = self.config
        low = max(cfg.handover_smaller * beside, cfg.handover_min_area)
        high = min(cfg.handover_larger * beside, cfg.handover_max_area)
        if cfg.handover_filled and together > 1:
            high = max(high, beside / cfg.handover_smaller)
        area = footprint(track.last)
        if area < low:
            area = median_footprint(track)
        return low <= area <= high

    def _moving_as_it_ended(self, track: Track) -> bool:
        """Whether ``track``'s last ``min_moving_observations`` observations of ``evidence_points`` returns or more
        were seen through."""
        want = self.config.min_moving_observations
        last = []
        for obs in reversed(track.observations):
            if self._judged(obs):
                last.append(obs)
                if len(last) == want:
                    break
        return len(last) == want and all(self.seen_through(o) for o in last)

    def _as_it_ended(self, track: Track) -> tuple[np.ndarray, np.ndarray]:
        """The top-view box where ``track`` stood as it ended: its last box, or where it ended as the shrinking stub of
        a car moving off (fewer points in each of its last ``handover_scans`` + 1 observations), all of theirs."""
        last = track.observations[-(self.config.handover_scans + 1):]
        if len(last) > 1 and all(a.points > b.points for a, b in zip(last, last[1:])):
            return np.min([o.lo[:2] for o in last], axis=0), np.max([o.hi[:2] for o in last], axis=0)
        return track.last.lo[:2], track.last.hi[:2]

    def handovers(self, movers: dict[int, str]) -> dict[int, str]:
        """{track id: WAITED} for the tracks that are a mover before it moved. A car that waits at a light and then
        drives off often breaks its track as it moves off (its cluster splits, its centroid jumps), and where it
        waited is not always seen empty later (the sensor has turned into another street); under SemanticKITTI's
        convention it is moving there too.

        Such a track ended (its last observation) within ``handover_scans`` of the first observation of a mover's track
        (or of another such track), began before it, its last box (or, where it ended as a shrinking stub, the boxes of
        its last ``handover_scans`` + 1 observations) overlaps that first box from above (both grown by
        ``handover_margin``) and is car-sized beside it (its last observation, or where that is smaller, the stub of a
        car moving off, its median observation; ``handover_smaller`` to ``handover_larger`` times its footprint,
        ``handover_min_area`` to ``handover_max_area``: a pole, or a cluster of parked cars and hedges that a passer-by
        walked past, is not), and no other track but the movers' began in its last box within ``handover_scans`` of its
        end: a parked car that a passer-by merged with ends where the passer-by's track begins, and goes on as another
        track. Fragments of a car moving off (tracks shorter than ``handover_scans``) do not count, nor does the next
        car of a queue, whose track began long before it took the place, nor a mover whose track began as a part cut off
        an object for being seen through (a passer-by leaving the kerb or pole it was merged with), nor one whose boxes
        travelled less than ``handover_travel`` (it left nowhere: a hedge seen through now and then). A track that was
        itself seen moving as it ended (``handover_seen_moving``) needs none of the size and emptiness checks."""
        cfg = self.config
        if cfg.handover_scans == 0 or not movers:
            return {}
        last_scan = np.array([t.last.scan for t in self.tracks])
        first_scan = np.array([t.observations[0].scan for t in self.tracks])
        last_lo = np.array([t.last.lo[:2] for t in self.tracks])
        last_hi = np.array([t.last.hi[:2] for t in self.tracks])
        ending = [self._as_it_ended(t) for t in self.tracks]
        end_lo = np.array([o[0] for o in ending])
        end_hi = np.array([o[1] for o in ending])
        first_lo = np.array([t.observations[0].lo[:2] for t in self.tracks])
        first_hi = np.array([t.observations[0].hi[:2] for t in self.tracks])
        track_len = np.array([len(t.observations) for t in self.tracks])
        margin = cfg.handover_margin
        out: dict[int, str] = {}

        @functools.cache
        def median_area(a: int) -> float:
            return median_footprint(self.tracks[a])

        def left_empty(a: int) -> bool:
            """No other track (but movers, fragments shorter than ``handover_scans``, and slivers under
            ``handover_smaller`` of its median footprint) began where track ``a`` ended, as it ended: its place was not
            taken over by the object it was."""
            c = np.flatnonzero((np.abs(first_scan - last_scan[a]) <= cfg.handover_scans) & (first_scan > first_scan[a])
                               & (track_len >= cfg.handover_scans)
                               & overlap_from_above(first_lo, first_hi, last_lo[a], last_hi[a]))
            least = cfg.handover_smaller * median_area(a)
            return all(int(t) in movers or int(t) in out or t == a or median_area(int(t)) < least for t in c)

        beginning = self._beginning()
        todo = list(movers)
        while todo:
            b = self.tracks[todo.pop()]
            first = b.observations[0]
            if first.cut:  # it began cut off an object it passed: that object stood, and stays
                continue
            near = np.flatnonzero((np.abs(last_scan - first.scan) <= cfg.handover_scans) & (first_scan < first.scan)
                                  & overlap_from_above(end_lo - margin, end_hi + margin, first.lo[:2] - margin,
                                                       first.hi[:2] + margin))
            near = [a for a in near.tolist() if a not in movers and a not in out]
            if not near:  # most movers: nothing ended where they began (and their travel need not be measured)
                continue
            travelled = b.id in out or evidence_travel(b.observations, cfg.evidence_travel) >= cfg.handover_travel
            for a in near:
                if not (travelled or self._left(b, end_lo[a], end_hi[a])):
                    continue  # it did not leave: nothing waited there (a track it was handed over to stood, by design)
                if cfg.handover_seen_moving and self._moving_as_it_ended(self.tracks[a]):
                    out[a] = WAITED
                    todo.append(a)
                    continue
                glimpse, together = self._glimpse(first, end_lo[a], end_hi[a], beginning.get(first.scan, []), movers,
                                                  out)
                if self._car_sized_as_it_ended(self.tracks[a], glimpse, together) and left_empty(a):
                    out[a] = WAITED
                    todo.append(a)
        return out

    def resumptions(self, movers: dict[int, str]) -> dict[int, str]:
        """{track id: RESUMED} for the tracks that are a mover seen again where it stood. A car or bus that stopped
        beside the road is hidden bit by bit as a truck passes between it and the sensor, and its track ends; when
        the truck has passed, it is revealed bit by bit where it stood, as a new track that neither moves nor is seen
        through. Under SemanticKITTI's convention it is moving there too.

        Such a track begins 1 to ``resume_scans`` scans after a mover's track ended (one that visibility made a
        mover: the online model's word on a parked car, seen again, would spread its error; a track that waited
        before its mover, :meth:`handovers`, did not end standing), and its first ``resume_observations`` boxes lie
        within the box where the mover stood as it ended (:meth:`_where_it_stood`, grown by ``handover_margin``) seen
        from above, and reach into its heights (grown as much): a sign or a tree's crown over where a car stood,
        revealed as the sensor passes, is not the car. The mover stood if its boxes over its last
        ``resume_stood_observations`` full views (before it was hidden bit by bit) travelled ``resume_stood`` m or
        less (:func:`evidence_travel`): a car that drove on while hidden is seen again elsewhere, and the parked car
        it passed, revealed where it drove by, lies beside its box, not within it. It moved before it stood: its
        boxes over the whole track travelled ``resume_travel`` m or more (a parked car seen through now and then, a
        mover by its share, never did; a track seen again is its mover's, and needs no travel of its own)."""
        cfg = self.config
        if cfg.resume_scans == 0 or not movers:
            return {}
        beginning = self._beginning()
        m = cfg.handover_margin
        out: dict[int, str] = {}
        todo = [t for t, evidence in movers.items() if evidence == SEEN_THROUGH]
        while todo:
            a = self.tracks[todo.pop()]
            stood = self._where_it_stood(a)
            if stood is None or (a.id not in out
                                 and evidence_travel(a.observations, cfg.evidence_travel) < cfg.resume_travel):
                continue  # it was still moving as it ended, or it never moved (a parked car seen through now and then)
            lo, hi = stood[0] - m, stood[1] + m
            end = a.last.scan
            for scan in range(end + 1, end + cfg.resume_scans + 1):
                for b in beginning.get(scan, []):
                    if b.id in movers or b.id in out:
                        continue
                    first = b.observations[:cfg.resume_observations]
                    if all(bool(np.all(o.lo[:2] >= lo[:2]) and np.all(o.hi[:2] <= hi[:2])
                                and o.lo[2] <= hi[2] and o.hi[2] >= lo[2]) for o in first):
                        out[b.id] = RESUMED
                        todo.append(b.id)
        return out

    def _beginning(self) -> dict[int, list[Track]]:
        """First scan -> the tracks that begin in it."""
        beginning: dict[int, list[Track]] = {}
        for t in self.tracks:
            beginning.setdefault(t.observations[0].scan, []).append(t)
        return beginning

    def _where_it_stood(self, track: Track) -> tuple[np.ndarray, np.ndarray] | None:
        """The box (x, y, z) where ``track`` stood as it ended: the boxes of its last observation and of the ones
        before it while it was hidden bit by bit (fewer points in each), together; None where its boxes over its last
        ``resume_stood_observations`` full views (up to the first one of those) travelled more than ``resume_stood``
        m: it was still moving."""
        cfg = self.config
        obs = track.observations
        start = len(obs) - 1
        while start > 0 and obs[start - 1].points > obs[start].points:
            start -= 1
        full = obs[max(0, start + 1 - cfg.resume_stood_observations): start + 1]
        if len(full) < min(cfg.resume_stood_observations, 2) or \
                evidence_travel(full, cfg.evidence_travel) > cfg.resume_stood:
            return None
        hidden = obs[start:]
        return np.min([o.lo for o in hidden], axis=0), np.max([o.hi for o in hidden], axis=0)

    def _glimpse(self, first: Observation, lo: np.ndarray, hi: np.ndarray, beginning: list[Track],
                 movers: dict[int, str], waited: dict[int, str]) -> tuple[float, int]:
        """The footprint of the first glimpse of a car moving off from the top-view box (lo, hi) as the mover's track
        beginning with ``first`` begins: the box around ``first`` and the first observations of the other movers'
        tracks that begin in the same scan (``beginning``: the tracks that do) there (boxes grown by
        ``handover_margin``), and how many tracks' first boxes it holds. A car seen end-on as it pulls away (one that
        queued behind or ahead of the sensor) breaks into slivers, each a track of its own."""
        m = self.config.handover_margin
        firsts = [first] + [t.observations[0] for t in beginning
                            if t.observations[0] is not first and (t.id in movers or t.id in waited)
                            and overlap_from_above(t.observations[0].lo[:2] - m, t.observations[0].hi[:2] + m,
                                                   lo - m, hi + m)]
        side = np.maximum(np.max([o.hi[:2] for o in firsts], axis=0) - np.min([o.lo[:2] for o in firsts], axis=0),
                          MIN_FOOTPRINT_SIDE)
        return float(side[0] * side[1]), len(firsts)

    def _left(self, mover: Track, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Whether ``mover``'s track ended apart from the top-view box (lo, hi) it began in (grown by
        ``handover_margin``): it left that place, though its boxes, the slivers of a car seen end-on, barely travel."""
        m = self.config.handover_margin
        return not bool(overlap_from_above(mover.last.lo[:2] - m, mover.last.hi[:2] + m, lo - m, hi + m))

    def movers(self, cue: bool = False) -> dict[int, str]:
        """{track id: the evidence that makes it a mover}: 'seen through', else 'online model' (``cue``: the
        observations carry the online model's labels)."""
        out = {}
        for t in self.tracks:
            if self.seen_moving(t, cue):
                out[t.id] = SEEN_THROUGH
            elif self.labelled_moving(t):
                out[t.id] = ONLINE_MODEL
        return out
