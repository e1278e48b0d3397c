"""Issue 29: how fast `ros2-mos autolabel` labels a drive, alone or alternating with another checkout of the code.

    python benchmarks/autolabel_speed.py data/real-kitti-raw-sfnd/sequences/r2 --sensor hdl64 --deskew on
    git worktree add /tmp/previous HEAD~1 && (cd /tmp/previous && python setup.py build_ext --inplace)
    python benchmarks/autolabel_speed.py DRIVE --sensor hdl64 --deskew on --against /tmp/previous --runs 5

Each run is the CLI in a process of its own (`python -m ros2_mos.cli autolabel`), started from an empty folder so
that the code imported is the checkout's named on PYTHONPATH, not the one a working directory would put first.
With ``--against`` the two checkouts alternate A B B A A B ..., so that a machine that speeds up or slows down over
the minutes weighs on both alike. Prints per run the CLI's own scans/s (which leaves out the start), the wall time,
the CPU seconds of the run's processes and its peak memory (the resident memory of the CLI and every process it
started, summed, read from /proc every 0.2 s; Linux only, nan elsewhere); then per checkout the medians, and the
ratio of the medians; and whether the last runs' label files are identical. Run it on drives of 200 and 2,000 scans
to see whether memory grows with a drive's length (issue 29: it must not). The machine should be otherwise idle: the
same code spreads 4.5-6.2 scans/s from hour to hour on the project's 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
SPEED = re.compile(r"([0-9.]+) scans/s")


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def tree_rss_mb(pid: int) -> float | None:
    """The resident memory (MB) of process ``pid`` and all its descendants, summed; None where /proc cannot say."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    tree, grew = {pid}, True
    while grew:
        more = {child for child, parent in parents.items() if parent in tree} - tree
        tree |= more
        grew = bool(more)
    total = 0.0
    for member in tree:
        try:
            status = Path(f"/proc/{member}/status").read_text()
        except OSError:
            continue
        total += next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")), 0) / 1024
    return total if total > 0 else None


def run_once(checkout: Path, drive: Path, sensor: str, deskew: str, out: Path) -> dict[str, float]:
    """One `ros2-mos autolabel` of ``drive`` with ``checkout``'s code into ``out``: its scans/s, wall and CPU s, and
    peak MB (nan where /proc cannot say)."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    command = [sys.executable, "-m", "ros2_mos.cli", "autolabel", str(drive), "--out", str(out), "--sensor", sensor,
               "--deskew", deskew]
    cpu, start = children_cpu(), time.perf_counter()
    peak = float("nan")
    with tempfile.TemporaryDirectory() as empty, tempfile.TemporaryFile("w+") as stdout, \
            tempfile.TemporaryFile("w+") as stderr:
        process = subprocess.Popen(command, cwd=empty, env=env, stdout=stdout, stderr=stderr, text=True)
        while process.poll() is None:
            rss = tree_rss_mb(process.pid)
            if rss is not None:
                peak = rss if np.isnan(peak) else max(peak, rss)
            time.sleep(0.2)
        stdout.seek(0)
        stderr.seek(0)
        done = subprocess.CompletedProcess(command, process.returncode, stdout.read(), stderr.read())
    wall, cpu = time.perf_counter() - start, children_cpu() - cpu
    found = SPEED.findall(done.stdout.strip().splitlines()[-1]) if done.returncode == 0 and done.stdout.strip() else []
    if not found:
        last = (done.stderr.strip() or done.stdout.strip() or "no output").splitlines()[-1]
        raise SystemExit(f"autolabel_speed: {checkout}: the run failed ({last})")
    return {"scans/s": float(found[-1]), "wall": wall, "cpu": cpu, "peak MB": peak}


def label_files_differ(a: Path, b: Path) -> int:
    """How many label files of two output roots differ (or exist in one only)."""
    files_a = {p.relative_to(a): p for p in a.rglob("*.label")}
    files_b = {p.relative_to(b): p for p in b.rglob("*.label")}
    both = files_a.keys() & files_b.keys()
    return len(files_a.keys() ^ files_b.keys()) + sum(files_a[n].read_bytes() != files_b[n].read_bytes() for n in both)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("drive", type=Path, help="a drive autolabel reads (a sequence folder or a bag)")
    parser.add_argument("--sensor", required=True)
    parser.add_argument("--deskew", choices=("auto", "on", "off"), default="auto")
    parser.add_argument("--runs", type=int, default=3, help="runs of each checkout")
    parser.add_argument("--against", type=Path, help="another checkout (its kernels built) to alternate with")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be 1 or more")
    if not args.drive.exists():
        parser.error(f"no drive at {args.drive}")
    checkouts = {"this": HERE}
    if args.against is not None:
        if not (args.against / "ros2_mos" / "__init__.py").is_file():
            parser.error(f"--against {args.against}: not a checkout of this project (no ros2_mos/__init__.py)")
        checkouts["against"] = args.against.resolve()
    names = list(checkouts)
    order = [names[(i + i // 2) % len(names)] for i in range(len(names) * args.runs)]  # A B B A A B ...
    print(f"`ros2-mos autolabel {args.drive} --sensor {args.sensor} --deskew {args.deskew}`, "
          f"{time.strftime('%Y-%m-%d %H:%M')}: " + ", ".join(f"{n} = {p}" for n, p in checkouts.items()) + "\n")
    print("| run | code | scans/s | wall s | CPU s | peak MB |")
    print("|---:|---|---:|---:|---:|---:|")
    rows: dict[str, list[dict[str, float]]] = {n: [] for n in names}
    with tempfile.TemporaryDirectory() as work:
        for i, name in enumerate(order):
            out = Path(work) / name
            shutil.rmtree(out, ignore_errors=True)
            row = run_once(checkouts[name], args.drive.resolve(), args.sensor, args.deskew, out)
            rows[name].append(row)
            print(f"| {i + 1} | {name} | {row['scans/s']:.1f} | {row['wall']:.1f} | {row['cpu']:.1f} | "
                  f"{row['peak MB']:.0f} |", flush=True)
        differ = label_files_differ(Path(work) / names[0], Path(work) / names[-1]) if len(names) > 1 else None
    print()
    medians = {n: {k: float(np.median([r[k] for r in rows[n]])) for k in ("scans/s", "wall", "cpu")} for n in names}
    for n in names:
        m = medians[n]
        print(f"{n}: median {m['scans/s']:.1f} scans/s, wall {m['wall']:.1f} s, CPU {m['cpu']:.1f} s, "
              f"peak {max(r['peak MB'] for r in rows[n]):.0f} MB ({len(rows[n])} runs)")
    if len(names) > 1:
        ratio = medians["this"]["scans/s"] / medians["against"]["scans/s"]
        print(f"this / against: {ratio:.2f}x scans/s; label files differing between the last runs: {differ}")


if __name__ == "__main__":
    main()
