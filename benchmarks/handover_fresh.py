"""Autolabel's handover rule (``TrackConfig.handover_scans``) on fresh simulated drives no rule was found or tuned on:
seeds 9701-9732 (``benchmarks/autolabel.py --seeds fresh``; looked into since round 22). Prints, per drive, the
SemanticKITTI and instant IoU with the rule off and on.

    python benchmarks/handover_fresh.py [--data data/fresh]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from autolabel import FRESH_SEEDS, score_drive  # noqa: E402

from ros2_mos.offline.autolabel import AutolabelConfig  # noqa: E402
from ros2_mos.scoring.suite import ensure_sim_sequences  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=Path("data/fresh"))
    parser.add_argument("--scans", type=int, default=100)
    args = parser.parse_args()
    on = AutolabelConfig(online_cue=False)
    off = dataclasses.replace(on, tracks=dataclasses.replace(on.tracks, handover_scans=0))
    print("| drive | semantickitti off | semantickitti on | instant off | instant on |")
    print("|---|---:|---:|---:|---:|")
    rows = []
    for _, name, folder in ensure_sim_sequences(args.data, args.scans, FRESH_SEEDS, log=print):
        a, b = score_drive(folder, "hdl64", False, off), score_drive(folder, "hdl64", False, on)
        rows.append((a, b))
        print(f"| {name} | {100 * a['auto semantickitti']:.1f} | {100 * b['auto semantickitti']:.1f} | "
              f"{100 * a['auto instant']:.1f} | {100 * b['auto instant']:.1f} |", flush=True)
    for key in ("auto semantickitti", "auto instant"):
        print(f"mean {key}: off {100 * sum(a[key] for a, _ in rows) / len(rows):.2f}, "
              f"on {100 * sum(b[key] for _, b in rows) / len(rows):.2f}")


if __name__ == "__main__":
    main()
