"""Steady-state env-iterations per second of the training loop, measured inside each process.

`train_rate.py` differences the wall times of two fresh ``train.py`` processes, so start-up noise
(20-30 s of imports and set-up per process on a busy virtual machine) lands in the rate. Here each
configuration runs `aectorch.runtime.run_experiment` (``train.py``'s loop: callbacks, watchdog,
metrics; evaluation, figures, TensorBoard and the progress bar off) in a fresh process, and the rate
is taken from the timestamps of iterations ``--skip`` to the last. Rounds run every configuration
once, in turn (the order reversed every other round); the table shows medians, and each
configuration's round-by-round ratio to the first.

Configurations are `train_rate.py`'s: ``LABEL=new|old|COMMIT[:key=value,...,env:NAME=VALUE]``
(``old``: ``--baseline``; a commit runs from a git worktree beside ``--worktree``).

Usage:
    python benchmarks/loop_rate.py --configs "before=0d9b7b4" "now=new"
    python benchmarks/loop_rate.py --configs "sleep=new" "spin=new:env:GOMP_SPINCOUNT=10000" --rounds 5
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(root: str, iterations: int, skip: int, overrides: list[str]) -> None:
    """In a fresh process: the loop of ``root``'s aectorch, one line ``RATE <env-it/s>``."""
    sys.path.insert(0, root)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as train.py
    from omegaconf import OmegaConf

    from aectorch.runtime import run_experiment
    from aectorch.runtime.config import ExperimentConfig, to_experiment_config

    quiet = ["eval.enabled=false", "train.figures=false", "train.progress=false", "train.tensorboard=false",
             "train.checkpoint_every=100000", f"train.iterations={iterations}"]
    cfg = to_experiment_config(OmegaConf.merge(OmegaConf.structured(ExperimentConfig),
                                               OmegaConf.from_dotlist(quiet + overrides)))
    stamps: list[float] = []
    with tempfile.TemporaryDirectory() as folder:
        run_experiment(cfg, folder, callback=lambda done, record: stamps.append(time.perf_counter()))
    rate = (len(stamps) - 1 - skip) * cfg.env.num_envs / (stamps[-1] - stamps[skip])
    print(f"RATE {rate}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", nargs="+", required=True)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=160)
    parser.add_argument("--skip", type=int, default=20, help="first iterations not timed (warm-up)")
    parser.add_argument("--baseline", default="b39d619")
    parser.add_argument("--worktree", type=Path, default=Path(tempfile.gettempdir()) / "aectorch-baseline")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "loop_rate.json")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        root, iterations, skip, *overrides = args.child
        child(root, int(iterations), int(skip), overrides)
        return
    if args.iterations <= args.skip + 1:
        raise SystemExit(f"--iterations must exceed --skip + 1 ({args.skip + 1}), got {args.iterations}")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info
    from benchmarks.train_rate import parse, worktree

    configs = [parse(text, 0, 0) for text in args.configs]
    folders = {"new": ROOT}
    for config in configs:
        where = config["where"]
        if where not in folders:
            commit = args.baseline if where == "old" else where
            folders[where] = worktree(commit, args.worktree if where == "old" else args.worktree.with_name(
                f"aectorch-{commit}"))
    rates: dict[str, list[float]] = {c["label"]: [] for c in configs}
    for round_ in range(args.rounds):
        for config in configs if round_ % 2 == 0 else configs[::-1]:
            env = dict(os.environ, PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"), **config["env"])
            command = [sys.executable, str(Path(__file__).resolve()), "--configs", "-", "--child",
                       str(folders[config["where"]]), str(args.iterations), str(args.skip), *config["overrides"]]
            result = subprocess.run(command, env=env, capture_output=True, text=True)
            lines = [line for line in result.stdout.splitlines() if line.startswith("RATE ")]
            if result.returncode or not lines:
                raise SystemExit(f"{config['label']}: failed ({result.returncode}):\n{result.stderr[-2000:]}")
            rates[config["label"]].append(float(lines[-1].split()[1]))
            print(f"round {round_ + 1}: {config['label']}: {rates[config['label']][-1]:,.1f} env-iterations/s",
                  file=sys.stderr, flush=True)
    first = rates[configs[0]["label"]]
    print(f"\n{args.rounds} round(s), iterations {args.skip + 1}-{args.iterations} timed, medians\n")
    print("| configuration | env-iterations/s | x first (median of rounds) | x first, round by round |")
    print("|---|---:|---:|---|")
    rows = []
    for label, values in rates.items():
        paired = [v / f for v, f in zip(values, first)]
        rows.append({"label": label, "rates": values, "env_iterations_per_s": statistics.median(values),
                     "ratio_to_first_by_round": paired, "ratio_to_first": statistics.median(paired)})
        print(f"| {label} | {statistics.median(values):,.1f} | {statistics.median(paired):.2f}x | "
              f"{', '.join(f'{p:.2f}' for p in paired)} |")
    report = {"benchmark": "loop_rate", "iterations": args.iterations, "skip": args.skip, "rounds": args.rounds,
              "configs": args.configs, "machine": machine_info(), "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
