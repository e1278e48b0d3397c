"""Maps from scans and poses: raw vs MOS-cleaned, ghost points, files and a bird's-eye view.

Moving objects leave "ghost" trails in a map built from raw scans (the paper's Fig. 8).
:class:`VoxelMap` is a voxel-downsampled point map (one point per voxel: the first one
that fell into it, so every map point keeps the tag of the scan point it came from);
:func:`build_maps` fills a raw and a MOS-cleaned map side by side, tagging each point
with its ground-truth class so that :func:`ghost_share` can say how much of a map
is made of moving objects.  The same :class:`VoxelMap`, with a radius and a point
budget around the sensor, is the node's bounded local ``/mos/static_map``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from ros2_mos.core.atomic import atomic_path, write_bytes_atomically
from ros2_mos.core.config import MosConfig
from ros2_mos.core.deskew import check_deskew_mode, deskew, deskew_wanted, drive_motions
from ros2_mos.core.errors import ConfigError, DatasetError, ScanError, scan_refused
from ros2_mos.core.inference import MosModel
from ros2_mos.core.projection import finite_mask
from ros2_mos.io.labels import IGNORE, MOVING, to_moving_classes
from ros2_mos.io.semantic_kitti import KITTI_TR
from ros2_mos.io.sweep import read_sweep_file
from ros2_mos.offline.drives import Drive, DriveScan, FolderDrive, given_poses, scan_place

# Per-point tags a map keeps (ground truth of the scan point a map point came from).
TAG_STATIC = 0
TAG_MOVING = 1  # a ghost: the point belonged to a moving object when it was scanned
TAG_UNKNOWN = 2  # unlabelled data or ignored ground truth

_BITS = 21
_OFFSET = 1 << (_BITS - 1)  # voxel indices in [-2^20, 2^20): +-52 km at 5 cm voxels


@dataclass(frozen=True)
class VoxelMapConfig:
    """How a :class:`VoxelMap` downsamples and bounds itself.

    ``max_radius`` drops map points farther than this (horizontally and vertically, a
    sphere) from the latest sensor position given to :meth:`VoxelMap.insert`;
    ``max_points`` keeps only the points nearest to it.  ``None`` leaves the map unbounded
    (offline mapping); the node wants both, so that its memory and messages stay bounded.
    """

    voxel_size: float = 0.2
    max_radius: float | None = None
    max_points: int | None = None

    def __post_init__(self) -> None:
        if not self.voxel_size > 0:
            raise ConfigError(f"voxel map: voxel_size must be positive, got {self.voxel_size}")
        if self.max_radius is not None and not self.max_radius > 0:
            raise ConfigError(f"voxel map: max_radius must be positive or None, got {self.max_radius}")
        if self.max_points is not None and self.max_points < 1:
            raise ConfigError(f"voxel map: max_points must be >= 1 or None, got {self.max_points}")


def transform(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``R p + t`` for (N, 3) points, element-wise: a BLAS matmul of an N x 3 array is slower here
    (thread start-up, and it contends with ONNX Runtime's threads in the node)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    r, t = pose[:3, :3], pose[:3, 3]
    return p[:, 0:1] * r[:, 0] + p[:, 1:2] * r[:, 1] + p[:, 2:3] * r[:, 2] + t


class VoxelMap:
    """A voxel-downsampled map of world points: one point per occupied voxel.

    Kept sorted by voxel key, so inserting N points into a map of M costs a binary search
    (N log M) and one array insert (M), with no Python loop over points.  Each point keeps a
    ``uint8`` tag and the ``stamp`` of the insert that added it.
    """

    def __init__(self, config: VoxelMapConfig = VoxelMapConfig()) -> None:
        self.config = config
        self.clear()

    def clear(self) -> None:
        self._keys = np.zeros(0, np.int64)
        self._points = np.zeros((0, 3), np.float32)
        self._tags = np.zeros(0, np.uint8)
        self._stamps = np.zeros(0, np.float64)

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def points(self) -> np.ndarray:
        """(M, 3) float32 world points (a read-only view; copy before changing it)."""
        view = self._points.view()
        view.flags.writeable = False
        return view

    @property
    def tags(self) -> np.ndarray:
        view = self._tags.view()
        view.flags.writeable = False
        return view

    @property
    def stamps(self) -> np.ndarray:
        view = self._stamps.view()
        view.flags.writeable = False
        return view

    def voxel_keys(self, points: np.ndarray) -> np.ndarray:
        """One int64 per point identifying its voxel (three 21-bit indices packed)."""
        idx = np.floor(np.asarray(points, dtype=np.float64) / self.config.voxel_size).astype(np.int64)
        if len(idx) and (idx.min() < -_OFFSET or idx.max() >= _OFFSET):
            reach = _OFFSET * self.config.voxel_size
            raise ScanError(f"voxel map: points beyond +-{reach:.0f} m of the origin cannot be stored at "
                            f"{self.config.voxel_size} m voxels")
        idx += _OFFSET
        return (idx[:, 0] << (2 * _BITS)) | (idx[:, 1] << _BITS) | idx[:, 2]

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether the voxel of each point is occupied in the map."""
        keys = self.voxel_keys(np.asarray(points).reshape(-1, 3))
        return self._find(keys) >= 0

    def _find(self, keys: np.ndarray) -> np.ndarray:
        """Index of each key in the map, -1 where absent."""
        if len(self._keys) == 0:
            return np.full(len(keys), -1, np.int64)
        pos = np.searchsorted(self._keys, keys)
        hit = self._keys[np.minimum(pos, len(self._keys) - 1)] == keys
        return np.where(hit, pos, -1)

    def insert(
        self,
        points: np.ndarray,
        sensor_position: np.ndarray | None = None,
        tags: np.ndarray | None = None,
        stamp: float = 0.0,
    ) -> int:
        """Add world points; voxels already occupied keep their point. Returns how many points were added.

        Non-finite points are skipped.  With ``max_radius``/``max_points`` set, the map is then
        bounded around ``sensor_position`` (required in that case).
        """
        pts = np.asarray(points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ScanError(f"voxel map: expected (N, 3) points, got shape {pts.shape}")
        tag = np.zeros(len(pts), np.uint8) if tags is None else np.asarray(tags, np.uint8).reshape(-1)
        if len(tag) != len(pts):
            raise ScanError(f"voxel map: {len(tag)} tags for {len(pts)} points")
        ok = np.isfinite(pts).all(axis=1)
        pts, tag = pts[ok], tag[ok]
        keys = self.voxel_keys(pts)
        keys, first = np.unique(keys, return_index=True)  # first point per voxel, sorted keys
        new = self._find(keys) < 0
        keys, first = keys[new], first[new]
        pos = np.searchsorted(self._keys, keys)
        self._keys = np.insert(self._keys, pos, keys)
        self._points = np.insert(self._points, pos, pts[first], axis=0)
        self._tags = np.insert(self._tags, pos, tag[first])
        self._stamps = np.insert(self._stamps, pos, np.full(len(keys), stamp))
        if self.config.max_radius is not None or self.config.max_points is not None:
            if sensor_position is None:
                raise ConfigError("voxel map: a bounded map (max_radius/max_points) needs the sensor position")
            self.bound(np.asarray(sensor_position, dtype=np.float64).reshape(3))
        return len(keys)

    def insert_scan(
        self, points_sensor: np.ndarray, pose: np.ndarray, tags: np.ndarray | None = None, stamp: float = 0.0
    ) -> int:
        """Add a scan given in its sensor frame with its 4x4 world pose (the sensor sits at the pose's origin)."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ScanError(f"voxel map: pose must be 4x4, got {pose.shape}")
        return self.insert(transform(points_sensor, pose), pose[:3, 3], tags, stamp)

    def bound(self, center: np.ndarray) -> None:
        """Apply ``max_radius`` and ``max_points`` around ``center`` (the nearest points stay)."""
        d2 = np.sum((self._points - np.asarray(center, np.float32)) ** 2, axis=1)
        keep = np.ones(len(d2), bool)
        if self.config.max_radius is not None:
            keep &= d2 <= self.config.max_radius**2
        limit = self.config.max_points
        if limit is not None and np.count_nonzero(keep) > limit:
            d2 = np.where(keep, d2, np.inf)
            nearest = np.argpartition(d2, limit - 1)[:limit]
            keep = np.zeros(len(d2), bool)
            keep[nearest] = True
        if not keep.all():
            self._keys, self._points = self._keys[keep], self._points[keep]
            self._tags, self._stamps = self._tags[keep], self._stamps[keep]


def ghost_share(voxel_map: VoxelMap) -> float:
    """Share of map points that came from ground-truth moving points (NaN for an empty map)."""
    return float(np.mean(voxel_map.tags == TAG_MOVING)) if len(voxel_map) else float("nan")


def gt_tags(labels: np.ndarray | None, n: int) -> np.ndarray:
    """Per-point map tags from raw SemanticKITTI labels (all unknown without labels)."""
    if labels is None:
        return np.full(n, TAG_UNKNOWN, np.uint8)
    cls = to_moving_classes(labels)
    tags = np.full(n, TAG_STATIC, np.uint8)
    tags[cls == MOVING] = TAG_MOVING
    tags[cls == IGNORE] = TAG_UNKNOWN
    return tags


@dataclass(frozen=True)
class MappingConfig:
    """Which scan points go into the maps: the far, sparse returns add noise, the nearest the ego car."""

    voxel_size: float = 0.1
    min_range: float = 2.5
    max_range: float = 50.0
    poses: str = "estimated"  # 'estimated' (the MOS pipeline's KISS-ICP) or 'gt' (the dataset's poses)
    #: Each scan deskewed into the frame of its pose before it enters both maps (:mod:`~ros2_mos.core.deskew`, the
    #: motion from the poses the maps are built with): 'on', 'off', or 'auto': where the labels' folder says how
    #: autolabel took the sweeps (its ``sweep.txt``), else where the sequence's ``sweep.txt`` says skewed
    deskew: str = "auto"

    def __post_init__(self) -> None:
        check_deskew_mode(self.deskew, "mapping")
        if not 0.0 <= self.min_range < self.max_range:
            raise ConfigError(f"mapping: need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}")
        if self.poses not in ("estimated", "gt"):
            raise ConfigError(f"mapping: poses must be 'estimated' or 'gt', got {self.poses!r}")
        VoxelMapConfig(self.voxel_size)


class MapBuilder:
    """A raw and a cleaned map filled from the same scans; the cleaned one without the masked points."""

    def __init__(self, config: MappingConfig = MappingConfig()) -> None:
        self.config = config
        self.raw = VoxelMap(VoxelMapConfig(config.voxel_size))
        self.cleaned = VoxelMap(VoxelMapConfig(config.voxel_size))
        self.scans = 0

    def add(
        self, points: np.ndarray, pose: np.ndarray, remove: np.ndarray, tags: np.ndarray, stamp: float = 0.0
    ) -> None:
        """Add one scan (sensor frame) with its world pose; ``remove`` marks the points the cleaned map skips."""
        pts = np.asarray(points, dtype=np.float32)
        remove = np.asarray(remove, bool).reshape(-1)
        tags = np.asarray(tags, np.uint8).reshape(-1)
        if not (len(pts) == len(remove) == len(tags)):
            raise ScanError(f"map builder: {len(pts)} points, {len(remove)} mask values, {len(tags)} tags")
        r = np.linalg.norm(pts, axis=1)
        use = finite_mask(pts) & (r >= self.config.min_range) & (r <= self.config.max_range)
        self.raw.insert_scan(pts[use], pose, tags[use], stamp)
        keep = use & ~remove
        self.cleaned.insert_scan(pts[keep], pose, tags[keep], stamp)
        self.scans += 1

    def static_kept(self) -> float:
        """Share of the raw map's ground-truth static points whose voxel the cleaned map still has.

        The other side of :func:`ghost_share`: a mask that removed everything would have no
        ghosts, and it would show here.
        """
        static = self.raw.tags == TAG_STATIC
        if not static.any():
            return float("nan")
        return float(np.mean(self.cleaned.contains(self.raw.points[static])))


@dataclass
class MappingResult:
    builder: MapBuilder
    poses: np.ndarray  # (N, 4, 4) the LiDAR poses the maps were built with
    moving_share: float  # share of valid points MOS labelled moving
    deskewed: bool = False  # the scans were deskewed before they entered the maps (``MappingConfig.deskew``)

    @property
    def raw(self) -> VoxelMap:
        return self.builder.raw

    @property
    def cleaned(self) -> VoxelMap:
        return self.builder.cleaned


#: Wraps the pass over a drive's scans (a progress bar)
Progress = Callable[[Iterable[DriveScan]], Iterable[DriveScan]]


def build_maps(
    drive: Drive,
    config: MosConfig = MosConfig(),
    mapping: MappingConfig = MappingConfig(),
    model: MosModel | None = None,
    progress: Progress = lambda scans: scans,
) -> MappingResult:
    """Run MOS over a drive (a sequence folder or a bag: :func:`~ros2_mos.offline.drives.open_drive`) and build the
    raw and the MOS-cleaned map from the same poses.

    With ``mapping.poses='estimated'`` the poses are the pipeline's own KISS-ICP with
    ``map_update='static'`` (what the node does online); with ``'gt'`` the drive's poses.
    The maps are filled once every pose is known (a scan is deskewed with the poses before and after it).
    """
    from ros2_mos.core.pipeline import MosPipeline

    given = given_poses(drive, "mapping with the drive's own poses") if mapping.poses == "gt" else None
    cfg = dataclasses.replace(config, odometry=dataclasses.replace(config.odometry, map_update="static"))
    pipeline = MosPipeline(cfg, model)
    pipeline.reset()
    poses, moving, shares, stamps = [], [], [], []
    for scan in progress(drive):
        try:
            res = pipeline.process(scan.points, scan.intensity, scan.stamp,
                                   pose=given[scan.index] if given is not None else None)
        except ScanError as exc:
            raise scan_refused(exc, scan_place(drive, scan.index)) from exc
        poses.append(res.pose)
        moving.append(np.packbits(res.labels.astype(bool)))  # a bit per point: bounded for a long drive
        stamps.append(scan.stamp)
        n_valid = int(res.valid.sum())
        shares.append(float(res.labels.sum()) / n_valid if n_valid else 0.0)
    deskewed = _deskews(mapping, drive)
    builder = fill_maps(drive, np.array(poses), lambda k, scan: np.unpackbits(moving[k], count=len(scan.points))
                        .astype(bool), mapping, deskewed, np.array(stamps))
    return MappingResult(builder, np.array(poses), float(np.mean(shares)), deskewed)


def build_maps_from_labels(
    drive: Drive,
    labels_root: str | Path,
    mapping: MappingConfig = MappingConfig(),
    progress: Progress = lambda scans: scans,
) -> MappingResult:
    """The raw and the cleaned map from labels written beforehand (``ros2-mos autolabel`` or ``infer``):
    ``LABELS_ROOT/sequences/<name>/predictions/*.label`` (every id 251-259 moving; one per point as stored), with the
    poses written beside them (``poses.txt``, autolabel's KISS-ICP over the whole drive) or, with
    ``mapping.poses='gt'``, the drive's. With ``mapping.deskew='auto'`` the scans are deskewed where autolabel
    deskewed them (its ``sweep.txt``), by the stamps written beside the labels (``times.txt``) where there are.
    """
    from ros2_mos.io.semantic_kitti import read_label, read_poses, read_times

    folder = Path(labels_root) / "sequences" / drive.name
    predictions = folder / "predictions"
    if not predictions.is_dir():
        raise DatasetError(f"no labels for {drive.name}: {predictions} is missing")
    n = len(drive)
    if mapping.poses == "gt":
        poses = given_poses(drive, "mapping with the drive's own poses")
    else:
        if not (folder / "poses.txt").is_file():
            raise DatasetError(f"{folder}: no poses.txt beside the labels (or use the drive's: poses 'gt')")
        poses = read_poses(folder / "poses.txt", KITTI_TR)
        if len(poses) < n:
            raise DatasetError(f"{folder / 'poses.txt'}: {len(poses)} poses for {n} scans")
    poses = np.asarray(poses[:n])
    label_files = [predictions / f"{name}.label" for name in drive.scan_names]
    stamps = read_times(folder / "times.txt")[:n] if (folder / "times.txt").is_file() else None
    deskewed = _deskews(mapping, drive, folder)
    shares: list[float] = []

    def moving(k: int, scan: DriveScan) -> np.ndarray:
        mask = (to_moving_classes(read_label(label_files[k], scan.stored)) == MOVING)[scan.kept]
        shares.append(float(mask.mean()) if len(mask) else 0.0)
        return mask

    builder = fill_maps(drive, poses, moving, mapping, deskewed, stamps, progress)
    return MappingResult(builder, poses, float(np.mean(shares)), deskewed)


def has_ground_truth(drive: Drive) -> bool:
    """Whether ``drive`` has labels of its own (a sequence folder's ``labels/``): the maps' ghost share needs them."""
    return isinstance(drive, FolderDrive) and drive.sequence.has_labels


def _deskews(mapping: MappingConfig, drive: Drive, labels_folder: Path | None = None) -> bool:
    """Whether the maps deskew ``drive``'s scans (``MappingConfig.deskew``; 'auto': the labels' folder's
    ``sweep.txt`` where it has one, else what the drive says: :attr:`Drive.skewed`)."""
    said = read_sweep_file(labels_folder) if labels_folder is not None else None
    return deskew_wanted(mapping.deskew, said if said is not None else drive.skewed)


def fill_maps(
    drive: Drive,
    poses: np.ndarray,
    moving: Callable[[int, DriveScan], np.ndarray],
    mapping: MappingConfig,
    deskewed: bool,
    stamps: np.ndarray | None = None,
    progress: Progress = lambda scans: scans,
) -> MapBuilder:
    """Both maps from every scan of ``drive`` at ``poses``; ``moving(k, scan)``: the mask over scan k's points of
    those the cleaned map leaves out. Deskewed (``stamps``: one per scan, to scale each scan's motion to one sweep
    where they increase), a scan keeps its points' order, so the mask still fits; a bag's per-point times give the
    firing phases where its clouds carry them."""
    motions = drive_motions(poses, stamps) if deskewed else None
    truth = _ground_truth(drive)
    builder = MapBuilder(mapping)
    for scan in progress(drive):
        k = scan.index
        points = scan.points if motions is None else deskew(scan.points, motions[k], scan.phase)
        builder.add(points, poses[k], moving(k, scan), truth(k, scan), scan.stamp)
    return builder


def _ground_truth(drive: Drive) -> Callable[[int, DriveScan], np.ndarray]:
    """Per scan, the map tags of its points from the drive's own labels (:func:`gt_tags`; unknown without)."""
    if not has_ground_truth(drive):
        return lambda k, scan: gt_tags(None, len(scan.points))
    from ros2_mos.io.semantic_kitti import read_label

    sequence = drive.sequence  # type: ignore[attr-defined]
    return lambda k, scan: gt_tags(read_label(sequence.label_path(k), scan.stored)[scan.kept], len(scan.points))


# ---------------------------------------------------------------- files


def height_colors(points: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 colours by height (2nd..98th percentile over a blue-green-yellow ramp)."""
    z = np.asarray(points)[:, 2]
    if len(z) == 0:
        return np.zeros((0, 3), np.uint8)
    lo, hi = np.percentile(z, [2, 98])
    t = np.clip((z - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    anchors = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64)
    xs = np.linspace(0.0, 1.0, len(anchors))
    return np.column_stack([np.interp(t, xs, anchors[:, c]) for c in range(3)]).astype(np.uint8)


def write_map(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write a point map as binary PLY (via trimesh) or binary PCD (x y z rgb), chosen by suffix."""
    path = Path(path)
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    rgb = height_colors(pts) if colors is None else np.asarray(colors, np.uint8).reshape(-1, 3)
    if len(rgb) != len(pts):
        raise ScanError(f"write_map: {len(rgb)} colours for {len(pts)} points")
    suffix = path.suffix.lower()
    if suffix == ".ply":
        import trimesh

        rgba = np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])
        write_bytes_atomically(path, trimesh.PointCloud(pts, colors=rgba).export(file_type="ply"))
    elif suffix == ".pcd":
        _write_pcd(path, pts, rgb)
    else:
        raise ConfigError(f"map file {path}: unknown format {suffix!r}; use .ply or .pcd")
    return path


def _write_pcd(path: Path, points: np.ndarray, rgb: np.ndarray) -> None:
    """PCL's PCD v0.7, binary: x y z as float32 and rgb packed into a float32 as PCL does."""
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2].astype(np.uint32)
    record = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    record["x"], record["y"], record["z"] = points[:, 0], points[:, 1], points[:, 2]
    record["rgb"] = packed
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\n"
        f"TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {len(points)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(points)}\nDATA binary\n"
    )
    write_bytes_atomically(path, header.encode("ascii") + record.tobytes())


def map_paths(out: str | Path) -> tuple[Path, Path]:
    """``map.ply`` -> (``map_raw.ply``, ``map_cleaned.ply``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_raw{out.suffix}"), out.with_name(f"{out.stem}_cleaned{out.suffix}")


# ---------------------------------------------------------------- bird's-eye view

GHOST_COLOR = (230, 40, 40)


def bev_image(
    voxel_map: VoxelMap, extent: tuple[float, float, float, float], resolution: float, mark_ghosts: bool = True
) -> np.ndarray:
    """Top view (H, W, 3) uint8 of a map: the highest point per pixel coloured by height, ghosts red on top.

    ``extent`` is (x_min, x_max, y_min, y_max) in metres, ``resolution`` metres per pixel;
    +x points right and +y up in the image.
    """
    x0, x1, y0, y1 = extent
    width = max(1, int(np.ceil((x1 - x0) / resolution)))
    height = max(1, int(np.ceil((y1 - y0) / resolution)))
    img = np.full((height, width, 3), 255, np.uint8)
    pts = voxel_map.points
    if len(pts) == 0:
        return img
    col = ((pts[:, 0] - x0) / resolution).astype(np.int64)
    row = (height - 1 - (pts[:, 1] - y0) / resolution).astype(np.int64)
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    colors = height_colors(pts)
    order = np.argsort(pts[:, 2], kind="stable")  # later (higher) points overwrite lower ones
    order = order[inside[order]]
    img[row[order], col[order]] = colors[order]
    if mark_ghosts:
        ghosts = inside & (voxel_map.tags == TAG_MOVING)
        img[row[ghosts], col[ghosts]] = GHOST_COLOR
    return img


def side_by_side(panels: list[np.ndarray], titles: list[str], title_height: int = 24, gap: int = 8) -> Any:
    """Equal-sized (H, W, 3) uint8 pictures in a row on white, each with its title above it: a PIL image."""
    from PIL import Image, ImageDraw

    h, w = panels[0].shape[:2]
    canvas = np.full((h + title_height, len(panels) * w + (len(panels) - 1) * gap, 3), 255, np.uint8)
    for i, panel in enumerate(panels):
        canvas[title_height:, i * (w + gap) : i * (w + gap) + w] = panel
    image = Image.fromarray(canvas)
    draw = ImageDraw.Draw(image)
    for i, title in enumerate(titles):
        draw.text((i * (w + gap) + 6, 6), title, fill=(0, 0, 0))
    return image


def write_bev_png(
    path: str | Path,
    maps: dict[str, VoxelMap],
    max_pixels: int = 1400,
    margin: float = 2.0,
) -> Path:
    """Write the maps' top views side by side in one PNG (same extent and scale), titled by the dict's keys.

    Like the paper's Fig. 8; in addition, points that came from ground-truth moving
    objects (where labels exist) are drawn red so that ghosts are easy to see.
    """
    try:
        import PIL  # noqa: F401
    except ImportError:  # pragma: no cover - pillow is in requirements.txt
        raise ConfigError("writing a PNG needs pillow (pip install pillow)") from None
    if not maps:
        raise ConfigError("write_bev_png: no map to draw")
    filled = [m.points for m in maps.values() if len(m)]
    if not filled:
        raise DatasetError("write_bev_png: every map is empty")
    allpts = np.vstack(filled)
    lo, hi = allpts[:, :2].min(axis=0) - margin, allpts[:, :2].max(axis=0) + margin
    resolution = max(float((hi - lo).max()) / max_pixels, 0.05)
    extent = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    panels = [bev_image(m, extent, resolution) for m in maps.values()]
    image = side_by_side(panels, [f"{name}  ({len(m)} points, {resolution:.2f} m/px)" for name, m in maps.items()])
    path = Path(path)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")
    return path
