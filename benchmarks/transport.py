"""Issue 14: what a subscriber in another process gets from mos_node, with and without a DDS profile.

    python benchmarks/transport.py [--scans 40] [--repeat 2] [--setup N]... [--qos sensor|reliable]
                                   [--node-param NAME:=VALUE]...

For each setup (no profile anywhere but the node's own; a profile-less node as well, i.e. Fast DDS
defaults everywhere; the shipped profile in every process) and each QoS (sensor data / reliable), a
peer process (test/integration/transport_peer.py) publishes full-size HDL-64-like clouds at 10 Hz and
counts what comes back. Prints a Markdown table. ``--setup`` (1-3, in that order) and ``--qos`` pick rows;
``--node-param`` passes a parameter to every mos_node (e.g. ``worker_nice:=5``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PEER = ROOT / "test" / "integration" / "transport_peer.py"
EMPTY_PROFILE = '<?xml version="1.0"?>\n<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"/>\n'


def run(setup: str, qos: str, scans: int, domain: int, empty: Path, node_params: list[str]) -> dict:
    from ros2_mos.ros.dds import PROFILE_VARIABLES, profile_path

    base = {k: v for k, v in os.environ.items() if k not in PROFILE_VARIABLES and k != "RMW_IMPLEMENTATION"}
    base.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    node_env, peer_env = dict(base), dict(base)
    if setup == "Fast DDS defaults everywhere":  # a user profile with nothing in it: the node keeps it
        node_env.update({v: str(empty) for v in PROFILE_VARIABLES})
    elif setup == "shipped profile in every process":
        for env in (node_env, peer_env):
            env.update({v: str(profile_path()) for v in PROFILE_VARIABLES})
    node = subprocess.Popen([str(Path(sys.executable).parent / "mos_node"), "--ros-args", "-p",
                             "qos.reliability:=" + ("reliable" if qos == "reliable" else "best_effort"),
                             *[arg for p in node_params for arg in ("-p", p)]],
                            env=node_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        peer = subprocess.run([sys.executable, str(PEER), "--scans", str(scans), "--qos", qos], env=peer_env,
                              capture_output=True, text=True, timeout=300)
    finally:
        node.send_signal(2)
        out, _ = node.communicate(timeout=30)
    result = json.loads(peer.stdout.strip().splitlines()[-1])
    found = re.search(r"final statistics: (\d+)/(\d+) scans processed", out)
    lost = re.search(r"lost: (\d+) in the node's queue, ~(\d+) on the way in", out)
    return {"sent": result["sent"], "received": int(found.group(2)), "processed": int(found.group(1)),
            "queue": int(lost.group(1)), "transport": int(lost.group(2)),
            **{t: len(result[t]) for t in ("static_points", "moving_points", "labels")}}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scans", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--setup", type=int, action="append", choices=(1, 2, 3), help="only these setups")
    parser.add_argument("--qos", action="append", choices=("sensor", "reliable"), help="only these QoS")
    parser.add_argument("--node-param", action="append", default=[], help="NAME:=VALUE for every mos_node")
    args = parser.parse_args()
    setups = ("no profile set by the user (the node sets its own)", "Fast DDS defaults everywhere",
              "shipped profile in every process")
    setups = tuple(s for k, s in enumerate(setups, 1) if not args.setup or k in args.setup)
    if args.node_param:
        print("mos_node parameters: " + ", ".join(args.node_param))
    print("| setup | subscriber QoS | run | sent | node received | node processed | lost in queue / on the way in |"
          " static / moving / labels received | share of processed |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        empty = Path(tmp) / "empty.xml"
        empty.write_text(EMPTY_PROFILE)
        domain = 150
        for setup in setups:
            for qos in args.qos or ("sensor", "reliable"):
                for k in range(args.repeat):
                    domain += 1
                    r = run(setup, qos, args.scans, domain, empty, args.node_param)
                    got = (r["static_points"], r["moving_points"], r["labels"])
                    share = min(got) / r["processed"] if r["processed"] else float("nan")
                    print(f"| {setup} | {qos} | {k + 1} | {r['sent']} | {r['received']} | {r['processed']} | "
                          f"{r['queue']} / {r['transport']} | {' / '.join(map(str, got))} | {100 * share:.0f} % |",
                          flush=True)


if __name__ == "__main__":
    main()
