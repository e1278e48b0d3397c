"""Scan-to-scan registration: each past scan's relative pose refined against the current scan before the residuals.

KISS-ICP registers every scan against a voxel map of 0.5-1 m cells. Between two scans its relative pose is off by a
few centimetres, and by 5-17 cm where the ego pulls away along a street with little to hold the pose
(`benchmarks/experiments.md`, row 9). A residual of a parked car 3 m away then reads 2-4 %, which is what a slow
mover looks like, and the network calls it moving.

Here the relative pose is refined at the range image's own resolution: projective point-to-plane ICP (as
KinectFusion does it). Each current point (every ``point_stride``-th occupied pixel) is moved into the past scan's
frame with the current estimate and paired with the past scan's *own* point at that pixel; the plane there comes
from the past point's neighbours to the right and below. Gauss-Newton on the Huber-weighted point-to-plane distance
``e = n · (T q − s)`` with ``J = (n, q × n)`` gives a left-multiplied update ``exp(δ)``; a small damping keeps an
unconstrained direction (along a featureless street) where the odometry put it. Movers are few pixels and far
from their past surfaces (the pairing limits drop them; the Huber weight damps the rest).

The sums of a step are computed by the compiled kernel where built (``kernels.plane_icp_sums``) and by
:func:`plane_icp_sums` in numpy otherwise; both do the same double-precision arithmetic per pair
(``test/test_registration.py``).
"""

from __future__ import annotations

import math

import numpy as np

from ros2_mos.core import kernels
from ros2_mos.core.config import RegistrationConfig, SensorConfig
from ros2_mos.core.projection import pixel_index_columns
from ros2_mos.core.residuals import relative_pose, transform_columns

#: Pairs farther apart than this (m) are not the same surface, whatever the plane says.
POINT_LIMIT = 1.0
#: Point-to-plane distance (m) up to which a pair has full weight (Huber). 0.05 needed twice the steps to
#: converge from a 10 cm error (benchmarks/experiments.md, row 21).
HUBER = 0.15
#: Fewer pairs than this: the refinement is not trusted and the odometry's pose stays.
MIN_PAIRS = 200
#: Damping of the normal equations, relative to their trace / 6.
DAMPING = 1e-6
#: A refinement that moves the pose by more than this (m, rad) is refused: the odometry's pose stays.
MAX_CORRECTION = (0.5, math.radians(2.0))
#: Stop when a step is smaller than this (m, rad).
CONVERGED = (1e-4, 1e-5)


def normal_planes(planes: np.ndarray, range_image: np.ndarray) -> np.ndarray:
    """(3, H*W) float32 unit normals of a scan's own points per pixel; (0, 0, 0) where there is no plane.

    The normal at a pixel is the cross product of the vectors to its right neighbour (wrapping around) and the
    one below, where all three hold points no farther apart than 5 % of the range + 0.3 m; the last row has none.
    """
    if kernels.enabled():
        return kernels.normals(planes, range_image)
    rng = np.asarray(range_image, np.float32)
    h, w = rng.shape
    xyz = np.asarray(planes, np.float32).reshape(3, h, w)
    out = np.zeros((3, h, w), np.float32)
    s = xyz[:, :-1].astype(np.float64)
    a = np.roll(xyz[:, :-1], -1, axis=2) - s
    c = xyz[:, 1:] - s
    r0 = rng[:-1]
    ok = (r0 > 0) & (np.roll(rng[:-1], -1, axis=1) > 0) & (rng[1:] > 0)
    limit2 = (0.05 * r0.astype(np.float64) + 0.3) ** 2
    ok &= (np.einsum("kij,kij->ij", a, a) < limit2) & (np.einsum("kij,kij->ij", c, c) < limit2)
    n = np.stack([a[1] * c[2] - a[2] * c[1], a[2] * c[0] - a[0] * c[2], a[0] * c[1] - a[1] * c[0]])
    norm = np.sqrt(np.einsum("kij,kij->ij", n, n))
    ok &= norm > 1e-9
    out[:, :-1] = np.where(ok, n / np.where(ok, norm, 1.0), 0.0)
    return out.reshape(3, -1)


def plane_icp_sums(planes: np.ndarray, points: np.ndarray, transform: np.ndarray, sensor: SensorConfig,
                   past_planes: np.ndarray, past_normals: np.ndarray, plane_limit: float,
                   point_limit: float = POINT_LIMIT, huber: float = HUBER) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The Gauss-Newton sums ``(J^T W J, J^T W e, e^T W e, pairs)`` of one projective point-to-plane step.

    ``planes`` / ``past_planes`` (3, H*W) hold the current / past scan's own points per pixel, ``past_normals``
    the past scan's :func:`normal_planes`, ``points`` the flat ids of the current pixels to use, and
    ``transform`` (4x4) takes current points into the past frame. A current point pairs with the past point at
    its pixel where that pixel has a normal, the point-to-plane distance ``e`` is below ``plane_limit`` and
    the points are closer than ``point_limit``; each pair has the Huber weight of ``e``.
    """
    if kernels.enabled():
        return kernels.plane_icp_sums(planes, points, transform, sensor, past_planes, past_normals, plane_limit,
                                      point_limit, huber)
    points = np.asarray(points, dtype=np.int64)
    cur = np.ascontiguousarray(np.asarray(planes, np.float32)[:, points].T)
    x, y, z = transform_columns(cur, transform)
    pix = pixel_index_columns(x, y, z, sensor)
    p0 = pix.v.astype(np.int64) * sensor.width + pix.u
    n = np.asarray(past_normals, np.float32)[:, p0].T.astype(np.float64)
    keep = pix.in_image & (n != 0.0).any(axis=1)
    q = np.stack([x, y, z], 1).astype(np.float64)
    d = q - np.asarray(past_planes, np.float32)[:, p0].T
    e = np.einsum("ij,ij->i", n, d)
    keep &= (np.abs(e) < float(np.float32(plane_limit)))
    keep &= np.einsum("ij,ij->i", d, d) < float(np.float32(point_limit)) ** 2
    n, q, e = n[keep], q[keep], e[keep]
    hub = float(np.float32(huber))
    weight = np.where(np.abs(e) <= hub, 1.0, hub / np.maximum(np.abs(e), 1e-300))
    jac = np.concatenate([n, np.cross(q, n)], 1)
    hessian = (jac * weight[:, None]).T @ jac
    gradient = (jac * weight[:, None]).T @ e
    return hessian, gradient, float(np.sum(weight * e * e)), int(len(e))


def se3_exp(delta: np.ndarray) -> np.ndarray:
    """The rigid transform of a twist (translation, rotation vector): rotation by Rodrigues, translation as is."""
    t, w = np.asarray(delta[:3], np.float64), np.asarray(delta[3:], np.float64)
    angle = float(np.linalg.norm(w))
    out = np.eye(4)
    if angle > 0.0:
        k = w / angle
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        out[:3, :3] = np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)
    out[:3, 3] = t
    return out


def refine_to_past(to_past: np.ndarray, planes: np.ndarray, points: np.ndarray, past_planes: np.ndarray,
                   past_normals: np.ndarray, sensor: SensorConfig, iterations: int, plane_limit: float,
                   ) -> tuple[np.ndarray, bool]:
    """``to_past`` (current frame -> past frame) refined; and whether the refinement was taken.

    Kept as given when fewer than ``MIN_PAIRS`` pairs remain, the equations are singular, or the result moves
    the pose by more than ``MAX_CORRECTION``.
    """
    start = np.asarray(to_past, np.float64)
    if kernels.enabled():
        refined = kernels.refine(planes, points, start, sensor, past_planes, past_normals, iterations, plane_limit,
                                 POINT_LIMIT, HUBER, DAMPING, MIN_PAIRS, CONVERGED)
        return _checked(start, refined)
    pose = start
    for _ in range(iterations):
        hessian, gradient, _, pairs = plane_icp_sums(planes, points, pose, sensor, past_planes, past_normals,
                                                     plane_limit)
        if pairs < MIN_PAIRS:
            return start, False
        hessian = hessian + np.eye(6) * DAMPING * np.trace(hessian) / 6.0
        try:
            delta = -np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            return start, False
        if not np.isfinite(delta).all():
            return start, False
        pose = se3_exp(delta) @ pose
        if np.linalg.norm(delta[:3]) < CONVERGED[0] and np.linalg.norm(delta[3:]) < CONVERGED[1]:
            break
    return _checked(start, pose)


def _checked(start: np.ndarray, pose: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """``pose``, unless it is None or moves ``start`` by more than ``MAX_CORRECTION``: then ``start``."""
    if pose is None:
        return start, False
    correction = pose @ np.linalg.inv(start)
    moved = float(np.linalg.norm(correction[:3, 3]))
    turned = math.acos(max(-1.0, min(1.0, (float(np.trace(correction[:3, :3])) - 1.0) / 2.0)))
    if moved > MAX_CORRECTION[0] or turned > MAX_CORRECTION[1]:
        return start, False
    return pose, True


def register_to_past(pose: np.ndarray, planes: np.ndarray, mask: np.ndarray,
                     past: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], sensor: SensorConfig,
                     config: RegistrationConfig) -> tuple[np.ndarray, list[np.ndarray]]:
    """This scan's pose on the registered trajectory, and its refined transform into each past scan's frame.

    ``pose`` is the odometry's world pose of the current scan, whose points per pixel are ``planes`` (3, H*W)
    where ``mask`` (H, W). ``past`` holds, newest first and the previous scan first of all, each past scan's own
    points per pixel (3, H*W), their :func:`normal_planes`, its odometry pose and its registered pose. The previous scan
    is registered with ``config.iterations`` steps, starting from the odometry's increment; the others start
    from the registered trajectory (so they are already close) and take ``config.other_iterations`` steps.
    """
    points = np.flatnonzero(mask.reshape(-1))[:: config.point_stride]
    prev_planes, prev_normals, prev_pose, prev_registered = past[0]
    # The odometry's increment, as the start on the registered trajectory.
    to_prev, _ = refine_to_past(relative_pose(prev_pose, pose), planes, points, prev_planes, prev_normals, sensor,
                                config.iterations, config.max_error)
    registered = prev_registered @ to_prev
    farther = [refine_to_past(relative_pose(past_registered, registered), planes, points, past_planes, past_normals,
                              sensor, config.other_iterations, config.max_error)[0]
               for past_planes, past_normals, _, past_registered in past[1:]]
    return registered, [to_prev] + farther
