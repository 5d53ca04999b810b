"""Env-iterations per second of the standard RL environments beside the training loop, in one run.

Two workloads, interleaved round by round in this one process (so that the ratio is robust to the
machine's drift), each timed step by step after a warm-up, median over the steps:

  * ``train loop``: ``JointLearner.iteration`` on ``ActiveDepthEnv`` with train.py's defaults
    (B = 32, both cues, learning): B env-iterations per iteration.
  * ``Vergence-v0``: ``gymnasium.make_vec("aectorch/Vergence-v0", num_envs=N,
    vectorization_mode="vector_entry_point")`` stepped with random actions (default N = 256,
    features observation, the internal encoder learning): N env-iterations per step, NumPy
    conversion at Gymnasium's boundary included. With the default ``reward="improvement"``, with
    ``reward="coding"`` (the default before it, and the same steps without the subtraction), with
    ``reward="scaled"``, and with ``reward="error"`` and ``observation="images"``, which need no
    encoder.

``--clock cpu`` times each step by this process's CPU time (``time.process_time``, all its
threads) instead of the wall clock: on a machine shared with other jobs, the time they take the
cores away is then left out.

Usage:
    python benchmarks/rl_envs.py [--num-envs 256] [--rounds 5] [--steps 20] [--clock wall|cpu] [--json benchmarks/results/rl_envs.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch


def _train_loop(batch: int):
    from aectorch.framework import JointLearner, LearnerConfig
    from aectorch.sim import ActiveDepthEnv, TextureBank

    env = ActiveDepthEnv(batch, textures=TextureBank.default("train"), seed=0)
    learner = JointLearner(LearnerConfig(), generator=torch.Generator().manual_seed(0))
    return batch, lambda: learner.iteration(env), env.close


def _vergence(num_envs: int, **options):
    import gymnasium as gym

    import aectorch.envs  # noqa: F401  (registers the ids)

    envs = gym.make_vec("aectorch/Vergence-v0", num_envs=num_envs, vectorization_mode="vector_entry_point", **options)
    envs.reset(seed=0)
    envs.action_space.seed(0)
    return num_envs, lambda: envs.step(envs.action_space.sample()), envs.close


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--batch", type=int, default=32, help="the training loop's B (train.py: 32)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=20, help="timed steps per workload and round")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                        help="wall: time.perf_counter; cpu: time.process_time (this process's CPU time)")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/rl_envs.json"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)  # train.py's default: torch ops on one thread, the fused kernels on every core
    workloads = {
        f"train loop (B = {args.batch})": _train_loop(args.batch),
        f"Vergence-v0, features + improvement (N = {args.num_envs})": _vergence(args.num_envs),
        f"Vergence-v0, features + coding (N = {args.num_envs})": _vergence(args.num_envs, reward="coding"),
        f"Vergence-v0, features + scaled (N = {args.num_envs})": _vergence(args.num_envs, reward="scaled"),
        f"Vergence-v0, features + error (N = {args.num_envs})": _vergence(args.num_envs, reward="error"),
        f"Vergence-v0, images + error (N = {args.num_envs})": _vergence(args.num_envs, observation="images",
                                                                         reward="error"),
    }
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    times: dict[str, list[float]] = {name: [] for name in workloads}
    for name, (_, step, _) in workloads.items():
        for _ in range(args.warmup):
            step()
    for _ in range(args.rounds):
        for name, (_, step, _) in workloads.items():
            for _ in range(args.steps):
                start = clock()
                step()
                times[name].append(clock() - start)
    rows = {}
    for name, (n, _, close) in workloads.items():
        median = statistics.median(times[name])
        rows[name] = {"env_iterations_per_step": n, "median_step_s": median, "env_iterations_per_s": n / median}
        close()
    base = next(iter(rows.values()))["env_iterations_per_s"]
    print(f"| workload | env-iterations per step | median step (ms) | env-iterations/s | vs the training loop |")
    print("|---|---|---|---|---|")
    for name, row in rows.items():
        row["ratio_to_train_loop"] = row["env_iterations_per_s"] / base
        print(f"| {name} | {row['env_iterations_per_step']} | {row['median_step_s'] * 1e3:.1f} | "
              f"{row['env_iterations_per_s']:.0f} | {row['ratio_to_train_loop']:.2f}x |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": platform.processor() or platform.machine(), "torch": torch.__version__,
                                     "args": {k: str(v) for k, v in vars(args).items()}, "rows": rows,
                                     "samples_s": times}, indent=1) + "\n")
    print(f"written to {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
