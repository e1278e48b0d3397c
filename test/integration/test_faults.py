"""Faults around mos_node over real rclpy: broken models and mismatched sensors at start-up of the process,
the input going silent and coming back, odometry failing, clouds of another sensor, hostile PointCloud2.

(Covered elsewhere: a missing model file and bad parameters at start-up, bad/empty/NaN clouds, stamps going
backwards, pose jumps, queue drops and SIGINT in test_node.py; a looped bag (time going backwards across
processes), bounded queue and memory, and SIGTERM in test_soak.py.)
"""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from conftest import make_wrong_channels_model  # noqa: E402
from ros_harness import (  # noqa: E402
    BASE_STAMP,
    TYPES,
    child_env,
    cloud,
    executable,
    harness_fixture,
    sequence_fixture,
)

from ros2_mos.core.errors import ScanError  # noqa: E402
from ros2_mos.io.pointcloud2 import FLOAT32, INT16, MAX_FIELDS, MAX_POINT_STEP, decode_xyz_intensity  # noqa: E402
from ros2_mos.ros import messages as m  # noqa: E402
from ros2_mos.ros.diagnostics import STALE_AFTER_S  # noqa: E402

DOMAIN = 45 + os.getpid() % 150 + 6  # apart from test_node's and test_soak's domains in the same run
PERIOD = 100_000_000


# ----------------------------------------------------------------------------- start-up of the process

def test_broken_models_and_mismatched_sensors_stop_the_process_with_a_clear_message(tmp_path, tiny_model_path):
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(tiny_model_path.read_bytes()[: len(tiny_model_path.read_bytes()) // 2])
    cases = {
        "truncated model": (["-p", f"model:={truncated}"], "ONNX Runtime cannot load it"),
        "wrong input size": (["-p", f"model:={make_wrong_channels_model(tmp_path / 'wrong.onnx')}"],
                             "network takes 7 input channels but its metadata"),
        "hdl64 preset on a 32-beam model": (["-p", f"model:={tiny_model_path}", "-p", "sensor.preset:=hdl64"],
                                            "sensor hdl64 projects to 64 x 2048 but the model was trained for test32"),
        "custom 16-beam sensor": (["-p", f"model:={tiny_model_path}", "-p", "sensor.preset:=custom",
                                   "-p", "sensor.height:=16", "-p", "sensor.width:=512"],
                                  "sensor custom projects to 16 x 512 but the model was trained for test32"),
    }
    mos_node = executable("mos_node")
    procs = {name: subprocess.Popen([mos_node, "--ros-args", *args], env=child_env(DOMAIN + 1), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
             for name, (args, _) in cases.items()}  # in parallel: four interpreter start-ups cost one
    for name, proc in procs.items():
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 1, (name, out)
        assert "cannot start" in out and cases[name][1] in out, (name, out)
        assert "Traceback" not in out and "ready in" not in out, (name, out)


# ----------------------------------------------------------------------------- in-process node

sequence = sequence_fixture(6)
harness = harness_fixture(DOMAIN, reset_after_gap=1.0)


def _status(msg):
    s = msg.status[0]
    level = s.level if isinstance(s.level, int) else int.from_bytes(s.level, "little")
    return level, s.message, {kv.key: kv.value for kv in s.values}


def _wait_diag(harness, predicate, start: int, timeout: float):
    """The first diagnostics message after index ``start`` that satisfies ``predicate``, or None."""
    found = []

    def check() -> bool:
        for msg in harness.received["diag"][start:]:
            if predicate(*_status(msg)):
                found.append(_status(msg))
                return True
        return False

    harness._wait(check, timeout)
    return found[0] if found else None


def test_silent_input_is_reported_stale_then_processing_resumes_with_a_reset(harness, sequence):
    harness.node.processor.reset()
    stamp = BASE_STAMP + 20 * 10**12
    for i in range(3):
        assert harness.feed(cloud(stamp + i * PERIOD, *sequence[i][:2])) is not None
    # A gap shorter than reset_after_gap (1 s) keeps the buffer.
    stamp += 2 * PERIOD + 500_000_000
    assert harness.feed(cloud(stamp, *sequence[3][:2])) is not None
    out = harness.node._last_output
    assert not out.reset and out.result.residuals_complete
    resets = harness.node.stats.snapshot().resets

    # Silence: the diagnostics turn to "no input" (WARN) once nothing arrived for STALE_AFTER_S.
    start = len(harness.received["diag"])
    stale = _wait_diag(harness, lambda level, message, _: message.startswith("no input"), start, STALE_AFTER_S + 5)
    assert stale is not None, "diagnostics never reported the silent input"
    assert stale[0] == m.WARN and float(stale[1].split()[-2]) >= STALE_AFTER_S, stale[1]  # printed to 0.1 s

    # The driver comes back 3 s (of stamps) later: > reset_after_gap, so the buffer is reset.
    stamp += 3_000_000_000
    assert harness.feed(cloud(stamp, *sequence[4][:2])) is not None
    out = harness.node._last_output
    assert out.reset and any("reset_after_gap" in n for n in out.notes), out.notes
    assert out.result.n_past_available == 0 and out.result.degraded
    assert harness.node.stats.snapshot().resets == resets + 1
    start = len(harness.received["diag"])
    # The node counts a scan processed just after publishing its outputs, so a diagnostics message may land in
    # between (received 5, processed 4): wait for the one that counts it.
    resumed = _wait_diag(harness, lambda level, message, values: not message.startswith("no input")
                         and int(values["processed"]) >= 5, start, 5)
    assert resumed is not None, "diagnostics never counted the scan after the silence"
    # ...and the next scan 0.1 s later uses the fresh buffer again.
    assert harness.feed(cloud(stamp + PERIOD, *sequence[5][:2])) is not None
    assert harness.node._last_output.result.n_past_available == 1


def test_odometry_raising_resets_and_the_next_scan_is_flagged_degraded(harness, sequence):
    harness.node.processor.reset()
    stamp = BASE_STAMP + 21 * 10**12
    for i in range(3):
        assert harness.feed(cloud(stamp + i * PERIOD, *sequence[i][:2])) is not None
    odometry = harness.node.processor.pipeline.odometry
    real = odometry.estimate

    def failing(*args, **kwargs):
        raise RuntimeError("simulated KISS-ICP failure")

    odometry.estimate = failing
    try:
        errors = harness.node.stats.snapshot().errors
        assert harness.feed(cloud(stamp + 3 * PERIOD, *sequence[3][:2])) is None  # nothing published for it
        snap = harness.node.stats.snapshot()
        assert snap.errors == errors + 1 and "simulated KISS-ICP failure" in snap.last_warning
    finally:
        odometry.estimate = real
    out = harness.feed(cloud(stamp + 4 * PERIOD, *sequence[4][:2]))
    assert out is not None
    assert harness.node._last_output.result.n_past_available == 0 and harness.node._last_output.result.degraded


def test_non_finite_odometry_pose_never_reaches_the_outputs(harness, sequence, monkeypatch):
    import ros2_mos.ros.diagnostics as diagnostics

    # the degraded scan's report is what is checked: when its processing takes over 2 s (a loaded CI machine), the
    # input is already stale when the scan is done, and "no input" would be reported in its place
    monkeypatch.setattr(diagnostics, "STALE_AFTER_S", 60.0)
    harness.node.processor.reset()
    stamp = BASE_STAMP + 22 * 10**12
    for i in range(3):
        assert harness.feed(cloud(stamp + i * PERIOD, *sequence[i][:2])) is not None
    odometry = harness.node.processor.pipeline.odometry
    real = odometry.estimate
    start = len(harness.received["diag"])
    resets = harness.node.stats.snapshot().resets
    calls = []

    def diverges_once(points, *args, **kwargs):
        calls.append(1)
        odometry.estimate = real
        real(points, *args, **kwargs)
        return np.full((4, 4), np.nan)

    odometry.estimate = diverges_once
    try:
        out = harness.feed(cloud(stamp + 4 * PERIOD, *sequence[4][:2]))
    finally:
        odometry.estimate = real
    assert calls and out is not None
    pos = out["odometry"].pose.pose.position
    assert np.isfinite([pos.x, pos.y, pos.z]).all()
    last = harness.node._last_output
    assert last.reset and last.result.degraded and any("non-finite pose" in n for n in last.notes)
    assert harness.node.stats.snapshot().resets == resets + 1
    diag = _wait_diag(harness, lambda level, message, _: "non-finite pose" in message, start, 5)
    assert diag is not None and diag[0] == m.WARN and diag[1].startswith("labels degraded")


def test_clouds_that_do_not_fit_the_sensor_are_processed_and_flagged(harness, sequence):
    harness.node.processor.reset()
    stamp = BASE_STAMP + 23 * 10**12
    errors = harness.node.stats.snapshot().errors
    rng = np.random.default_rng(7)
    n = 30000
    az, el = rng.uniform(-np.pi, np.pi, n), np.deg2rad(rng.choice(np.linspace(-45, 45, 128), n))
    r = 20.0 + 15.0 * np.sin(2.0 * az) * np.cos(el)  # a surface: scattered ranges are no LiDAR scan
    wide = np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)])
    above = wide.copy()
    above[:, 2] = np.abs(above[:, 2]) + 20.0  # every point above the 32-beam field of view
    for i, pts in enumerate([wide, above]):
        out = harness.feed(cloud(stamp + i * PERIOD, pts.astype(np.float32)))
        assert out is not None, "a cloud of another sensor must still be labelled"
        assert out["static_points"].width + out["moving_points"].width == n
        last = harness.node._last_output
        assert last.result.degraded and any("field of view" in note for note in last.notes), last.notes
    assert harness.node.stats.snapshot().errors == errors
    assert harness.feed(cloud(stamp + 2 * PERIOD, *sequence[0][:2])) is not None


def test_scattered_points_are_skipped_and_a_slow_registration_keeps_the_diagnostics_alive(harness, sequence):
    """Issue 13: a cloud of uniform random points held KISS-ICP for 9-18 s, and the diagnostics with it.

    Refused first, from its range image, counted under its reason. Forced through (check off), its slow
    registration runs in slices, so the diagnostics timer (period 0.2 s here) keeps publishing meanwhile.
    """
    import time

    import ros2_mos.core.pipeline as pipeline_module

    harness.node.processor.reset()
    stamp = BASE_STAMP + 25 * 10**12
    for i in range(3):
        assert harness.feed(cloud(stamp + i * PERIOD, *sequence[i][:2])) is not None
    scattered = np.random.default_rng(0).uniform(-30, 30, (60_000, 3)).astype(np.float32)
    before = harness.node.stats.snapshot()
    assert harness.feed(cloud(stamp + 3 * PERIOD, scattered)) is None
    snap = harness.node.stats.snapshot()
    assert snap.skipped.get("implausible_scan", 0) == before.skipped.get("implausible_scan", 0) + 1
    assert "is not a plausible LiDAR scan: only" in snap.last_warning and snap.errors == before.errors
    start = len(harness.received["diag"])
    diag = _wait_diag(harness, lambda level, message, values: "skipped.implausible_scan" in values, start, 5)
    assert diag is not None and int(diag[2]["skipped.implausible_scan"]) >= 1
    assert harness.feed(cloud(stamp + 4 * PERIOD, *sequence[3][:2])) is not None
    assert harness.node._last_output.result.n_past_available == 2  # the skipped cloud left the stream as it was

    arrivals: list[float] = []
    # Kept until the harness closes: destroying a subscription while the executor spins in its own thread can kill
    # that thread (rclpy InvalidHandle), and with it every later test of the module (seen on CI).
    harness.peer.create_subscription(TYPES.diagnostic_array, "/diagnostics",
                                     lambda msg: arrivals.append(time.monotonic()), 10)
    real_check = pipeline_module.implausible_message
    pipeline_module.implausible_message = lambda image: None  # let it through to KISS-ICP (~4 s of ICP here)
    try:
        time.sleep(0.5)  # the listener is matched and hears the timer
        started = time.monotonic()
        harness.feed(cloud(stamp + 5 * PERIOD, scattered), timeout=60)
        finished = time.monotonic()
        slices = list(harness.node.processor.pipeline.odometry.last_slice_seconds)
    finally:
        pipeline_module.implausible_message = real_check
        harness.node.processor.reset()  # its points are in the odometry map now
    odometry_s = harness.node.stats.snapshot().stage_ms["odometry"][1] * 1e-3
    if odometry_s < 1.0:
        pytest.skip(f"the forced registration took only {odometry_s:.2f} s here: too fast to show a stall")
    during = [t for t in arrivals if started <= t <= finished]
    gaps = np.diff([started, *during, finished])
    # One uninterrupted KISS-ICP call holds the GIL, so no diagnostics, for the whole registration: a gap at least
    # as long as the registration. In slices, with a short sleep between them (ICP_YIELD_S), the 0.2 s timer gets
    # through between them: several arrivals, typically 0.15-0.3 s apart. The bounds leave room for the odd slice that
    # takes 10x the others (0.64-0.69 s for 8 iterations, seen here and on CI, with the gap around it near 1 s) and
    # for a loaded 2-core machine; that the registration ran in slices at all is checked directly.
    assert len(slices) >= 2, f"one call into KISS-ICP ({slices}): the registration was not sliced"
    report = (gaps.round(2).tolist(), [round(s, 2) for s in slices], odometry_s)
    assert len(during) >= 2 and gaps.max() < 0.9 * odometry_s and np.median(gaps) < 0.5, report


# ----------------------------------------------------------------------------- hostile PointCloud2 to the node

def _hostile_clouds(stamp: int, rng: np.random.Generator) -> list[tuple[str, object]]:
    """Messages that fit PointCloud2's types (so DDS carries them) but lie about their layout."""
    pts = rng.normal(scale=10.0, size=(800, 3)).astype(np.float32)

    def base():
        return cloud(stamp, pts, np.ones(len(pts), np.float32))

    def field(name, offset, datatype=FLOAT32, count=1):
        return TYPES.point_field(name=name, offset=offset, datatype=datatype, count=count)

    out = []

    def case(name, mutate):
        msg = base()
        mutate(msg)
        out.append((name, msg))

    case("offset beyond point_step", lambda c: setattr(c.fields[2], "offset", c.point_step))
    case("field spans past point_step", lambda c: setattr(c.fields[3], "offset", c.point_step - 2))
    case("short data", lambda c: setattr(c, "data", bytes(c.data)[: len(c.data) // 2]))
    case("no data", lambda c: setattr(c, "data", b""))
    case("huge width", lambda c: setattr(c, "width", 2**31))
    case("huge width x height", lambda c: (setattr(c, "height", 2**16), setattr(c, "width", 2**16)))
    case("height claims more rows", lambda c: setattr(c, "height", 5))
    case("row_step below width * point_step", lambda c: setattr(c, "row_step", 4))
    case("point_step 0", lambda c: setattr(c, "point_step", 0))
    case("point_step huge", lambda c: setattr(c, "point_step", MAX_POINT_STEP + 1))
    case("duplicate field name", lambda c: c.fields.append(field("x", 0)))
    case("too many fields",
         lambda c: setattr(c, "fields", [*c.fields, *(field(f"f{k}", 0, 2) for k in range(MAX_FIELDS))]))
    for datatype in (0, 9, 255):
        case(f"unsupported datatype {datatype}", lambda c, d=datatype: setattr(c.fields[1], "datatype", d))
    case("integer coordinates", lambda c: setattr(c.fields[0], "datatype", INT16))
    case("count 0", lambda c: setattr(c.fields[0], "count", 0))
    case("empty field name", lambda c: setattr(c.fields[1], "name", ""))
    case("no z", lambda c: setattr(c, "fields", [f for f in c.fields if f.name != "z"]))
    case("no fields", lambda c: setattr(c, "fields", []))
    for k in range(12):  # random field tables over random bytes
        def scramble(c, k=k):
            c.fields = [field(str(name), int(rng.integers(0, 24)), int(rng.integers(0, 11)), int(rng.integers(0, 3)))
                        for name in rng.permutation(["x", "y", "z", "intensity", "ring"])[: rng.integers(1, 6)]]
            c.point_step = int(rng.integers(0, 32))
            c.width = int(rng.integers(0, 2000))
            c.row_step = c.width * c.point_step + int(rng.integers(-4, 8)) % 8
            c.data = rng.integers(0, 256, int(rng.integers(0, 40000)), dtype=np.uint8).tobytes()
        case(f"random layout {k}", scramble)
    for k in range(6):  # a valid layout over random bytes: NaN, inf, 1e38 and 1e-38 coordinates
        def garbage(c, k=k):
            c.data = rng.integers(0, 256, len(c.data), dtype=np.uint8).tobytes()
        case(f"random payload {k}", garbage)
    return out


def test_hostile_clouds_are_skipped_with_their_reason_and_the_node_survives(harness, sequence, capfd):
    harness.node.processor.reset()
    stamp = BASE_STAMP + 24 * 10**12
    rng = np.random.default_rng(11)
    clouds = _hostile_clouds(0, rng)
    before = harness.node.stats.snapshot()
    outcomes = {"rejected": 0, "processed": 0, "too_few_points": 0}
    for i, (name, msg) in enumerate(clouds):
        msg.header.stamp = m.make_header(TYPES, stamp + i * PERIOD, "velodyne").stamp
        try:
            decode_xyz_intensity(msg)
            expected = None
        except ScanError as exc:
            expected = str(exc)
        handled = harness.handled()
        try:
            result = harness.feed(msg)
        except AssertionError as exc:
            raise AssertionError(f"{name}: {exc} ({harness.node.stats.snapshot().last_warning})") from None
        snap = harness.node.stats.snapshot()
        assert harness.handled() == handled + 1, name
        if expected is not None:
            assert result is None, name
            assert snap.last_warning == expected, (name, snap.last_warning, expected)
            outcomes["rejected"] += 1
        elif result is None:
            assert "finite points" in snap.last_warning or "repeats" in snap.last_warning, (name, snap.last_warning)
            outcomes["too_few_points"] += 1
        else:
            outcomes["processed"] += 1
    after = harness.node.stats.snapshot()
    assert after.errors == before.errors, after.last_warning  # every one was handled as input, none as a crash
    assert outcomes["rejected"] >= len(clouds) - 18  # all the hand-made ones, plus whatever random ones are bad
    assert outcomes["processed"] + outcomes["too_few_points"] >= 6  # the random payloads have valid layouts
    assert after.skipped.get("bad_cloud", 0) - before.skipped.get("bad_cloud", 0) == outcomes["rejected"]
    # The node is alive and labels a good scan afterwards; the reason was logged (throttled to 1/s).
    assert harness.feed(cloud(stamp + len(clouds) * PERIOD, *sequence[0][:2])) is not None
    err = capfd.readouterr().err
    assert "bad PointCloud2 skipped: PointCloud2" in err, err[-2000:]
    with capfd.disabled():
        print(f"\nhostile clouds fed to the node: {len(clouds)} -> {outcomes}")
