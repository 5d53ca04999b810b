"""Where a default training iteration's CPU time goes, by torch operator, and two per-iteration costs
around it: torch's NaN fill of new tensors in deterministic mode and the watchdog's finiteness check.

1. torch's profiler over ``--iterations`` learner iterations (after ``--warmup``), once with the
   deterministic NaN fill on (what ``train.deterministic`` gave before it was switched off) and
   once off: each operator's self CPU time per iteration and calls per iteration.
2. The watchdog's check of every floating-point state tensor of the learner: ``isfinite().all()``
   per tensor (before session 3), a sum per tensor checked on its own (session 3) and the sums
   stacked and checked at once (`aectorch.runtime.watchdog._all_finite`, session 5), interleaved,
   medians of ``--repeats``.

Usage:
    python benchmarks/loop_ops.py                      # B = 32, the defaults
    python benchmarks/loop_ops.py --json benchmarks/results/loop_ops.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as train.py
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile  # noqa: E402


def build(num_envs: int):
    from omegaconf import OmegaConf

    from aectorch.framework import Shard
    from aectorch.runtime import prepare_run
    from aectorch.runtime.builders import build_env, build_learner, set_threads
    from aectorch.runtime.config import ExperimentConfig, to_experiment_config

    raw = OmegaConf.merge(OmegaConf.structured(ExperimentConfig), OmegaConf.from_dotlist([f"env.num_envs={num_envs}"]))
    cfg, _ = prepare_run(to_experiment_config(raw))
    set_threads(cfg.train.threads, 1)
    return build_env(cfg, Shard.single(num_envs)), build_learner(cfg)


def op_table(env, learner, iterations: int, fill: bool, top: int) -> dict:
    torch.utils.deterministic.fill_uninitialized_memory = fill
    start = time.perf_counter()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(iterations):
            learner.iteration(env)
    wall = time.perf_counter() - start
    events = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)
    total = sum(e.self_cpu_time_total for e in events)
    return {"fill": fill, "wall_ms_per_iteration": 1000 * wall / iterations,
            "self_cpu_ms_per_iteration": total / 1000 / iterations,
            "ops": [{"op": e.key, "self_cpu_ms_per_iteration": e.self_cpu_time_total / 1000 / iterations,
                     "share": e.self_cpu_time_total / total, "calls_per_iteration": e.count / iterations}
                    for e in events[:top]]}


def watchdog_check(learner, repeats: int) -> dict:
    from aectorch.runtime.watchdog import _all_finite

    named = list(learner.named_parameters()) + list(learner.named_buffers())
    tensors = [t for _, t in named if t.is_floating_point() and t.numel() > 0]

    def before():
        return torch.stack([t.detach().isfinite().all() for t in tensors]).tolist()

    def each_sum():  # session 3's form: each sum checked and moved on its own
        return torch.stack([t.detach().sum().isfinite() for t in tensors]).tolist()

    def after():
        return _all_finite(tensors)

    assert before() == each_sum() == after()
    times: dict[str, list[float]] = {"isfinite().all() per tensor": [], "a sum per tensor, each checked": [],
                                     "the sums stacked, checked at once (_all_finite)": []}
    for _ in range(repeats):
        for label, fn in zip(times, (before, each_sum, after)):
            start = time.perf_counter()
            for _ in range(20):
                fn()
            times[label].append(1000 * (time.perf_counter() - start) / 20)
    return {"tensors": len(tensors), "elements": sum(t.numel() for t in tensors),
            "ms_per_check": {k: statistics.median(v) for k, v in times.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--warmup", type=int, default=30)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "loop_ops.json")
    args = parser.parse_args()
    torch.use_deterministic_algorithms(True, warn_only=True)  # as train.deterministic
    env, learner = build(args.num_envs)
    for _ in range(args.warmup):
        learner.iteration(env)
    tables = [op_table(env, learner, args.iterations, fill, args.top) for fill in (True, False)]
    for table in tables:
        print(f"\nNaN fill {'on' if table['fill'] else 'off'}: {table['self_cpu_ms_per_iteration']:.1f} ms self CPU "
              f"per iteration (wall {table['wall_ms_per_iteration']:.1f} ms, profiled)\n")
        print("| operator | ms / iteration | share | calls / iteration |\n|---|---:|---:|---:|")
        for op in table["ops"]:
            print(f"| `{op['op']}` | {op['self_cpu_ms_per_iteration']:.2f} | {op['share']:.1%} | "
                  f"{op['calls_per_iteration']:.1f} |")
    check = watchdog_check(learner, args.repeats)
    print(f"\nwatchdog check of {check['tensors']} state tensors ({check['elements']:,} values), medians:")
    for label, ms in check["ms_per_check"].items():
        print(f"  {label}: {ms:.3f} ms")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    report = {"benchmark": "loop_ops", "num_envs": args.num_envs, "iterations": args.iterations,
              "machine": machine_info(), "profiles": tables, "watchdog": check}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
