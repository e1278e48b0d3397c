"""Out of the box across processes (issue 14): mos_node in one process; a driver + SLAM-stack process with
default ROS settings (no DDS profile anywhere) publishes a full-size 10 Hz stream and subscribes to the outputs.

The node configures its own participant for large messages when the user set no profile; the subscriber
must then get (nearly) every scan the node processed, with sensor-data (best effort) and with reliable QoS.
The bar leaves a margin for this noisy 2-core machine; the counts are printed (``pytest -s``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from ros2_mos.ros.dds import PROFILE_VARIABLES  # noqa: E402

HERE = Path(__file__).parent
SCANS = 40
#: Share of the node's processed scans that a default subscriber in another process must receive.
MIN_SHARE = 0.9
#: Scans the node must have labelled (the peer publishes beyond SCANS, up to its --max-scans, until it has them).
MIN_PROCESSED = 3


def _default_env(domain: int) -> dict[str, str]:
    """A user's environment: no DDS profile, the default middleware; isolated from other runs."""
    env = {k: v for k, v in os.environ.items() if k not in PROFILE_VARIABLES and k != "RMW_IMPLEMENTATION"}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    return env


@pytest.mark.parametrize("qos", ["sensor", "reliable"])
def test_a_default_subscriber_in_another_process_gets_every_processed_scan(qos):
    domain = 60 + (os.getpid() + (qos == "reliable")) % 140
    env = _default_env(domain)
    node_args = ["-p", "qos.reliability:=" + ("reliable" if qos == "reliable" else "best_effort")]
    node = subprocess.Popen([str(Path(sys.executable).parent / "mos_node"), "--ros-args", *node_args],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        peer_args = ["--scans", str(SCANS), "--qos", qos, "--min-outputs", str(MIN_PROCESSED)]
        peer = subprocess.run([sys.executable, str(HERE / "transport_peer.py"), *peer_args],
                              env=env, capture_output=True, text=True, timeout=180)
        assert peer.returncode == 0, peer.stderr[-2000:]
    finally:
        node.send_signal(2)
        try:
            out, _ = node.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            node.kill()
            out, _ = node.communicate()
    result = json.loads(peer.stdout.strip().splitlines()[-1])
    assert "Traceback" not in out, out[-3000:]
    assert "transport: Fast DDS with ros2_mos's large-message profile" in out, out[-3000:]
    found = re.search(r"final statistics: (\d+)/(\d+) scans processed", out)
    assert found, out[-3000:]
    processed, received = int(found.group(1)), int(found.group(2))
    counts = {t: len(result[t]) for t in ("static_points", "moving_points", "labels")}
    print(f"\n{qos}: sent {result['sent']} clouds of {result['points']} points; node received {received}, "
          f"processed {processed}; subscriber got {counts}")
    # The node must have had work; how much reaches it from a best-effort publisher with Fast DDS's defaults is the
    # driver's side (9-19 of 40 measured, benchmarks/transport.md; clean-clone CI runs saw 4 and 1), so the peer
    # publishes on until MIN_PROCESSED labels came back, and only that floor is asserted here: enough scans for the
    # share below to mean something.
    assert processed >= MIN_PROCESSED, out[-3000:]
    for topic, n in counts.items():
        assert n >= MIN_SHARE * processed, f"{topic}: {n} of {processed} processed scans arrived"
