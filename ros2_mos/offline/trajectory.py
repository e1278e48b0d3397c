"""One trajectory from KISS-ICP run over a drive forwards and backwards.

KISS-ICP falls behind when the sensor starts to move together with the traffic around it (a jam moving off: the
cars it registers against move with it, and its map was built while they stood). Sometimes it stays behind (on the
simulated traffic_jam-9201 the forward poses stay 1.1 m behind for the rest of the drive); more often it lags for a
few seconds and catches up (0.56 m on benchmark-10121, 0.87 m on narrow_street-10213: parked cars beside the sensor
are then "seen through"). Run backwards, that moment is a stop, which it follows. The backward pass is run where the
sensor stood and moved off (:func:`starts_from_rest`); a pass that stayed behind travelled less, so the drive's poses
are those of the pass that travelled clearly farther (``margin`` metres and ``margin_share`` of the path), and where
neither did, those of the pass preferred, by default (autolabel's ``odometry_prefer``) the backward one: over 54
simulated drives that start from rest, its poses of scans 20 and 40 apart are 0.043 m off on average, the forward
pass's 0.118 m, and less on 46 of the 54 (benchmarks/autolabel.md, round 26).
"""

from __future__ import annotations

import numpy as np

from ros2_mos.core.errors import ConfigError

#: The two passes: forwards, backwards.
PASSES = ("f", "b")
#: The path is measured in straight steps of this many scans (single scan-to-scan steps add their noise).
PATH_STEP = 5


def path_length(poses: np.ndarray, step: int = PATH_STEP) -> float:
    """Metres travelled along (N, 4, 4) poses, summed over straight steps of ``step`` scans."""
    poses = np.asarray(poses, np.float64)
    ends = [*range(0, len(poses) - 1, step), len(poses) - 1] if len(poses) > 1 else []
    return float(sum(np.linalg.norm(poses[b, :3, 3] - poses[a, :3, 3]) for a, b in zip(ends, ends[1:])))


def starts_from_rest(poses: np.ndarray, stamps: np.ndarray, rest_speed: float = 0.3, moving_speed: float = 1.0,
                     rest_seconds: float = 1.0, step: int = PATH_STEP) -> bool:
    """Whether the sensor stood (under ``rest_speed`` m/s, measured over ``step`` scans) for ``rest_seconds`` and
    moved off later (over ``moving_speed``): the one moment KISS-ICP falls behind at, and so the one a backward pass
    is run for (at 25 ms a scan)."""
    poses, stamps = np.asarray(poses, np.float64), np.asarray(stamps, np.float64)
    if len(poses) <= step:
        return False
    speed = (np.linalg.norm(poses[step:, :3, 3] - poses[:-step, :3, 3], axis=1)
             / np.maximum(stamps[step:] - stamps[:-step], 1e-6))
    # [first, last] stamp of standing speeds since the sensor last moved: creeping speeds between the two bounds
    # neither end nor restart it (a queue creeps off at 0.2-0.9 m/s before it drives)
    rest: list[float] = []
    for k, v in enumerate(speed):
        if v < rest_speed:
            rest = [rest[0] if rest else stamps[k], stamps[k]]
        elif v > moving_speed:
            if rest and rest[1] - rest[0] >= rest_seconds:
                return True
            rest = []
    return False


def farther_pass(forward: np.ndarray, backward: np.ndarray, margin: float, margin_share: float,
                 prefer: str = "f") -> tuple[np.ndarray, str]:
    """The poses of the pass that travelled clearly farther (by more than ``margin`` metres and ``margin_share`` of
    the other's path), else of the pass ``prefer`` names ('f' or 'b'); the backward pass's moved into the forward
    pass's frame (scan 0 where the forward pass put it). Returns the poses and 'b' or 'f'."""
    forward, backward = np.asarray(forward, np.float64), np.asarray(backward, np.float64)
    if forward.shape != backward.shape or forward.ndim != 3 or forward.shape[1:] != (4, 4) or len(forward) == 0:
        raise ConfigError(f"farther_pass needs two (N, 4, 4) pose arrays of one shape, N > 0, got {forward.shape} "
                          f"and {backward.shape}")
    if not (np.isfinite(margin) and np.isfinite(margin_share) and margin >= 0 and margin_share >= 0):
        raise ConfigError(f"farther_pass needs finite margins >= 0, got {margin} and {margin_share}")
    if prefer not in PASSES:
        raise ConfigError(f"farther_pass: prefer must be one of {', '.join(PASSES)}, got {prefer!r}")
    forward_path, backward_path = path_length(forward), path_length(backward)

    def clearly_farther(a: float, b: float) -> bool:
        return a - b > margin and a - b > margin_share * b

    if clearly_farther(forward_path, backward_path):
        which = "f"
    elif clearly_farther(backward_path, forward_path):
        which = "b"
    else:
        which = prefer
    if which == "b":
        return forward[0] @ np.linalg.inv(backward[0]) @ backward, "b"
    return forward.copy(), "f"
