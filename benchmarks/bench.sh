#!/usr/bin/env bash
# The benchmark as recorded in benchmarks/bench.md and docs/evaluation.md (issue 8): the shipped model, FastMOS
# N=1 and N=8 and SalsaNext N=8 with random weights (timing only), the LiDAR-MOS-style reference, and
# mos_node under replay at 10 and 20 Hz. Extra options go to `ros2-mos bench` (e.g. --geometry torch).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=ros2-mos
[ -x .venv/bin/ros2-mos ] && BIN=.venv/bin/ros2-mos   # `make install`'s venv, else the one on PATH
exec "$BIN" bench --scans 40 --reference-scans 3 \
    --untrained fastmos:1 --untrained fastmos:8 --untrained salsanext:8 \
    --out benchmarks/bench.md "$@"
