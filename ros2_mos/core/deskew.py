"""Motion compensation of a rotating LiDAR's sweep (deskewing) from the poses of the scans around it.

A spinning sensor fires its columns one after another over one scan period while the vehicle moves, so each point
is measured from the pose of its own firing time: a real scan is *skewed* (KITTI raw's and most drivers' clouds are;
SemanticKITTI's are not: KITTI's odometry benchmark compensated them with the vehicle's GPS/IMU; the simulator's are
skewed with ``--intra-sweep-motion``). At 6 m/s the points behind the sensor, fired first and last, lie 0.3 m off
either way. Scans compared from far apart then disagree where an object's bearing changed, and a thin static pole or
bollard that the sensor drives past is "seen through" by another scan.

The sweep is KITTI's Velodyne convention (the simulator's too): it starts behind the sensor (azimuth +pi) and turns
clockwise seen from above, through the left and the front (phase 0, the scan's pose) to the right and back
(KISS-ICP's KITTI timestamps the same way). A cloud's own per-point times give each point's firing phase where it
has them (:func:`~ros2_mos.io.pointcloud2.sweep_phases`, a bag's PointCloud2); without, its azimuth does
(:func:`sweep_phase`); the sensor's motion over the sweep is the twist between the poses before and after
(:func:`scan_motions`, constant velocity), and :func:`deskew` moves each point into the frame of the scan's pose.
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.errors import ConfigError

#: How a consumer of a drive treats its sweeps: 'on' deskews, 'off' takes them as they are, 'auto' deskews where the
#: drive says they are skewed (a folder's ``sweep.txt``, a bag's per-point times).
DESKEW_MODES = ("auto", "on", "off")


def check_deskew_mode(mode: str, where: str) -> str:
    """``mode`` if it is one of :data:`DESKEW_MODES`; else a one-line :class:`ConfigError` naming ``where``."""
    if mode not in DESKEW_MODES:
        raise ConfigError(f"{where}: deskew must be one of {', '.join(DESKEW_MODES)}, got {mode!r}")
    return mode


def deskew_wanted(mode: str, said: bool | None) -> bool:
    """Whether a drive's scans are deskewed under ``mode`` (:data:`DESKEW_MODES`): 'on' always, 'off' never, 'auto'
    where what the drive says (``said``: a ``sweep.txt``'s word, a bag's per-point times; None: nothing) is skewed."""
    return mode == "on" or (mode == "auto" and said is True)


def drive_motions(poses: np.ndarray, stamps: np.ndarray | None) -> np.ndarray:
    """:func:`scan_motions` of a drive's poses, scaled by its ``stamps`` where there is one per pose and they
    increase; otherwise (a bag's stamps that do not, none at all) each step is taken as one sweep."""
    steady = stamps is not None and len(stamps) == len(poses) and bool(np.all(np.diff(stamps) > 0))
    return scan_motions(poses, stamps if steady else None)


def sweep_phase(points: np.ndarray) -> np.ndarray:
    """Per (N, 3+) point, its firing time relative to the scan's pose, in sweeps: -0.5 behind at the start, 0 ahead,
    +0.5 behind at the end (azimuth +pi -> -pi, clockwise)."""
    return (-np.arctan2(points[:, 1], points[:, 0]) / (2.0 * np.pi)).astype(np.float64)


def rotation_log(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle, radians) of a 3x3 rotation matrix."""
    cos = np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    skew = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    if angle < 1e-9:
        return skew / 2.0
    return skew * (angle / (2.0 * np.sin(angle)))


def scan_motions(poses: np.ndarray, stamps: np.ndarray | None = None) -> np.ndarray:
    """Per scan of (N, 4, 4) world poses, the sensor's motion over one sweep in the scan's own frame: (N, 6), rotation
    vector then translation. The mean of the steps from the scan before and to the scan after (one of them at either
    end of the drive); zeros for a single scan. With the scans' ``stamps`` (s), each step is scaled to the drive's
    median time between scans (one sweep): a scan dropped between two does not double their motion."""
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ConfigError(f"scan_motions: poses must be (N, 4, 4), got {poses.shape}")
    n = len(poses)
    steps = np.zeros((max(n - 1, 0), 6))
    for k in range(n - 1):
        relative = np.linalg.inv(poses[k]) @ poses[k + 1]
        steps[k, :3] = rotation_log(relative[:3, :3])
        steps[k, 3:] = relative[:3, 3]
    if stamps is not None and n > 1:
        gaps = np.diff(np.asarray(stamps, np.float64))
        if gaps.shape != (n - 1,) or not np.all(np.isfinite(gaps)) or not np.all(gaps > 0):
            raise ConfigError("scan_motions: stamps must be one finite, increasing time per pose")
        steps *= (np.median(gaps) / gaps)[:, None]
    out = np.zeros((n, 6))
    if n < 2:
        return out
    out[0], out[-1] = steps[0], steps[-1]
    out[1:-1] = (steps[:-1] + steps[1:]) / 2.0
    return out


def deskew(points: np.ndarray, motion: np.ndarray, phase: np.ndarray | None = None) -> np.ndarray:
    """The (N, 3) points of one skewed sweep moved into the frame of the scan's pose (float32, same order): a point
    fired at phase s (``phase``, per point, from the cloud's own times; else :func:`sweep_phase` of its azimuth) was
    measured from the pose moved by s times ``motion`` (rotation vector, translation: :func:`scan_motions`)."""
    motion = np.asarray(motion, np.float64)
    if motion.shape != (6,) or not np.all(np.isfinite(motion)):
        raise ConfigError(f"deskew: motion must be 6 finite numbers, got {motion!r}")
    xyz = np.asarray(points[:, :3], np.float64)
    columns = np.ascontiguousarray(xyz.T)  # x, y, z, each contiguous: numpy is slow on the short axis of (N, 3)
    if phase is None:
        phase = sweep_phase(columns.T)
    else:
        phase = np.asarray(phase, np.float64)
        if phase.shape != (len(xyz),) or not np.all(np.isfinite(phase)):
            raise ConfigError(f"deskew: phase must be one finite number per point ({len(xyz)}), got shape "
                              f"{phase.shape}")
    omega, velocity = motion[:3], motion[3:]
    angle = float(np.linalg.norm(omega))
    out = phase[None, :] * velocity[:, None]
    out += columns  # the point moved by its share of the translation ...
    if angle > 0:  # ... and turned by its share of the rotation about the axis (Rodrigues)
        axis = omega / angle
        theta = phase * angle
        cos, sin = np.cos(theta), np.sin(theta)
        cos_less_one, one_less_cos = cos - 1.0, 1.0 - cos
        dot = xyz @ axis
        for i, (j, k) in enumerate(((1, 2), (2, 0), (0, 1))):
            turn = columns[i] * cos_less_one
            across = axis[j] * columns[k]  # (axis x point)[i]
            across -= axis[k] * columns[j]
            across *= sin
            turn += across
            turn += dot * axis[i] * one_less_cos
            out[i] += turn
    return np.ascontiguousarray(out.T, np.float32)  # (N, 3) rows, as the callers (KISS-ICP above all) expect
