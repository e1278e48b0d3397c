"""Simulate the training data, then train one or more variants of a recipe side by side.

    python tools/train_models.py --config configs/fastmos_signed.yaml --data data/train \\
        [--variant "NAME KEY=VALUE ..."]... [--runs runs] [--scans 120] [--jobs N] [--pack runs.tar]

Sequence names in the config say which preset each is simulated with (b* benchmark,
t* traffic_jam, e* easy, s* slow_traffic); every sequence gets its own randomised sensor effects
(:func:`ros2_mos.sim.presets.randomized_for_sequence`) from ``--seed`` (100 by default;
the evaluation suite's seeds are different, see :mod:`ros2_mos.scoring.suite`).
Sequences already on disk are kept where this simulator wrote them with these settings
(their ``simulator.txt``); others (another seed, scan count, sensor or simulator version,
or cut short) are simulated anew.  The first variant builds the shared input
cache; the others start once it trains.  Without ``--variant`` the config is
trained as it is.  A run resumes from its ``last.pt``.

Library calls only (no CLI, no ROS, no ONNX Runtime): it runs where only numpy,
torch, PyYAML and embreex are installed, e.g. a bare GPU machine.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import shutil
import signal
import sys
import tarfile
import time
from pathlib import Path

import yaml

PRESET_OF_PREFIX = {"b": "benchmark", "t": "traffic_jam", "e": "easy", "s": "slow_traffic"}


def _preset(name: str, seed: int, large_trees: bool, beam_layout: bool, narrow_street: bool, parked_vans: bool):
    from ros2_mos.sim import sim_preset
    from ros2_mos.sim.presets import randomized_for_sequence

    return randomized_for_sequence(sim_preset(PRESET_OF_PREFIX[name[0]]), seed, name, large_trees, beam_layout,
                                   narrow_street, parked_vans)


def _simulate(job: tuple[str, str, int, int, object, object]) -> str:
    from ros2_mos.sim import simulate_sequence

    root, name, scans, seed, preset, sensor = job
    folder = Path(root) / "sequences" / name
    if folder.exists():  # another simulator's, other settings', or cut short (main checked)
        shutil.rmtree(folder)
    simulate_sequence(root, name, scans, preset, seed, sensor=sensor, convention="instant")
    return name


def _train(config: dict, data: str, log_path: str) -> None:
    from ros2_mos.training.trainer import TrainConfig, Trainer

    with open(log_path, "a", buffering=1) as log:
        cfg = TrainConfig.from_dict(config)
        trainer = Trainer(cfg, data, log=lambda s: print(s, file=log), show_progress=False)
        print(f"{cfg.setup.label}: {len(trainer.train_set)} train / {len(trainer.valid_set)} valid scans", file=log)
        start = time.monotonic()
        trainer.fit()
        print(f"trained in {(time.monotonic() - start) / 60:.1f} min", file=log)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("--runs", default="runs")
    parser.add_argument("--variant", action="append", default=[], help='"NAME KEY=VALUE ..." (VALUE in YAML)')
    parser.add_argument("--scans", type=int, default=100)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=mp.cpu_count())
    parser.add_argument("--pack", help="write the run folders (no caches) into this tar file at the end")
    parser.add_argument("--simulate-only", action="store_true", help="simulate the sequences, train nothing")
    args = parser.parse_args()

    base = yaml.safe_load(Path(args.config).read_text())
    variants = []
    for text in args.variant or [Path(args.config).stem]:
        name, *pairs = text.split()
        overrides = {}
        for pair in pairs:
            key, sep, value = pair.partition("=")
            if not sep:
                print(f"error: variant {name}: {pair!r} is not KEY=VALUE", file=sys.stderr)
                return 2
            overrides[key] = yaml.safe_load(value)
        variants.append((name, {**base, **overrides, "out_dir": str(Path(args.runs) / name)}))
    # Every sequence some variant trains or validates on (a variant may override the lists).
    names = list(dict.fromkeys(str(n) for _, config in variants
                               for n in [*config["train_sequences"], *config["valid_sequences"]]))
    unknown = [n for n in names if n[:1] not in PRESET_OF_PREFIX]
    if unknown:
        print(f"error: sequence names must start with one of {', '.join(PRESET_OF_PREFIX)} (the preset): {unknown}",
              file=sys.stderr)
        return 2
    start = time.monotonic()
    from ros2_mos.core.config import SensorConfig
    from ros2_mos.sim.writer import made_by_this_simulator

    sensor = base.get("sensor", "hdl64")  # a preset name, or a custom sensor's dict
    sensor = sensor if isinstance(sensor, str) else SensorConfig.from_dict(sensor)
    narrow = {str(n) for n in base.get("sim_narrow_streets", [])}
    vans = {str(n) for n in base.get("sim_parked_vans", [])}
    jobs = [(args.data, n, args.scans, args.seed,
             _preset(n, args.seed, bool(base.get("sim_large_trees", False)), bool(base.get("sim_beam_layout", True)),
                     n in narrow, n in vans), sensor) for n in names]
    todo = [job for job in jobs
            if not made_by_this_simulator(Path(args.data) / "sequences" / job[1], job[4], sensor, args.seed,
                                          args.scans)]
    stale = [job[1] for job in todo if (Path(args.data) / "sequences" / job[1]).exists()]
    if stale:
        print(f"simulating anew (another simulator, other settings, or cut short): {' '.join(stale)}", flush=True)
    with mp.get_context("spawn").Pool(max(1, args.jobs)) as pool:
        for name in pool.imap_unordered(_simulate, todo):
            pass
    print(f"simulated {len(todo)} of {len(names)} sequences x {args.scans} scans in {time.monotonic() - start:.0f} s",
          flush=True)
    if args.simulate_only:
        return 0

    runs = Path(args.runs)
    runs.mkdir(parents=True, exist_ok=True)
    ctx = mp.get_context("spawn")
    procs: list = []

    def stop(signum: int, _frame: object) -> None:  # the training processes end with this one
        for proc in procs:
            proc.terminate()
        sys.exit(128 + signum)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    for k, (name, config) in enumerate(variants):
        proc = ctx.Process(target=_train, args=(config, args.data, str(runs / f"{name}.log")))
        proc.start()
        procs.append(proc)
        if k == 0:  # the first one builds the shared cache; wait until it trains
            while proc.is_alive() and not (Path(config["out_dir"]) / "config.yaml").is_file():
                time.sleep(2)
    for proc in procs:
        proc.join()
    for name, _ in variants:
        print(f"== {name}\n" + "".join((runs / f"{name}.log").read_text().splitlines(True)[-3:]), flush=True)
    if args.pack:
        with tarfile.open(args.pack, "w") as tar:
            for name, _ in variants:
                for f in ("best.pt", "last.pt", "metrics.csv", "config.yaml"):
                    if (runs / name / f).is_file():
                        tar.add(runs / name / f, arcname=f"{name}/{f}")
                tar.add(runs / f"{name}.log", arcname=f"{name}.log")
    print(f"total {time.monotonic() - start:.0f} s")
    return 0 if all(p.exitcode == 0 for p in procs) else 1


if __name__ == "__main__":
    sys.exit(main())
