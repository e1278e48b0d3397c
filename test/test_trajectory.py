"""ros2_mos.offline.trajectory: one trajectory from KISS-ICP run forwards and backwards (hand-made poses)."""

from __future__ import annotations

import numpy as np
import pytest

from ros2_mos.core.errors import ConfigError
from ros2_mos.offline.trajectory import farther_pass, path_length, starts_from_rest


def _along_x(steps: list[float], frame: np.ndarray = np.eye(4)) -> np.ndarray:
    """Poses that move by ``steps`` metres along x, one step per scan, in world ``frame``."""
    poses = []
    for x in np.concatenate([[0.0], np.cumsum(steps)]):
        pose = np.eye(4)
        pose[0, 3] = x
        poses.append(frame @ pose)
    return np.asarray(poses)


def _turned(yaw_deg: float, shift: tuple[float, float, float]) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    frame = np.eye(4)
    frame[:2, :2] = [[c, -s], [s, c]]
    frame[:3, 3] = shift
    return frame


def test_path_length_sums_straight_steps():
    assert path_length(_along_x([1.0] * 12), step=5) == pytest.approx(12.0)
    # there and back in one 5-scan step is no way at all; scan by scan it is 4 m
    wobble = _along_x([1.0, 1.0, -1.0, -1.0, 0.0])
    assert path_length(wobble, step=5) == pytest.approx(0.0) and path_length(wobble, step=1) == pytest.approx(4.0)
    assert path_length(_along_x([])) == 0.0


def test_the_backward_pass_is_taken_where_the_forward_one_fell_clearly_behind():
    # forwards, KISS-ICP falls behind in scans 5-10 (a jam moves off) and stays 2.5 m behind
    forward = _along_x([1.0] * 5 + [0.5] * 5 + [1.0] * 10)
    backward = _along_x([1.0] * 20, _turned(30.0, (4.0, -2.0, 1.0)))  # its own world frame
    poses, which = farther_pass(forward, backward, margin=0.75, margin_share=0.02)
    assert which == "b"
    np.testing.assert_allclose(poses[:, 0, 3], np.arange(21.0), atol=1e-9)  # in the forward pass's frame
    np.testing.assert_allclose(poses[:, :3, :3], np.tile(np.eye(3), (21, 1, 1)), atol=1e-9)


def test_the_forward_pass_stays_unless_the_backward_one_is_clearly_farther():
    forward = _along_x([1.0] * 20)
    stopped = _along_x([1.0] * 10 + [0.6] * 5 + [1.0] * 5)  # backwards, the stop at scans 10-15 is a start
    for backward in (stopped, _along_x([1.0] * 19 + [1.5])):  # behind; 0.5 m farther: under 0.75 m
        poses, which = farther_pass(forward, backward, margin=0.75, margin_share=0.02)
        assert which == "f"
        np.testing.assert_allclose(poses, forward)
    # 1 m farther on a 100 m drive is over the margin but under 2 % of the path
    long_forward = _along_x([1.0] * 100)
    assert farther_pass(long_forward, _along_x([1.0] * 99 + [2.0]), 0.75, 0.02)[1] == "f"
    assert farther_pass(long_forward, _along_x([1.0] * 99 + [3.5]), 0.75, 0.02)[1] == "b"


def test_where_neither_pass_is_clearly_farther_the_preferred_one_is_taken():
    # forwards, KISS-ICP lags 0.8 m as the sensor moves off (scans 5-10) and catches up by scan 15: both paths end
    # equally long, and the backward pass, which followed that moment as a stop, is preferred
    forward = _along_x([0.0] * 5 + [0.6] * 5 + [1.4] * 5 + [1.0] * 5)
    backward = _along_x([0.0] * 5 + [0.76] * 5 + [1.24] * 5 + [1.0] * 5, _turned(30.0, (4.0, -2.0, 1.0)))
    poses, which = farther_pass(forward, backward, margin=0.75, margin_share=0.02, prefer="b")
    assert which == "b"
    np.testing.assert_allclose(poses[10, 0, 3], 3.8, atol=1e-9)  # the forward pass put scan 10 at 3.0 m
    assert farther_pass(forward, backward, 0.75, 0.02, prefer="f")[1] == "f"
    # a forward pass clearly farther is taken whatever the preference (backwards, a stop was a start it lagged at)
    assert farther_pass(_along_x([1.0] * 20), _along_x([1.0] * 10 + [0.6] * 5 + [1.0] * 5), 0.75, 0.02,
                        prefer="b")[1] == "f"


def test_bad_input_is_refused():
    poses = _along_x([1.0] * 4)
    with pytest.raises(ConfigError, match="one shape"):
        farther_pass(poses, poses[:3], 0.75, 0.02)
    with pytest.raises(ConfigError, match="one shape"):
        farther_pass(poses[:0], poses[:0], 0.75, 0.02)
    for margin, share in ((float("nan"), 0.02), (0.75, float("inf")), (-1.0, 0.02)):
        with pytest.raises(ConfigError, match="finite margins"):
            farther_pass(poses, poses, margin, share)
    with pytest.raises(ConfigError, match="prefer"):
        farther_pass(poses, poses, 0.75, 0.02, prefer="backward")


def test_a_backward_pass_is_wanted_only_where_the_sensor_stood_and_moved_off():
    stamps = np.arange(61) * 0.1
    stands_then_drives = _along_x([0.0] * 20 + [0.3] * 40)  # 2 s standing, then 3 m/s
    assert starts_from_rest(stands_then_drives, stamps)
    assert not starts_from_rest(_along_x([0.5] * 60), stamps)  # 5 m/s throughout
    assert not starts_from_rest(_along_x([0.3] * 20 + [0.0] * 40), stamps)  # drives, then stops: no start
    # stands 0.5 s only (the 5-scan speeds stand still for 1 scan of it): not a start from rest
    assert not starts_from_rest(_along_x([0.3] * 20 + [0.0] * 5 + [0.3] * 35), stamps)
    # speeding up slowly after the stand (0.05 m/s, then 3 m/s) still counts
    assert starts_from_rest(_along_x([0.0] * 15 + [0.005] * 10 + [0.3] * 35), stamps)
    assert not starts_from_rest(_along_x([0.0] * 3), stamps[:4])  # too short to tell
    # stands 1.2 s, creeps off at 0.35 m/s, slows to 0.2 m/s, then drives: the creep does not restart the stand
    assert starts_from_rest(_along_x([0.0] * 12 + [0.035] * 6 + [0.02] * 6 + [0.3] * 36), stamps)
