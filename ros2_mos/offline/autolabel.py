"""``ros2-mos autolabel``: moving / static labels for a whole drive, from its past and its future.

The steps (:meth:`AutoLabeler.label`: :meth:`~AutoLabeler.track` does 1, 2 and the tracks of 3, nearly all the time;
:meth:`~AutoLabeler.decide` the rest, in under a second, and can decide the same tracks again under other settings:
``benchmarks/autolabel_rules.py``), each a stage built once:

1. **Poses**: KISS-ICP over the drive (or the drive's own poses); where the sensor stood and moved off, KISS-ICP
   backwards too (in a process of its own beside the forward pass: :mod:`~ros2_mos.offline.kiss_passes`), and the
   pass that did not fall behind (the backward one where neither travelled clearly farther:
   :mod:`~ros2_mos.offline.trajectory`). The same pass finds the returns of the vehicle carrying the sensor
   (:class:`~ros2_mos.offline.objects.VehicleReturns`).
2. **Objects and evidence**, in a window sliding over the drive: each scan is deskewed where its sweeps are skewed
   (``AutolabelConfig.deskew``, :mod:`~ros2_mos.core.deskew`), its ground removed and the rest cut into
   object-sized segments (:mod:`~ros2_mos.offline.objects`); each object's points are checked against the range
   images of scans before and after it (:mod:`~ros2_mos.offline.visibility`): where those scans saw through the
   place the object occupies now, it moved. Scans 5 or more apart are seen from their pose registered to the scan
   (:mod:`~ros2_mos.offline.viewpoints`): KISS-ICP's drifts over seconds. The online model (the one shipped for
   the sensor) labels each scan too, with these poses: a cue for what is never seen through, and for the points on
   no object that belong to one (``AutolabelConfig.cue_attach``). Per scan only the points' object ids go to disk,
   so memory stays bounded by the window, not by the drive.
3. **Tracks** through the drive (:mod:`~ros2_mos.offline.tracks`): a track with enough seen-through observations is a
   mover; so is one that the online model labels moving often enough (cars queueing in a jam).
4. **Labels**: under SemanticKITTI's convention every point of a mover is moving in every scan in which it is seen
   (also while it waits) where it overlaps a place it was seen through or moves there; under the instant
   convention only in the scans where nearby scans saw through it or its box moved (:func:`box_shift`), or for the
   online model's movers, where it labels them moving.
"""

from __future__ import annotations

import csv
import shutil
import tempfile
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ros2_mos.core.atomic import folder_kept_on_success
from ros2_mos.core.config import OdometryConfig, SensorConfig
from ros2_mos.core.deskew import check_deskew_mode, deskew, deskew_wanted, drive_motions
from ros2_mos.core.errors import ConfigError, DatasetError
from ros2_mos.core.residuals import transform_columns
from ros2_mos.core.sensor_check import mismatch_message
from ros2_mos.io.conventions import SEMANTICKITTI, check_convention, write_convention_file
from ros2_mos.io.labels import to_submission
from ros2_mos.io.semantic_kitti import write_label, write_poses, write_times
from ros2_mos.io.sweep import write_sweep_file
from ros2_mos.offline.cue import OnlineCue, OnlineCueProcess
from ros2_mos.offline.drives import Drive, given_poses, scan_place
from ros2_mos.offline.kiss_passes import BackwardPass, backward_poses, frame_path, restart
from ros2_mos.offline.objects import (
    ObjectConfig,
    VehicleReturns,
    check_numbers,
    find_objects,
    moving_clusters,
    nearest_object_within,
    voxel_clusters,
)
from ros2_mos.offline.tracks import (
    ONLINE_MODEL,
    PULLED_AWAY,
    RESUMED,
    TRACKING_FIELDS,
    WAITED,
    Observation,
    TrackConfig,
    Tracker,
    box_shift,
    overlap_from_above,
)
from ros2_mos.offline.trajectory import farther_pass, starts_from_rest
from ros2_mos.offline.viewpoints import PairRegistration, PairRegistrationConfig
from ros2_mos.offline.visibility import SeenScan

#: Fewer scans give no future or past to compare with.
MIN_SCANS = 2
#: Every this many scans, the scan is checked against the sensor (rings and field of view; ~20 ms for a 64-beam
#: scan): a drive of mixed sensors is refused before anything is written.
SENSOR_CHECK_EVERY = 10
#: Every this many scans of the forward KISS-ICP pass, its poses so far are checked for a stand and a move off, to
#: start the backward pass in its process (:class:`~ros2_mos.offline.kiss_passes.BackwardPass`) as soon as it is
#: wanted.
REST_CHECK_EVERY = 10
#: The KISS-ICP pass ``AutolabelConfig.odometry_prefer`` names, as :func:`farther_pass` names it.
ODOMETRY_PASSES = {"forward": "f", "backward": "b"}
#: How the instant convention measures an object's motion between observations: the box edges that moved together
#: (:func:`box_shift`), or the centroid (slides while the sensor passes a standing object).
INSTANT_MOTION = ("box", "centroid")
#: An observation of a mover found by the online cue moves now where the online model labelled at least this share
#: of its points moving.
CUE_MOVING_NOW = 0.5
#: ``AutolabelConfig.instant_cue_centroid``: a mover's observations whose box travelled under this speed (m/s) and
#: that no near scan saw through stood; where it stood this often, the online model must have labelled under this
#: share of them moving (its mean) for its word to count on the track
CUE_STILL_SPEED = 0.05
CUE_STILL_OBSERVATIONS = 3
CUE_STILL_ONLINE = 0.3
#: m: ... and not for an observation this close to the sensor (seen from above), whose view changes fastest as the
#: sensor passes: a parked car 3 m beside it slides its centroid
CUE_VIEW_DISTANCE = 4.0


@dataclass(frozen=True)
class AutolabelConfig:
    objects: ObjectConfig = field(default_factory=ObjectConfig)
    tracks: TrackConfig = field(default_factory=TrackConfig)
    #: Scans far apart registered to each other for visibility (:mod:`~ros2_mos.offline.viewpoints`)
    pairs: PairRegistrationConfig = field(default_factory=PairRegistrationConfig)
    #: Scans this far away (before or after) are checked for motion now (the instant convention) ...
    near_offsets: tuple[int, ...] = (-5, -2, 2, 5)
    #: ... and these too for motion at any time (SemanticKITTI's).
    far_offsets: tuple[int, ...] = (-40, -20, -10, 10, 20, 40)
    #: An observation of a mover moves now when this share of its points was seen through by a near scan ...
    instant_seen_through: float = 0.15
    #: ... or its box (or centroid) moved this fast (m/s) over the observations ``instant_span`` before and after it.
    instant_speed: float = 0.4
    instant_span: int = 5
    instant_motion: str = "box"
    instant_context: int = 10  # observations (the centroid rule only)
    #: ... the box's edges that the vehicle's shadow cut (``Observation.edge_reach`` at the drive's blind radius)
    #: not counted: a bus alongside the sensor is two objects, each with one edge pinned at the shadow, one moving
    shadow_edges: bool = True
    #: An observation of a mover is moving (SemanticKITTI's convention) only where its box, grown by this many
    #: metres, overlaps from above the box of a seen-through observation of its track (see ``_moving_ever``).
    support_margin: float = 0.3
    #: An object whose points seen through and not seen through lie apart (:func:`split_seen_apart`, its parts cut
    #: with voxels of this many metres) is two (0: never cut).
    split_voxel: float = 0.1
    use_poses: bool = False  # the drive's own poses instead of KISS-ICP
    #: KISS-ICP also over the drive backwards where the sensor stood and moved off; its poses are taken when it
    #: travelled farther than the forward pass by ``odometry_margin`` m and ``odometry_margin_share`` of the path:
    #: the forward pass falls behind where a jam moves off (:mod:`ros2_mos.offline.trajectory`)
    backward_odometry: bool = True
    odometry_margin: float = 0.75
    odometry_margin_share: float = 0.02
    #: ... and where neither pass travelled clearly farther, this one ('forward' or 'backward'): KISS-ICP lags up to
    #: 0.9 m for a few seconds as the sensor moves off in a queue and then catches up, so its path ends about as
    #: long, while backwards that moment is a stop, which it follows (:mod:`~ros2_mos.offline.trajectory`)
    odometry_prefer: str = "backward"
    #: The online model (the one shipped for the sensor) labels each scan too, with autolabel's poses: a track that
    #: visibility does not make a mover is one when the model labels it moving often enough (``TrackConfig.cue_share``).
    online_cue: bool = True
    #: m: a point on no object that the online model labels moving takes the label of the nearest object with a point
    #: this close, seen from above (0: none), where it stands clear of the ground (``objects.ground_height``) and
    #: on no cluster too long or too tall to be an object (a wall): the pieces of a mover too small, too flat or too
    #: high off the ground to be objects (a sparse sensor's rings on a van) move with it. Not the points nearer the
    #: ground: on the real drives those are road rings in front of a car, 0.1-0.2 m over the lowest point nearby.
    cue_attach: float = 2.0
    #: Points on no object that the online model labels moving, farther than ``cue_objects_apart`` m from every
    #: object seen from above (nearer ones are left to ``cue_attach``), are objects of their own where they make a
    #: cluster of ``objects.min_points`` or more (:func:`~ros2_mos.offline.objects.moving_clusters`), tracked and
    #: judged like any other object; not where the cluster stands ``cue_objects_lift`` m or less over the lowest
    #: return of the scan's other rings around it (2.5 m): that is the road, into which the model's labels bleed
    #: near a mover (real r2: ring pieces 20-35 m away). A sparse sensor sees a car or a cyclist 20-50 m away as one
    #: or two rings, too few or too flat for an object, where no other ring reaches the road near it (VLP-16
    #: validation 87.11 / 89.29 -> 87.46 / 89.62; benchmarks/autolabel.md, round 53)
    cue_objects: bool = True
    cue_objects_apart: float = 2.0
    cue_objects_lift: float = 0.15
    #: m: ... and only where the sensor's rows lie this far apart or more (its field of view over its rows: a
    #: VLP-16 from 15 m on, a VLP-32C 23 m, an OS1-64 41 m, a HDL-64E 66 m, an OS1-128 82 m; 0: anywhere); nearer, a
    #: car is seen by enough rings to be an object, and on a HDL-64E's traffic jam the clusters cost 23 % of the speed
    #: and 180 MB for nothing (round 53)
    cue_objects_spacing: float = 0.5
    #: An observation of a mover that moves now (the instant rules: seen through by a near scan, or its box
    #: travelling) has moved, so it is moving under SemanticKITTI's convention too, though its box overlaps no
    #: seen-through one: a car driving ahead at the sensor's speed hides its next place, so its last scans have no
    #: scan that sees through where it was (measured: benchmarks/autolabel.md, round 25)
    ever_from_motion: bool = True
    #: m: an observation of a mover whose box's two edges moved opposite ways, each more than this, over the
    #: observations ``instant_span`` before and after it (:func:`reshaped`: the view of it changed, so its box cannot
    #: tell whether it moved) moves now where the online model labelled at least ``CUE_MOVING_NOW`` of its points
    #: moving: a car creeping past the sensor, whose visible box grows at one end and shrinks at the other. Not where
    #: its box stood still: the model calls a queue moving while it waits (0: off; the box rule only)
    instant_cue_reshape: float = 0.2
    #: An observation of a mover whose centroid travelled ``instant_speed`` over the observations ``instant_span``
    #: before and after it moves now where the online model labelled at least ``CUE_MOVING_NOW`` of its points moving,
    #: though its box did not travel so fast (a car slowing to a stop or moving off, whose box the view of it stretches
    #: and shrinks; not within :data:`CUE_VIEW_DISTANCE` of the sensor), on a track where the model is not wrong while
    #: it stands: where its box stood still (:data:`CUE_STILL_SPEED`) and no near scan saw through it in
    #: :data:`CUE_STILL_OBSERVATIONS` observations or more, the model labelled under :data:`CUE_STILL_ONLINE` of it
    #: moving. Without these conditions the VLP-16 model, which labels waiting cars moving, took the centroids a
    #: changing view slides (VLP-16 validation 86.44 -> 85.97 instant; benchmarks/autolabel.md, round 42).
    instant_cue_centroid: bool = True
    #: An observation of a mover on the online model's word alone (no scan saw through its place often enough)
    #: moves now where the model labels at least ``CUE_MOVING_NOW`` of it moving and the instant rules for every
    #: mover say so too (a near scan saw through it, its box travelled or changed shape), but not by its centroid
    #: (``instant_cue_centroid``: the centroid of a car that waits slides as the sensor passes it, and the model
    #: calls that car moving 3-5 m away); off: wherever the model says so. The OS1-64 and VLP-32C models label a car
    #: that waits 50 m away moving: once such a car drove off, all its waiting scans moved now (OS1-64 suite
    #: benchmark-9102 instant 84.5 -> 87.6; benchmarks/autolabel.md, round 54)
    instant_cue_motion: bool = True
    #: Each scan deskewed before objects and visibility (:mod:`~ros2_mos.core.deskew`: its points moved into the
    #: frame of the scan's pose by the motion between the poses around it, each at its firing time: from the cloud's
    #: own per-point times where a bag's clouds have them, else from its azimuth): 'on', 'off', or 'auto': where the
    #: drive says its sweeps are skewed (a folder's ``sweep.txt``, :mod:`ros2_mos.io.sweep`, which the simulator
    #: writes; a bag whose clouds carry per-point times). Sweeps no driver compensated (KITTI raw's) disagree
    #: between scans far apart where an object's bearing changed, and thin static posts the sensor passes are seen
    #: through (real r2: 49 of 103 movers); a sweep that is not skewed (SemanticKITTI's, the simulator's by default)
    #: is bent by it the other way (one simulated drive 93.3 -> 10.3): so never on without the drive's or the
    #: user's word (benchmarks/autolabel.md, round 39)
    deskew: str = "auto"
    #: Drives of this many scans or more have their scan pairs registered (:mod:`~ros2_mos.offline.viewpoints`) and
    #: the online cue computed (:mod:`~ros2_mos.offline.cue`) each in a process of its own, up to ``process_lead``
    #: scans ahead of the scan being labelled, while this one finds objects, and the backward KISS-ICP pass beside
    #: the forward one (:mod:`~ros2_mos.offline.kiss_passes`; 0: never); shorter drives in this process, where
    #: starting one (~0.6 s) costs more than it saves
    processes_from: int = 50
    process_lead: int = 8

    def __post_init__(self) -> None:
        offsets = (*self.near_offsets, *self.far_offsets)
        if not offsets or 0 in offsets:
            raise ConfigError("autolabel: offsets must be non-zero scan offsets")
        if self.odometry_prefer not in ODOMETRY_PASSES:
            raise ConfigError(f"autolabel: odometry_prefer must be one of {', '.join(ODOMETRY_PASSES)}, got "
                              f"{self.odometry_prefer!r}")
        check_deskew_mode(self.deskew, "autolabel")
        if self.instant_motion not in INSTANT_MOTION:
            raise ConfigError(f"autolabel: instant_motion must be one of {', '.join(INSTANT_MOTION)}, got "
                              f"{self.instant_motion!r}")
        check_numbers(self, "autolabel", zero_ok=("instant_context", "support_margin", "split_voxel", "cue_attach",
                                                  "cue_objects_apart", "cue_objects_lift", "cue_objects_spacing",
                                                  "odometry_margin", "odometry_margin_share", "instant_cue_reshape",
                                                  "processes_from", "process_lead"),
                      at_most_one=("instant_seen_through",), whole=("processes_from", "process_lead"))

    def in_processes(self, scans: int) -> bool:
        """Whether a drive of ``scans`` scans has its pairs, cue and backward KISS-ICP pass in processes of their own
        (``processes_from``)."""
        return 0 < self.processes_from <= scans

    @property
    def window(self) -> int:
        return max(abs(o) for o in (*self.near_offsets, *self.far_offsets))


@dataclass
class AutolabelResult:
    name: str
    scans: int
    poses: np.ndarray
    stamps: np.ndarray  # (N,) seconds since the first scan
    tracker: Tracker
    movers: dict[int, str]  # track id -> the evidence that makes it a mover
    points: list[int]  # per scan
    moving_points: list[int] = field(default_factory=list)  # per scan, in the convention written
    moving_now: set[tuple[int, int]] = field(default_factory=set)  # (scan, object) of movers moving in that scan
    moving_ever: set[tuple[int, int]] = field(default_factory=set)  # (scan, object) of movers where they moved
    cue_model: str = ""  # the online model used as a cue ("" without one)
    cue_skipped: int = 0  # scans the online model refused (ScanError): no cue for them
    #: the KISS-ICP pass the poses are: 'f' forwards, 'b' backwards ("" with the drive's own poses or one pass)
    odometry_followed: str = ""
    #: m: the nearest the sensor saw anything over the drive (:func:`blind_radius`): where the vehicle's shadow begins
    blind_radius: float = float("inf")
    deskewed: bool = False  # the scans were deskewed (``AutolabelConfig.deskew``)


ProgressFn = Callable[[str, int], None]  # (stage, scans done in it)


def progress_steps(scans: int, config: AutolabelConfig) -> int:
    """How many progress steps labelling a drive of ``scans`` scans reports: poses, objects and labels per scan, and
    the backward KISS-ICP pass where there is one."""
    passes = 4 if config.backward_odometry and not config.use_poses else 3
    return passes * scans


#: KISS-ICP for autolabel's poses: on one thread, as the pair registration (``PairRegistrationConfig.threads``), so
#: that a drive labelled twice gets the same labels: with every core its sums add up in an order that varies with the
#: machine's load (benchmarks/autolabel.md, round 51). KISS-ICP fixes its threads for the whole process when its first
#: registration is built: the CLI's autolabel builds the pairs' first, each worker process its own; a script that ran
#: the online pipeline (every core) before it labels with KISS-ICP on every core.
REPEATABLE_ODOMETRY = OdometryConfig(threads=1)


class AutoLabeler:
    """Labels one drive at a time; the stages are built once."""

    def __init__(self, sensor: SensorConfig, config: AutolabelConfig = AutolabelConfig(),
                 odometry: OdometryConfig = REPEATABLE_ODOMETRY, model: str | Path | None = None) -> None:
        from ros2_mos.core.inference import shipped_models

        self.sensor, self.config, self.odometry_config = sensor, config, odometry
        #: The online cue's model: ``model``, else the one shipped for the sensor; None without the cue (also for a
        #: sensor that no shipped model was trained for).
        self.cue_model = (Path(model) if model is not None else shipped_models().get(sensor.name)) \
            if config.online_cue else None

    # -- the steps -------------------------------------------------------------------------------------------
    def label(self, drive: Drive, workdir: Path, progress: ProgressFn = lambda stage, n: None) -> AutolabelResult:
        """Run steps 1-4 over ``drive``; per-scan object ids are kept in ``workdir`` for :func:`scan_labels`."""
        return self.decide(self.track(drive, workdir, progress))

    def track(self, drive: Drive, workdir: Path, progress: ProgressFn = lambda stage, n: None) -> AutolabelResult:
        """Steps 1 and 2 over ``drive`` and the tracks of step 3: its poses, objects, evidence and tracks; nothing
        decided yet (no movers: :meth:`decide`). Per-scan object ids are kept in ``workdir``."""
        n = len(drive)
        if n < MIN_SCANS:
            raise DatasetError(f"{drive.name}: {n} scan(s); autolabel needs at least {MIN_SCANS} (past and future)")
        vehicle = VehicleReturns(self.config.objects)
        tracker = Tracker(self.config.tracks)
        # started first, so that the processes' start (~1 s) overlaps the poses
        pairs, online = self._helpers(n)
        try:
            poses, stamps, sizes, followed = self._poses(drive, vehicle, workdir, progress)
            motions = drive_motions(poses, stamps) if self.deskews(drive) else None
            blind = self._objects_and_evidence(drive, poses, stamps, vehicle.cells(), tracker, workdir, progress,
                                               pairs, online, motions)
        finally:
            pairs.close()
            if online is not None:
                online.close()
        return AutolabelResult(drive.name, n, poses, stamps, tracker, {}, sizes,
                               cue_model=self.cue_model.name if self.cue_model is not None else "",
                               cue_skipped=online.skipped if online is not None else 0, odometry_followed=followed,
                               blind_radius=blind, deskewed=motions is not None)

    def decide(self, result: AutolabelResult) -> AutolabelResult:
        """The rest of step 3 and step 4 on ``result``'s tracks (:meth:`track`) under this labeller's settings: which
        are movers, and where they move under each convention. Its tracker's tracks are cut where they jumped
        (:meth:`Tracker.cut_jumps`) and its settings become this labeller's: to decide again under other settings
        (any but those the tracks were built with, :data:`~ros2_mos.offline.tracks.TRACKING_FIELDS`), pass a copy
        (``copy.deepcopy``)."""
        tracker = result.tracker
        built = {name: getattr(tracker.config, name) for name in TRACKING_FIELDS}
        wanted = {name: getattr(self.config.tracks, name) for name in TRACKING_FIELDS}
        if built != wanted:
            changed = ", ".join(f"{k} {built[k]!r} -> {wanted[k]!r}" for k in built if built[k] != wanted[k])
            raise ConfigError(f"autolabel: the tracks were built with other tracking settings ({changed}); track the "
                              "drive again to change them")
        tracker.config = self.config.tracks
        tracker.cut_jumps(result.stamps, result.poses[:, :2, 3])
        movers = tracker.movers(cue=self.cue_model is not None)
        movers.update(tracker.handovers(movers))
        movers.update(tracker.resumptions(movers))
        movers.update(tracker.pulling_away(movers, result.poses[:, :2, 3]))
        movers.update(tracker.seen_leaving(movers))
        result.movers = movers
        result.moving_ever = self._moving_ever(result)
        now = self._moving_now(result)
        if self.config.ever_from_motion:
            result.moving_ever |= now
        result.moving_now = now & result.moving_ever  # moving now: where it moved at all
        return result

    def deskews(self, drive: Drive) -> bool:
        """Whether ``drive``'s scans are deskewed (``AutolabelConfig.deskew``; 'auto': where the drive says its
        sweeps are skewed)."""
        return deskew_wanted(self.config.deskew, drive.skewed)

    def _poses(self, drive: Drive, vehicle: VehicleReturns, workdir: Path,
               progress: ProgressFn) -> tuple[np.ndarray, np.ndarray, list[int], str]:
        """Step 1: the poses (KISS-ICP's forwards, and backwards: in a process of its own beside the forward pass
        (:class:`~ros2_mos.offline.kiss_passes.BackwardPass`), else here over the clouds the forward pass kept in
        ``workdir``; or the drive's own), the stamps, the point counts and which KISS-ICP pass the poses are ('f' or
        'b': :func:`farther_pass`; "" with one pass: the backward one runs only where the sensor stood and moved off);
        each scan's returns near the sensor go to ``vehicle``."""
        from ros2_mos.core.odometry import KissIcpOdometry

        use_own = self.config.use_poses
        own = given_poses(drive, "--use-poses") if use_own else None
        odometry = None if use_own else KissIcpOdometry(self.odometry_config)
        wanted = not use_own and self.config.backward_odometry
        beside = BackwardPass.start(drive, self.odometry_config, workdir) if wanted and self.config.in_processes(
            len(drive)) else None
        keep = wanted and beside is None
        try:
            poses, stamps, sizes = [], [], []
            for scan in drive:
                if len(scan.points) == 0:
                    raise DatasetError(f"{scan_place(drive, scan.index)}: no finite points; fix or remove that scan "
                                       "and run again")
                problem = mismatch_message(scan.points, self.sensor) if scan.index % SENSOR_CHECK_EVERY == 0 \
                    else None
                if problem:
                    raise DatasetError(f"{drive.name} scan {scan.index}: {problem}")
                if odometry is not None:
                    poses.append(odometry.register(scan.points))
                    if keep:
                        np.save(frame_path(workdir, scan.index), odometry.last_frame)
                vehicle.add(scan.points, poses[-1] if odometry is not None else own[scan.index])
                stamps.append(scan.stamp)
                sizes.append(len(scan.points))
                if beside is not None and not beside.going and scan.index % REST_CHECK_EVERY == 0 \
                        and starts_from_rest(poses, stamps):
                    beside.go()  # the sensor stood and moved off: the backward pass is wanted (the poses' restart
                    # below may still change that: then its poses are not asked for)
                progress("poses", 1)
            if use_own:
                return np.asarray(own[: len(stamps)], np.float64), np.asarray(stamps), sizes, ""
            forward = restart((scan.points for scan in drive), np.asarray(poses, np.float64), self.odometry_config)
            stamps = np.asarray(stamps)
            if not wanted:
                return forward, stamps, sizes, ""
            if not starts_from_rest(forward, stamps):  # nothing for KISS-ICP to fall behind at
                progress("backward", len(forward))
                return forward, stamps, sizes, ""
            if beside is not None:
                backward = beside.poses()
                progress("backward", len(forward))
            else:
                backward = backward_poses(workdir, len(forward), self.odometry_config,
                                          lambda done: progress("backward", done))
            poses, followed = farther_pass(forward, backward, self.config.odometry_margin,
                                           self.config.odometry_margin_share,
                                           prefer=ODOMETRY_PASSES[self.config.odometry_prefer])
            return poses, stamps, sizes, followed
        finally:
            if beside is not None:
                beside.close()
            for path in workdir.glob("kiss*.npy"):  # the clouds kept for the backward pass
                path.unlink()

    def _helpers(self, n: int) -> tuple[PairRegistration, OnlineCue | None]:
        """The scan pairs' registration and the online cue (None without one) for a drive of ``n`` scans: each in a
        process of its own from ``processes_from`` scans on."""
        own = self.config.in_processes(n)
        offsets = (*self.config.near_offsets, *self.config.far_offsets)
        pairs = PairRegistration.for_drive(self.config.pairs, offsets, n, self.sensor.height, own)
        if self.cue_model is None:
            return pairs, None
        try:
            return pairs, (OnlineCueProcess if own else OnlineCue)(self.cue_model, self.sensor)
        except BaseException:
            pairs.close()
            raise

    def _objects_and_evidence(self, drive: Drive, poses: np.ndarray, stamps: np.ndarray, vehicle: np.ndarray,
                              tracker: Tracker, workdir: Path, progress: ProgressFn, pairs: PairRegistration,
                              online: OnlineCue | None, motions: np.ndarray | None = None) -> float:
        """Steps 2 and 3 over the drive, each scan deskewed by its ``motions`` row where given
        (:func:`~ros2_mos.core.deskew.scan_motions`), its pairs registered by ``pairs`` and its cue from ``online``
        (:meth:`_helpers`); returns the drive's blind radius (:func:`blind_radius`)."""
        window = self.config.window
        n = len(poses)
        seen: dict[int, SeenScan] = {}
        pending: deque[tuple[int, np.ndarray]] = deque()
        last_stamp: float | None = None
        scans = iter(drive)
        loaded = 0
        blind = float("inf")
        lead = self.config.process_lead if self.config.in_processes(n) else 0
        for k in range(n):
            while loaded < min(n, k + window + 1 + lead):  # the window ahead of scan k, and the processes' lead
                scan = next(scans)
                i = scan.index
                cloud = scan.points if motions is None else deskew(scan.points, motions[i], scan.phase)
                seen[i] = SeenScan(cloud, poses[i], self.sensor)
                pending.append((i, cloud))
                pairs.add(i, cloud, poses[i])
                if online is not None:
                    online.add(i, cloud, scan.intensity, float(stamps[i]), poses[i])
                loaded += 1
            for old in [i for i in seen if i < k - window]:
                del seen[old]
            index, points = pending.popleft()
            assert index == k
            pairs.forget_before(k - window)
            pairs.wait_for(k)
            labelled = online.labels(k) if online is not None else None
            point_object, observations, nearest = self._observe(k, points, poses[k], vehicle, seen, pairs,
                                                                labelled)
            blind = min(blind, nearest)
            tracker.add_scan(k, float(stamps[k]), last_stamp, observations)
            last_stamp = float(stamps[k])
            np.save(workdir / f"{k:06d}.npy", point_object)
            progress("objects", 1)
        return blind

    def _observe(self, k: int, points: np.ndarray, pose: np.ndarray, vehicle: np.ndarray, seen: dict[int, SeenScan],
                 pairs: PairRegistration,
                 labelled: np.ndarray | None = None) -> tuple[np.ndarray, list[Observation], float]:
        """Scan k's objects (per point the object whose label it takes, :func:`label_objects`; none on the
        ``vehicle``'s cells), one observation per object, each scan of the window seen from the pose ``pairs`` refined
        for it where it did (``labelled``: the online model's moving labels of the scan's points, for the cue), and
        the scan's :func:`blind_radius`."""
        cfg = self.config
        found = find_objects(points, cfg.objects, vehicle, self.sensor)
        if labelled is not None and cfg.cue_objects:
            found = moving_clusters(points, found, labelled, cfg.objects, cfg.cue_objects_lift, cfg.cue_objects_apart,
                                    self.sensor, cfg.cue_objects_spacing)
        on_object = np.flatnonzero((found.point_object >= 0) & ~found.attached)
        obj = found.point_object[on_object]
        world = np.ascontiguousarray(transform_columns(points[on_object], pose).T)
        through = {o: seen[k + o].seen_through(world, pairs.viewpoint_pose(k, pose, k + o))
                   for o in (*cfg.near_offsets, *cfg.far_offsets)
                   if k + o in seen}  # per offset, per point on an object: seen through by that scan
        seen_any = np.logical_or.reduce(list(through.values())) if through else np.zeros(len(obj), bool)
        n_objects = found.n_objects
        if cfg.split_voxel > 0:  # a cyclist merged with the parked car beside it: two objects
            obj, n_objects = split_seen_apart(world, obj, seen_any, n_objects, cfg.split_voxel, cfg.objects.min_points)
            point_object = found.point_object.copy()
            point_object[on_object] = obj
        else:
            point_object = found.point_object
        counts = np.bincount(obj, minlength=n_objects)
        near = np.zeros(n_objects)
        far = np.zeros(n_objects)
        for offsets, best in ((cfg.near_offsets, near), (cfg.far_offsets, far)):
            for o in offsets:
                if o in through:
                    np.maximum(best, np.bincount(obj[through[o]], minlength=n_objects) / counts, out=best)
        np.maximum(far, near, out=far)
        sums = np.stack([np.bincount(obj, world[:, i], n_objects) for i in range(3)], axis=1)
        centroids = sums / counts[:, None]
        distance = np.hypot(centroids[:, 0] - pose[0, 3], centroids[:, 1] - pose[1, 3])
        # float32 like the points: ufunc.at casting float32 into float64 takes numpy's slow path
        lo = np.full((n_objects, 3), np.inf, np.float32)
        hi = np.full((n_objects, 3), -np.inf, np.float32)
        for i in range(3):
            np.minimum.at(lo[:, i], obj, world[:, i])
            np.maximum.at(hi[:, i], obj, world[:, i])
        lo, hi = lo.astype(np.float64), hi.astype(np.float64)
        ranges = np.sqrt(np.einsum("ij,ij->i", points[:, :3], points[:, :3]))  # from the sensor
        reach = edge_reach(ranges[on_object], world, obj, lo, hi)
        online = np.zeros(n_objects) if labelled is None else \
            np.bincount(obj, labelled[on_object].astype(np.float64), n_objects) / counts
        observations = [Observation(k, j, centroids[j], int(counts[j]), lo[j], hi[j], float(near[j]), float(far[j]),
                                    float(online[j]), j >= found.n_objects, float(distance[j]), reach[j])
                        for j in range(n_objects)]
        if labelled is not None and cfg.cue_attach > 0:
            # Clear of the ground and on no wall: the model's moving labels bleed into the road around a mover and
            # into the wall behind a pedestrian
            clear = found.height_above_ground > cfg.objects.ground_height
            point_object = label_objects(points, point_object, (labelled > 0) & clear & ~found.structure,
                                         cfg.cue_attach)
        return point_object, observations, blind_radius(ranges)

    def _moving_now(self, result: AutolabelResult) -> set[tuple[int, int]]:
        """The observations of movers that move in their own scan (the instant convention): seen through by a near
        scan, labelled moving by the online model where their box changed shape (``instant_cue_reshape``), or moving
        at ``instant_speed`` or more: their box (:func:`box_shift`), or with
        ``instant_motion='centroid'`` their centroid within ``instant_context`` observations of one that was seen
        through (the centroid of a car that waits long slides as the sensor passes it; the box rule needs no such
        guard, and with it a car that leaves at the very end of a drive, with no later scan to see through its old
        place, still counts). A track that waited, then left (:meth:`Tracker.handovers`) is judged by the same
        rules: it stands while it waits and moves as it moves off. A mover on the online model's word alone is judged
        by the same rules, but for the centroid's, where the model labels it moving (``instant_cue_motion``)."""
        cfg = self.config
        out = set()
        for tid, evidence in result.movers.items():
            obs = result.tracker.tracks[tid].observations
            if evidence == ONLINE_MODEL and not cfg.instant_cue_motion:
                out.update((o.scan, o.obj) for o in obs if o.online >= CUE_MOVING_NOW)
                continue
            t = result.stamps[[o.scan for o in obs]]
            m = len(obs)
            index = np.arange(m)
            before = np.maximum(index - cfg.instant_span, 0)
            after = np.minimum(index + cfg.instant_span, m - 1)
            dt = np.maximum(t[after] - t[before], 1e-3)

            def rate(shift: np.ndarray) -> np.ndarray:  # m/s over each observation's span; 0 where it has none
                return np.where(after > before, np.linalg.norm(shift, axis=1) / dt, 0.0)

            told = np.array([o.online >= CUE_MOVING_NOW for o in obs])
            centroid = np.array([o.centroid[:2] for o in obs])
            box = cfg.instant_motion == "box"
            if box:
                lo = np.array([o.lo[:2] for o in obs])
                hi = np.array([o.hi[:2] for o in obs])
                cut_lo = cut_hi = None
                if cfg.shadow_edges and np.isfinite(result.blind_radius):  # a cut edge (in either box) does not count
                    cut = np.array([o.edge_reach for o in obs]) <= result.blind_radius + SHADOW_MARGIN
                    cut_lo, cut_hi = cut[before, 0] | cut[after, 0], cut[before, 1] | cut[after, 1]
                shift = box_shift(lo[before], hi[before], lo[after], hi[after], cut_lo, cut_hi)
                context = np.ones(m, bool)
                labelled = reshaped(lo[before], hi[before], lo[after], hi[after], cfg.instant_cue_reshape) & told
            else:
                shift = centroid[after] - centroid[before]
                seen = np.flatnonzero([result.tracker.seen_through(o) for o in obs])
                context = (np.abs(index[:, None] - seen[None, :]) <= cfg.instant_context).any(axis=1) if len(seen) \
                    else np.zeros(m, bool)
                labelled = np.zeros(m, bool)
            speed = rate(shift)
            near = np.array([o.near >= cfg.instant_seen_through for o in obs])
            word = evidence == ONLINE_MODEL  # a mover on the model's word alone: the rules above where it says so
            if box and cfg.instant_cue_centroid and not word and model_right_where_it_stood(obs, speed, near):
                beside = np.array([o.distance < CUE_VIEW_DISTANCE for o in obs])
                labelled |= (rate(centroid[after] - centroid[before]) >= cfg.instant_speed) & told & ~beside
            moving = near | ((speed >= cfg.instant_speed) & context) | labelled
            if word:
                moving &= told
            out.update((o.scan, o.obj) for o, flag in zip(obs, moving) if flag)
        return out

    def _moving_ever(self, result: AutolabelResult) -> set[tuple[int, int]]:
        """The observations of movers that overlap, from above, where their track was seen through (SemanticKITTI's
        convention): where it waited is where it then moved from or to, while a static pole or parked car that the
        track ran into after losing the mover stands apart from all of that."""
        cfg = self.config
        out = set()
        for tid, evidence in result.movers.items():
            obs = result.tracker.tracks[tid].observations
            if evidence in (ONLINE_MODEL, PULLED_AWAY):  # movers on the online model's word: every observation
                out.update((o.scan, o.obj) for o in obs)
                continue
            lo = np.array([o.lo[:2] for o in obs]) - cfg.support_margin
            hi = np.array([o.hi[:2] for o in obs]) + cfg.support_margin
            # A track that waited, then left (Tracker.handovers): where it stood when it ended, too; a mover seen again
            # where it stood (Tracker.resumptions): where it was first seen again.
            support = np.array([result.tracker.seen_through(o) for o in obs])
            if evidence in (WAITED, RESUMED):
                support[-1 if evidence == WAITED else 0] = True
            overlap = overlap_from_above(lo[:, None, :], hi[:, None, :], lo[None, support, :], hi[None, support, :])
            out.update((o.scan, o.obj) for o, supported in zip(obs, overlap.any(axis=1)) if supported)
        return out

    # -- output ----------------------------------------------------------------------------------------------
    def moving_objects(self, result: AutolabelResult, scan: int, n_objects: int, convention: str) -> np.ndarray:
        """(n_objects,) bool: which of scan ``scan``'s objects are moving under ``convention``."""
        moving = np.zeros(n_objects, bool)
        for j in range(n_objects):
            if convention == SEMANTICKITTI:
                moving[j] = (scan, j) in result.moving_ever
            else:
                moving[j] = (scan, j) in result.moving_now
        return moving


def model_right_where_it_stood(obs: list[Observation], speed: np.ndarray, near: np.ndarray) -> bool:
    """Whether the online model labelled a track's observations that stood (``speed``, its box's, under
    :data:`CUE_STILL_SPEED`, and not seen through by a near scan, ``near``) mostly static: under
    :data:`CUE_STILL_ONLINE` on average, or it stood fewer than :data:`CUE_STILL_OBSERVATIONS` times."""
    stood = (speed < CUE_STILL_SPEED) & ~near
    if stood.sum() < CUE_STILL_OBSERVATIONS:
        return True
    return float(np.mean([o.online for o, s in zip(obs, stood) if s])) < CUE_STILL_ONLINE


def reshaped(lo0: np.ndarray, hi0: np.ndarray, lo1: np.ndarray, hi1: np.ndarray, least: float) -> np.ndarray:
    """(M,) whether the boxes (lo0, hi0) -> (lo1, hi1) (``(M, D)`` corners) changed shape rather than place: on some
    axis both edges moved more than ``least`` m, opposite ways (never with ``least`` 0)."""
    d_lo, d_hi = lo1 - lo0, hi1 - hi0
    if least <= 0:
        return np.zeros(len(d_lo), bool)
    return ((np.sign(d_lo) != np.sign(d_hi)) & (np.abs(d_lo) > least) & (np.abs(d_hi) > least)).any(axis=1)


#: The drive's blind radius (:func:`blind_radius`) is the range of a scan's this-many-th nearest return (a few stray
#: returns nearer do not count), the least over the drive; an object's box edge whose points (those within
#: ``SHADOW_EDGE`` metres of it) lie, ``SHADOW_SHARE`` of them, within ``SHADOW_MARGIN`` metres of it is the vehicle's
#: shadow's cut (:func:`edge_reach`); an object's own side facing the sensor reaches farther out.
SHADOW_RANK = 20
SHADOW_MARGIN = 0.1
SHADOW_EDGE = 0.15
SHADOW_SHARE = 0.9


def blind_radius(ranges: np.ndarray) -> float:
    """m: how near the sensor a scan has returns (``ranges``: per point, from the sensor): its
    :data:`SHADOW_RANK`-th nearest (inf if fewer)."""
    if len(ranges) <= SHADOW_RANK:
        return float("inf")
    return float(np.partition(ranges, SHADOW_RANK)[SHADOW_RANK])


def edge_reach(ranges: np.ndarray, world: np.ndarray, obj: np.ndarray, lo: np.ndarray,
               hi: np.ndarray) -> np.ndarray:
    """(n, 2, 2) per object (boxes ``lo``, ``hi``), edge (lower, upper) and axis (x, y): the range from the sensor
    within which :data:`SHADOW_SHARE` of its points within :data:`SHADOW_EDGE` of that edge lie (inf: none).
    ``ranges``, ``world``, ``obj``: per point on an object, its range from the sensor, world position and object.

    The sensor sees nothing nearer than its blind radius (the vehicle's body, or its minimum range), so an object
    alongside (a bus in the next lane) is cut there in two, and the cut's points all lie at that radius.
    """
    n = len(lo)
    reach = np.full((n, 2, 2), np.inf)
    for side, edge in enumerate((lo, hi)):
        for axis in (0, 1):
            at = np.flatnonzero(np.abs(world[:, axis] - edge[obj, axis]) <= SHADOW_EDGE)
            if not len(at):
                continue
            order = at[np.lexsort((ranges[at], obj[at]))]  # object by object, nearest first
            counts = np.bincount(obj[order], minlength=n)
            has = np.flatnonzero(counts)
            starts = np.cumsum(counts) - counts
            pick = starts[has] + np.ceil(SHADOW_SHARE * counts[has]).astype(np.int64) - 1
            reach[has, side, axis] = ranges[order[pick]]
    return reach


#: :func:`split_seen_apart`: a part of an object is its seen-through part where at least this share of its points
#: was seen through, and the rest is cut off only where at most ``SPLIT_REST_SEEN`` of it was.
SPLIT_PART_SEEN = 0.5
SPLIT_REST_SEEN = 0.1


def split_seen_apart(world: np.ndarray, obj: np.ndarray, seen: np.ndarray, n_objects: int, voxel: float,
                     min_points: int) -> tuple[np.ndarray, int]:
    """Objects (``obj``: per point, world ``world``) made of a part seen through by other scans and a part that was
    not, the two apart from above, cut in two: a cyclist who passes a parked car 0.2-0.8 m away is one voxel cluster
    with it. The parts: clusters of ``voxel`` (finer than the objects') with at least ``SPLIT_PART_SEEN`` of their
    points seen through, and the rest, which must hold at most ``SPLIT_REST_SEEN`` seen through; each of
    ``min_points`` or more. A car seen through only where it was a moment before (its rear) stays one: its parts
    touch. Returns the new per-point ids (the seen parts numbered from ``n_objects`` on) and the object count."""
    counts = np.bincount(obj, minlength=n_objects)
    seen_counts = np.bincount(obj[seen], minlength=n_objects)
    out = obj.copy()
    candidates = np.flatnonzero((seen_counts >= min_points) & (counts - seen_counts >= min_points))
    if len(candidates) == 0:
        return out, n_objects
    # Every candidate's parts in one call (an object's voxels never join another's), grouped by object.
    members = np.flatnonzero(np.isin(obj, candidates))  # indices of the candidates' points, object by object
    members = members[np.argsort(obj[members], kind="stable")]
    sub = voxel_clusters(world[members], voxel, groups=obj[members])
    part_of_member = (np.bincount(sub, seen[members]) / np.bincount(sub) >= SPLIT_PART_SEEN)[sub]
    starts = np.searchsorted(obj[members], candidates)
    for j, start, end in zip(candidates.tolist(), starts.tolist(), [*starts[1:].tolist(), len(members)]):
        idx, part = members[start:end], part_of_member[start:end]
        a, b = idx[part], idx[~part]
        if len(a) < min_points or len(b) < min_points or seen[b].mean() > SPLIT_REST_SEEN:
            continue
        lo_a, hi_a = world[a, :2].min(axis=0), world[a, :2].max(axis=0)
        lo_b, hi_b = world[b, :2].min(axis=0), world[b, :2].max(axis=0)
        if overlap_from_above(lo_a, hi_a, lo_b, hi_b):
            continue
        out[a] = n_objects
        n_objects += 1
    return out, n_objects


def label_objects(points: np.ndarray, point_object: np.ndarray, labelled_moving: np.ndarray,
                  reach: float) -> np.ndarray:
    """Per point, the object whose label it takes: its own (``point_object``), or for a point on no object that the
    online model labelled moving (``labelled_moving``), the nearest object with a point within ``reach`` m of it seen
    from above (:func:`~ros2_mos.offline.objects.nearest_object_within`); -1 for none. The objects' evidence and
    tracks do not change."""
    out = point_object.copy()
    loose = np.flatnonzero((point_object < 0) & labelled_moving)
    out[loose] = nearest_object_within(points, loose, point_object, reach)
    return out


def scan_labels(labeler: AutoLabeler, result: AutolabelResult, workdir: Path, scan: int,
                convention: str) -> np.ndarray:
    """Per point of ``scan``: moving?"""
    point_object = np.load(workdir / f"{scan:06d}.npy")
    n_objects = int(point_object.max()) + 1 if len(point_object) else 0
    moving_obj = labeler.moving_objects(result, scan, n_objects, convention)
    return (point_object >= 0) & moving_obj[np.maximum(point_object, 0)] if n_objects else np.zeros(
        len(point_object), bool)


def autolabel_drive(drive: Drive, out_root: str | Path, sensor: SensorConfig, convention: str = SEMANTICKITTI,
                    config: AutolabelConfig = AutolabelConfig(), png: bool = False,
                    progress: ProgressFn = lambda stage, n: None) -> tuple[Path, AutolabelResult]:
    """Label ``drive`` and write ``OUT_ROOT/sequences/<name>/``: ``predictions/*.label`` (251 moving / 9 static in
    ``convention``), ``poses.txt``, ``times.txt``, ``label_convention.txt``, ``sweep.txt`` (``skewed`` where the scans
    were deskewed, else ``compensated``: how the labels took the sweeps), ``objects.csv`` (the movers) and, with
    ``png``, ``movers.png``.

    Everything is written under a temporary name and renamed when complete: an error leaves nothing behind.
    """
    check_convention(convention)
    final = Path(out_root) / "sequences" / drive.name
    if final.exists():
        raise DatasetError(f"{final} already exists; remove it or choose another --out")
    with folder_kept_on_success(final.parent):
        partial = Path(tempfile.mkdtemp(prefix=f".{drive.name}.partial-", dir=final.parent))
        try:
            workdir = partial / "objects"
            workdir.mkdir()
            labeler = AutoLabeler(sensor, config)
            result = labeler.label(drive, workdir, progress)
            names = drive.scan_names
            bev = BirdsEye() if png else None
            for k, scan in enumerate(drive):  # read again: each label file has one label per stored point
                moving = scan_labels(labeler, result, workdir, k, convention)
                full = np.zeros(scan.stored, bool)
                full[scan.kept] = moving
                write_label(partial / "predictions" / f"{names[k]}.label", to_submission(full))
                result.moving_points.append(int(moving.sum()))
                if bev is not None:
                    tracks = track_ids(result, workdir, k)
                    bev.add(scan.points, result.poses[k], tracks if convention == SEMANTICKITTI
                            else np.where(moving, tracks, -1), k)
                progress("labels", 1)
            shutil.rmtree(workdir)
            write_poses(partial / "poses.txt", result.poses)
            write_times(partial / "times.txt", result.stamps)
            write_convention_file(partial, convention)
            write_sweep_file(partial, skewed=result.deskewed)  # how the labels took the sweeps (``map`` follows it)
            write_objects_table(partial / "objects.csv", result)
            if bev is not None:
                bev.write(partial / "movers.png", f"{drive.name}: {len(result.movers)} movers ({convention})")
            partial.rename(final)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            raise
    return final, result


def track_ids(result: AutolabelResult, workdir: Path, scan: int) -> np.ndarray:
    """Per point of ``scan``: the id of the mover it belongs to, -1 for the rest."""
    point_object = np.load(workdir / f"{scan:06d}.npy")
    n_objects = int(point_object.max()) + 1 if len(point_object) else 0
    ids = np.full(n_objects + 1, -1, np.int64)
    for j in range(n_objects):
        tid = result.tracker.track_of.get((scan, j))
        if tid is not None and tid in result.movers:
            ids[j] = tid
    return ids[np.where(point_object >= 0, point_object, n_objects)]


def write_objects_table(path: Path, result: AutolabelResult) -> None:
    """One row per mover: id, first and last scan, observations, points, path length, peak speed, median size, and
    the evidence that made it a mover."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["id", "first_scan", "last_scan", "scans", "points", "path_m", "peak_speed_mps",
                    "length_m", "width_m", "height_m", "evidence"])
        for tid in sorted(result.movers):
            t = result.tracker.tracks[tid]
            size = np.median(np.array([o.size for o in t.observations]), axis=0)
            length, width = max(size[0], size[1]), min(size[0], size[1])
            w.writerow([tid, t.observations[0].scan, t.last.scan, len(t.observations),
                        sum(o.points for o in t.observations), f"{t.path_length():.1f}",
                        f"{t.peak_speed(result.stamps):.1f}", f"{length:.1f}", f"{width:.1f}", f"{size[2]:.1f}",
                        result.movers[tid]])


class BirdsEye:
    """A bird's-eye picture of a drive: static points grey (thinned), movers coloured by track, the path black."""

    STATIC_EVERY = 5  # scans
    STATIC_STRIDE = 7  # points

    def __init__(self) -> None:
        self.static: list[np.ndarray] = []
        self.moving: list[np.ndarray] = []
        self.tracks: list[np.ndarray] = []
        self.path: list[np.ndarray] = []

    def add(self, points: np.ndarray, pose: np.ndarray, tracks: np.ndarray, k: int) -> None:
        world = transform_columns(points, pose)[:2].T
        self.path.append(np.asarray(pose)[:2, 3])
        mover = tracks >= 0
        self.moving.append(world[mover])
        self.tracks.append(tracks[mover])
        if k % self.STATIC_EVERY == 0:
            self.static.append(world[~mover][:: self.STATIC_STRIDE])

    def write(self, path: Path, title: str, max_pixels: int = 1600) -> None:
        from PIL import Image, ImageDraw

        static = np.vstack(self.static) if self.static else np.zeros((0, 2))
        moving = np.vstack(self.moving) if self.moving else np.zeros((0, 2))
        tracks = np.concatenate(self.tracks) if self.tracks else np.zeros(0, np.int64)
        route = np.array(self.path)
        lo = route.min(axis=0) - 40.0
        hi = route.max(axis=0) + 40.0
        res = max(float((hi - lo).max()) / max_pixels, 0.1)
        w, h = (int(np.ceil(v)) + 1 for v in (hi - lo) / res)
        img = np.full((h + 24, w, 3), 255, np.uint8)

        def pix(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            col = ((xy[:, 0] - lo[0]) / res).astype(np.int64)
            row = 24 + (h - 1 - (xy[:, 1] - lo[1]) / res).astype(np.int64)
            ok = (col >= 0) & (col < w) & (row >= 24) & (row < h + 24)
            return row[ok], col[ok], ok

        r, c, _ = pix(static)
        img[r, c] = (175, 175, 175)
        r, c, _ = pix(route)
        img[r, c] = (0, 0, 0)
        r, c, ok = pix(moving)
        palette = np.array([(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
                            (70, 200, 220), (240, 50, 230), (128, 128, 0), (0, 0, 128), (170, 110, 40)], np.uint8)
        img[r, c] = palette[tracks[ok] % len(palette)]
        image = Image.fromarray(img)
        ImageDraw.Draw(image).text((6, 6), f"{title}; {res:.2f} m/px", fill=(0, 0, 0))
        image.save(path, format="PNG")
