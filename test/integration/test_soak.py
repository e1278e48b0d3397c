"""A short soak of a mos_node process (benchmarks/soak.py, ~20 s of publishing): 10 Hz, then 3x the node's
capacity, the bag looped with its recorded stamps; stopped with SIGTERM. The long run is the script itself."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]


def test_short_soak_bounded_queue_memory_drops_reported_and_sigterm(tmp_path, tiny_model_path):
    out = tmp_path / "soak.json"
    domain = 45 + os.getpid() % 150 + 5  # apart from test_node's domains in the same run
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "soak.py"), "--seconds", "20", "--overload", "3",
         "--model", str(tiny_model_path), "--scans", "30", "--warmup", "5", "--domain", str(domain),
         "--json", str(out)],
        env=env, capture_output=True, text=True, timeout=120)
    print(done.stdout)
    assert out.is_file(), done.stdout + done.stderr
    r = json.loads(out.read_text())
    ten, overload = r["phases"]

    # The node survived the whole run and stopped cleanly on SIGTERM with its final statistics.
    assert r["node_exit_code"] == 0 and done.returncode == 0, done.stdout + done.stderr
    assert r["final_statistics"] and "scans processed" in r["final_statistics"], r["node_log_tail"]
    assert not r["traceback_in_log"], r["node_log_tail"]
    assert ten["processed"] > 0 and overload["processed"] > 0
    assert r["final_counts"]["errors"] == 0

    # Overloaded: clouds were dropped, counted and reported on /diagnostics...
    assert overload["dropped"] > 0, overload
    assert r["dropped_reported_max"] == r["final_counts"]["dropped"] > 0
    # ...and never queued: at most one waiting and one in hand (plus one being handed over) in any
    # diagnostics sample, and every received cloud was processed, dropped or skipped in the end.
    assert r["diagnostics_messages"] >= 10
    assert r["in_flight_max"] <= 3, r["in_flight_max"]
    assert r["unaccounted_at_end"] == 0, r["final_counts"]

    # Every loop of the bag makes time go backwards: the node reset its buffer, counted and logged it.
    assert ten["loop_wraps"] >= 2
    assert r["backwards_resets_logged"] >= 1 and r["final_counts"]["resets"] >= r["backwards_resets_logged"]

    # Memory stays bounded after warm-up (generous: the point is no growth with the scans processed).
    rss = r["rss"]
    assert rss["samples"] >= 20
    assert rss["max_above_warmup_mb"] < 50.0, rss
