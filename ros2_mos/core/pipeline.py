"""The MOS pipeline: one scan in, one moving/static label per point out.

The node, the CLI (``infer``, ``process``, ``bench``) and the evaluation all call
:class:`MosPipeline`, so nothing is computed differently offline and online::

    odometry -> projection -> residuals -> network -> kNN back-projection -> map update
"""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ros2_mos.core.config import MosConfig, PostprocessConfig, ResidualConfig, SensorConfig, same_beams
from ros2_mos.core.errors import ConfigError, ImplausibleScanError, ScanError
from ros2_mos.core.inference import MosModel, default_model_path, shipped_models
from ros2_mos.core.memory import retain_freed_memory
from ros2_mos.core.metadata import check_threshold
from ros2_mos.core.mover_memory import MoverMemory
from ros2_mos.core.network_input import assemble_input
from ros2_mos.core.odometry import BufferedScan, KissIcpOdometry, ScanBuffer
from ros2_mos.core.postprocess import backproject
from ros2_mos.core.projection import PixelIndex, RangeImage, check_points, finite_mask, project
from ros2_mos.core.registration import normal_planes, register_to_past
from ros2_mos.core.residuals import free_space_images, relative_pose, residual_images, transform_points
from ros2_mos.core.segments import drop_small_regions, fill_segments
from ros2_mos.core.sensor_check import implausible_message, mismatch_message
from ros2_mos.core.temporal import BeliefFilter

#: Above this share of points outside the sensor's vertical field of view or range limits, the
#: cloud does not fit the configured sensor (another beam layout): its labels are flagged degraded.
MAX_OUTSIDE_FRACTION = 0.5
#: postprocess.min_region_pixels counts pixels of an image this large (the HDL-64E's 64 x 2048).
REFERENCE_PIXELS = 64 * 2048
#: A model that takes remission was trained on 0..1 values; larger intensities (0..255 drivers) are flagged.
MAX_REMISSION = 1.0 + 1e-3


@dataclass
class MosResult:
    """Everything one scan produced; per-point arrays have one entry per *input* point."""

    labels: np.ndarray  # (N,) uint8: 1 moving, 0 static (also 0 for invalid points)
    probability: np.ndarray  # (N,) float32 moving probability (0 for invalid points)
    valid: np.ndarray  # (N,) bool: finite with positive range, so it was used
    pose: np.ndarray  # (4, 4) world pose of the scan
    range_image: np.ndarray  # (H, W) float32, 0 where empty
    probability_image: np.ndarray  # (H, W) float32 per-pixel moving probability
    mask_image: np.ndarray  # (H, W) uint8 per-pixel moving label (0 where empty)
    residuals: np.ndarray  # (n_past, H, W) residual images (empty for 'frames' setups)
    n_past_available: int  # how many past scans the residuals/frames were computed from
    n_past_required: int
    timings: dict[str, float] = field(default_factory=dict)  # stage -> milliseconds
    warnings: list[str] = field(default_factory=list)
    # Non-empty when the stream's first scan (since start or reset) did not fit the configured sensor
    # (ros2_mos.core.sensor_check): every label of the stream is then suspect.
    sensor_mismatch: str = ""
    # True when this scan reset the scan buffer (time went backwards, odometry failed or jumped).
    reset: bool = False

    @property
    def residuals_complete(self) -> bool:
        """False at a sequence start or after a buffer reset (missing residuals were zero)."""
        return self.n_past_available >= self.n_past_required

    @property
    def degraded(self) -> bool:
        """Labels were computed with less information than the model was trained for."""
        return not self.residuals_complete or bool(self.warnings) or bool(self.sensor_mismatch)


class _Stopwatch:
    """Per-stage wall-clock timings in milliseconds."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._start = self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Time since the last lap, added to ``stage`` (a stage may be timed in parts)."""
        now = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + (now - self._last) * 1e3
        self._last = now

    def total(self) -> None:
        self.timings["total"] = (time.perf_counter() - self._start) * 1e3


class NumpyGeometry:
    """The default geometry backend: residual images and the kNN vote in numpy.

    :class:`ros2_mos.core.torch_geometry.TorchGeometry` has the same methods (``geometry_backend: torch``); the
    pipeline picks one in ``__init__``. Past scans are re-projected on two threads (numpy releases the
    GIL in its ufuncs).
    """

    def __init__(self, sensor: SensorConfig, parallel: bool = True) -> None:
        self.sensor = sensor
        self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="mos-residuals") if parallel else None

    def residuals(self, current_range: np.ndarray, pose: np.ndarray, past: list[tuple[np.ndarray, np.ndarray]],
                  n: int, config: ResidualConfig, offsets: tuple[int, ...] | None = None,
                  signed: bool = False) -> np.ndarray:
        return residual_images(current_range, pose, past, n, self.sensor, config,
                               map_fn=self._pool.map if self._pool is not None else map, offsets=offsets,
                               signed=signed)

    def free_space(self, image: RangeImage, pose: np.ndarray, past: list[tuple[np.ndarray, np.ndarray]],
                   offsets: tuple[int, ...], config: ResidualConfig) -> np.ndarray:
        """Free-space images against ``past`` (own range image, world pose), newest first."""
        return free_space_images(image.xyz, image.mask, pose, past, offsets, self.sensor, config,
                                 map_fn=self._pool.map if self._pool is not None else map)

    def knn(self, prob_image: np.ndarray, range_image: np.ndarray, pixels: PixelIndex, config: PostprocessConfig,
            threshold: float) -> np.ndarray:
        return backproject(prob_image, range_image, pixels, config, threshold)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


@dataclass
class _Scan:
    """The usable points of a scan (finite, positive range) and where they sit in the input."""

    xyz: np.ndarray  # (M, 3) float32, contiguous
    remission: np.ndarray  # (M,) float32, non-finite values zeroed
    valid: np.ndarray  # (N,) bool over the input points

    def scatter(self, values: np.ndarray, dtype: type) -> np.ndarray:
        """Per-usable-point ``values`` as one value per input point (0 for the invalid ones)."""
        out = np.zeros(len(self.valid), dtype)
        out[self.valid] = values
        return out


@dataclass
class _Notes:
    """What a scan's checks found: warnings for the result and whether the buffer was reset."""

    warnings: list[str] = field(default_factory=list)
    reset: bool = False


def _usable_points(points: np.ndarray, intensity: np.ndarray | None) -> _Scan:
    """Check a scan's shapes and keep its finite, positive-range points; :class:`ScanError` when none is left."""
    pts = check_points(points)
    n = len(pts)
    if n == 0:
        raise ScanError("empty scan: no points")
    rem = np.zeros(n, np.float32) if intensity is None else np.asarray(intensity, np.float32).reshape(-1)
    if len(rem) != n:
        raise ScanError(f"intensity has {len(rem)} values for {n} points")
    valid = finite_mask(pts)
    n_valid = int(valid.sum())
    if n_valid == 0:
        raise ScanError(f"scan has no finite point with positive range (all {n} points invalid)")
    if n_valid == n:  # the common case: a plain copy (kept in the buffer), no boolean gather
        xyz = np.array(pts, dtype=np.float32, order="C")
        remission = np.nan_to_num(rem, nan=0.0, posinf=0.0, neginf=0.0)
    else:
        kept = np.flatnonzero(valid)
        xyz = np.take(pts, kept, axis=0).astype(np.float32, copy=False)  # a row gather, not a 2-D mask
        remission = np.nan_to_num(rem[kept], nan=0.0, posinf=0.0, neginf=0.0)
    return _Scan(xyz, remission, valid)


def image_sensor(configured: SensorConfig | None, trained: SensorConfig) -> SensorConfig:
    """The range image a pipeline projects to: the configured sensor's, or the model's where none is configured.

    A model trained for the configured preset (same name, rows and field of view) at another number of columns
    brings its own columns: the preset names the LiDAR, the model decides how finely its range image samples the
    azimuth. Any other difference in the image's rows or columns raises :class:`ConfigError`.
    """
    if configured is None:
        return trained
    same_lidar = configured.name == trained.name and same_beams(configured, trained)
    if same_lidar and configured.width != trained.width:
        return dataclasses.replace(configured, width=trained.width)
    if (configured.height, configured.width) != (trained.height, trained.width):
        raise ConfigError(
            f"sensor {configured.name} projects to {configured.height} x {configured.width} but the model "
            f"was trained for {trained.name} at {trained.height} x {trained.width}; "
            "use a model trained for this sensor (models ship for " + ", ".join(shipped_models()) + ")"
        )
    return configured


class MosPipeline:
    """Online MOS over a stream of scans from one sensor."""

    def __init__(self, config: MosConfig = MosConfig(), model: MosModel | None = None) -> None:
        self.config = config
        if config.tune_malloc:
            retain_freed_memory()
        if model is None:  # the configured file, else the model shipped for the configured sensor
            path = config.model or default_model_path(config.sensor.name if config.sensor else None)
            model = MosModel(path, intra_op_threads=config.intra_op_threads)
        self.model = model
        meta = self.model.metadata
        self.setup = meta.input
        self.sensor: SensorConfig = image_sensor(config.sensor, meta.sensor)
        recommended = check_threshold(meta.extra.get("recommended_threshold", 0.5), f"{self.model.path.name}: "
                                      "recommended_threshold in the model's metadata")
        #: The moving-probability threshold in use: the configured one, or the model's own.
        self.threshold = config.threshold or recommended
        # The setting counts pixels of a 64 x 2048 image: the same solid angle on other images.
        scale = self.sensor.height * self.sensor.width / REFERENCE_PIXELS
        self._min_region_pixels = round(config.postprocess.min_region_pixels * scale)
        #: Where residuals are computed: the configured window, or the one the model was trained with.
        self.residual_window = config.residuals.for_model(meta.residual_max_range)
        self.means = np.asarray(meta.means, np.float32)
        self.stds = np.asarray(meta.stds, np.float32)
        self.odometry = KissIcpOdometry(config.odometry)
        self.buffer = ScanBuffer(self.setup.history)
        self.belief = BeliefFilter(self.sensor, config.postprocess.temporal_weight)
        self.movers = MoverMemory(config.movers)
        # KISS-ICP deskews only with per-point times, and process() takes none yet: said once, not ignored silently.
        self._deskew_note = config.odometry.deskew
        self.geometry: Any
        if config.geometry_backend == "torch":
            from ros2_mos.core.torch_geometry import TorchGeometry  # the only place the runtime may import torch

            self.geometry = TorchGeometry(self.sensor, config.device)
        else:
            self.geometry = NumpyGeometry(self.sensor, parallel=self.n_past > 1)
        self._last_stamp: float | None = None
        self._last_pose: np.ndarray | None = None
        self._sensor_mismatch: str | None = None  # None: not checked yet
        # Scan-to-scan registration before the residuals (core/registration.py); residual models only.
        self._registers = self.setup.kind == "residual" and config.registration.iterations > 0

    @property
    def n_past(self) -> int:
        return self.setup.n_past

    def close(self) -> None:
        """Stop the worker threads (the pipeline is unusable afterwards)."""
        self.geometry.close()

    def reset(self) -> None:
        """Forget past scans and the odometry map (time went backwards, odometry failed, ...)."""
        self.forget_past_scans()
        self.odometry.reset()
        self._last_stamp = None
        self._last_pose = None
        self._sensor_mismatch = None

    def forget_past_scans(self) -> None:
        """Forget the scan buffer and the temporal belief, keep the odometry: what a jump in the poses or a gap in
        the stream makes meaningless, where the odometry's map still describes the place."""
        self.buffer.clear()
        self.belief.reset()
        self.movers.reset()

    def process(
        self, points: np.ndarray, intensity: np.ndarray | None, timestamp: float, pose: np.ndarray | None = None
    ) -> MosResult:
        """Label one scan. ``pose`` (4x4 world pose) skips the odometry, e.g. with a dataset's poses.

        Non-finite and zero-range points are left out and marked invalid; a scan with no
        usable point, or of the wrong shape, raises :class:`ScanError`; a cloud whose range image
        is no scan of surfaces (:func:`~ros2_mos.core.sensor_check.implausible_message`) raises
        :class:`ImplausibleScanError` before the odometry sees it, and leaves the pipeline as it was.
        """
        watch = _Stopwatch()
        scan = _usable_points(points, intensity)
        watch.lap("validate")
        # The projection needs no pose: done first, its range image tells a scan from scattered points before
        # KISS-ICP spends seconds on them (issue 13) and before any state (buffer, odometry map) changes.
        image = project(scan.xyz, scan.remission, self.sensor)
        watch.lap("projection")
        notes = _Notes()
        self._check_stream(scan, image, timestamp, notes)
        watch.lap("validate")
        given = pose is not None
        pose = self._pose(scan.xyz, pose, timestamp, notes)
        watch.lap("odometry")
        past, registered_pose = self._registered(image, pose, self.buffer.newest_first(), given)
        watch.lap("registration")
        residuals, network_past = self._past_inputs(image, pose, past)
        watch.lap("residuals")
        prob_image = self._infer(image, network_past)
        watch.lap("inference")
        prob_image = self.belief.fuse(prob_image, image, pose)
        watch.lap("temporal")
        prob_image, point_prob = self._postprocess(prob_image, image)
        watch.lap("postprocess")
        prob_image, point_prob = self.movers.apply(prob_image, point_prob, image, pose, timestamp, self.threshold)
        moving = point_prob >= self.threshold
        watch.lap("mover_memory")
        self._remember(scan, image, pose, registered_pose, timestamp, moving, prob_image >= self.threshold)
        watch.lap("map_update")
        watch.total()
        return MosResult(
            labels=scan.scatter(moving, np.uint8),
            probability=scan.scatter(point_prob, np.float32),
            valid=scan.valid,
            pose=pose,
            range_image=image.range,
            probability_image=prob_image,
            mask_image=((prob_image >= self.threshold) & image.mask).astype(np.uint8),
            residuals=residuals,
            n_past_available=sum(o <= len(past) for o in self.setup.offsets),
            n_past_required=self.n_past,
            timings=watch.timings,
            warnings=notes.warnings,
            sensor_mismatch=self._sensor_mismatch or "",
            reset=notes.reset,
        )

    def _check_stream(self, scan: "_Scan", image: RangeImage, timestamp: float, notes: "_Notes") -> None:
        """Refuse what is no LiDAR scan; note what makes the labels suspect; reset when time went backwards."""
        implausible = implausible_message(image.range)
        if implausible is not None:
            raise ImplausibleScanError(implausible)
        if self._deskew_note:
            notes.warnings.append("odometry.deskew is on, but per-point times are not passed to KISS-ICP yet: the "
                                  "scans are registered as they are, not deskewed")
            self._deskew_note = False
        remission = scan.remission
        if self.setup.uses_remission and len(remission) and (float(remission.max()) > MAX_REMISSION
                                                             or float(remission.min()) < 0.0):
            notes.warnings.append(
                f"intensity spans {float(remission.min()):.3g}..{float(remission.max()):.3g}, outside the 0..1 "
                "remission this model was trained on (KITTI's convention; Velodyne drivers publish 0..255, Ouster "
                "16-bit counts): "
                "labels may be wrong; use a model without remission input (the shipped one) or rescale")
        if self._last_stamp is not None and timestamp <= self._last_stamp:
            notes.warnings.append(f"time went backwards ({self._last_stamp:.3f} -> {timestamp:.3f} s): buffer reset")
            self.reset()
            notes.reset = True
        if self._sensor_mismatch is None:  # the first scan of a stream: is it the configured sensor at all?
            self._sensor_mismatch = mismatch_message(scan.xyz, self.sensor) or ""
        outside = 1.0 - float(image.pixels.in_image.mean())
        if outside > MAX_OUTSIDE_FRACTION:
            notes.warnings.append(
                f"{outside:.0%} of the points fall outside the {self.sensor.name} field of view or range (they take "
                "the nearest edge pixel's label): does the sensor configuration match the cloud?")

    def _pose(self, xyz: np.ndarray, pose: np.ndarray | None, timestamp: float, notes: "_Notes") -> np.ndarray:
        """The scan's world pose: given, or KISS-ICP's (restarted once if it diverges); a jump resets the buffer."""
        if pose is None:
            pose = np.asarray(self.odometry.estimate(xyz), dtype=np.float64)
            if not np.isfinite(pose).all():
                # A diverged ICP: its state is poisoned, so start a new odometry sequence at this scan.
                notes.warnings.append("odometry returned a non-finite pose: odometry and buffer reset")
                self.reset()
                notes.reset = True
                pose = np.asarray(self.odometry.estimate(xyz), dtype=np.float64)
                if not np.isfinite(pose).all():
                    raise ScanError("odometry returned a non-finite pose for this scan even after a reset")
        pose = np.asarray(pose, dtype=np.float64)
        if not np.isfinite(pose).all():
            raise ScanError("the given pose is not finite")
        if self._last_pose is not None and self._last_stamp is not None:
            motion = relative_pose(self._last_pose, pose)
            jump = float(np.linalg.norm(motion[:3, 3]))
            turn = float(np.degrees(np.arccos(np.clip((np.trace(motion[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
            # Per 0.1 s (one 10 Hz scan): scans dropped upstream must not look like a jump.
            periods = max(1.0, (timestamp - self._last_stamp) / 0.1)
            limit = self.config.odometry.max_translation_jump * periods
            turn_limit = self.config.odometry.max_rotation_jump * periods
            if jump > limit or turn > turn_limit:
                what = (f"jumped {jump:.1f} m" if jump > limit else f"turned {turn:.0f} deg") + " since the last scan"
                notes.warnings.append(f"pose {what} (limits {limit:.1f} m, {min(turn_limit, 180.0):.0f} deg): "
                                      "odometry suspect, buffer reset")
                self.forget_past_scans()
                notes.reset = True
        return pose

    def _registered(self, image: RangeImage, pose: np.ndarray, past: list[BufferedScan],
                    given: bool) -> tuple[list[BufferedScan], np.ndarray]:
        """The buffered scans, those at the model's offsets with poses that give the registered relative poses;
        and this scan's pose on the registered trajectory.

        A pose given with the scan is used as it is unless ``registration.refine_given_poses``.
        """
        if not self._registers or not past or (given and not self.config.registration.refine_given_poses):
            return past, pose
        at = sorted({0} | {o - 1 for o in self.setup.offsets if o <= len(past)})
        registered_pose, to_past = register_to_past(
            pose, image.planes, image.mask,
            [(past[i].xyz_planes, past[i].normals, past[i].pose, past[i].registered_pose) for i in at],
            self.sensor, self.config.registration)
        out = list(past)
        for i, transform in zip(at, to_past):
            out[i] = dataclasses.replace(past[i], pose=pose @ np.linalg.inv(transform))
        return out, registered_pose

    def _past_inputs(self, image: RangeImage, pose: np.ndarray,
                     past: list[BufferedScan]) -> tuple[np.ndarray, np.ndarray | list[RangeImage]]:
        """The residual images (empty for 'frames' setups) and what the network takes from the past scans."""
        if self.setup.kind == "residual":
            residuals = self.geometry.residuals(image.range, pose, [(s.points, s.pose) for s in past], self.n_past,
                                                self.residual_window, self.setup.offsets, self.setup.signed)
            if self.setup.free_space:
                free = self.geometry.free_space(image, pose, [(s.range_image, s.pose) for s in past],
                                                self.setup.offsets, self.residual_window)
                residuals = np.concatenate([residuals, free])
            return residuals, residuals
        frames = [project(transform_points(s.points, relative_pose(pose, s.pose)), s.remission, self.sensor)
                  for s in past]
        return np.zeros((0, self.sensor.height, self.sensor.width), np.float32), frames

    def _infer(self, image: RangeImage, network_past: np.ndarray | list[RangeImage]) -> np.ndarray:
        """The network's (H, W) moving probability, 0 on empty pixels."""
        prob_image = self.model.predict(assemble_input(image, network_past, self.setup, self.means, self.stds))
        # No point, no probability: empty pixels never vote in the kNN, and a value there would only make the
        # vote's "does this window mix both labels" test fire for nothing (measured: benchmarks/experiments.md, row 5).
        np.multiply(prob_image, image.mask, out=prob_image)
        return prob_image

    def _postprocess(self, prob_image: np.ndarray, image: RangeImage) -> tuple[np.ndarray, np.ndarray]:
        """Specks dropped (and segments filled, if set) in the image, then each point's probability by kNN vote."""
        if self._min_region_pixels > 1:
            prob_image = drop_small_regions(prob_image, image.range, self.threshold, self._min_region_pixels)
        if self.config.postprocess.segment_fill > 0:
            prob_image = fill_segments(prob_image, image.range, image.xyz[..., 2], self.threshold,
                                       self.config.postprocess.segment_fill)
        return prob_image, self.geometry.knn(prob_image, image.range, image.pixels, self.config.postprocess,
                                             self.threshold)

    def _remember(self, scan: "_Scan", image: RangeImage, pose: np.ndarray, registered_pose: np.ndarray,
                  timestamp: float, moving: np.ndarray, moving_pixels: np.ndarray) -> None:
        """The odometry map takes the scan (all of it, or its static points) and the buffer keeps it.

        For the registration of later scans it keeps its normals too, without the pixels labelled moving: later
        scans register against its static surfaces only (in a traffic jam the movers are most of what is near).
        """
        normals = None
        if self._registers:
            normals = normal_planes(image.planes, image.range)
            normals[:, np.flatnonzero(moving_pixels)] = 0.0
        if self.config.odometry.map_update == "static":
            self.odometry.update_map(scan.xyz[~moving])
        else:
            self.odometry.update_map()
        self.buffer.push(BufferedScan(points=scan.xyz, remission=scan.remission, pose=pose, timestamp=timestamp,
                                      range_image=image.range if self.setup.free_space else None,
                                      xyz_planes=image.planes if self._registers else None,
                                      normals=normals, registered_pose=registered_pose))
        self._last_stamp = timestamp
        self._last_pose = pose
