"""Env-iterations per second of ``aectorch/Vergence-v0`` (``gymnasium.make_vec``, random actions, each
reward and observation) beside the training loop's default run, interleaved in one process.
``AECTORCH_BENCH_CLOCK=cpu`` times the process's CPU time, which leaves out what other jobs take.
"""

import os
import statistics
import time

import torch

from benchmarks import harness

OPTIONS = {"features + improvement": {}, "features + coding": {"reward": "coding"},
           "features + scaled": {"reward": "scaled"}, "features + error": {"reward": "error"},
           "images + error": {"observation": "images", "reward": "error"}}


def _vergence(num_envs: int, **options):
    import gymnasium as gym

    import aectorch.envs  # noqa: F401  (registers the ids)

    envs = gym.make_vec("aectorch/Vergence-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                        **harness.size({"textures": torch.rand(4, 96, 96)}, {}), **options)
    envs.reset(seed=0)
    envs.action_space.seed(0)
    return envs


def test_rl_envs(benchmark):
    torch.set_num_threads(1)  # train.py's default: torch ops on one thread, the fused kernels on every core
    batch, num_envs = harness.size(2, 32), harness.size(4, 64)
    env, learner = harness.default_run(batch)
    workloads, sizes, vectors = {f"train loop (B = {batch})": lambda: learner.iteration(env)}, [batch], []
    for name, options in OPTIONS.items():
        vectors.append(_vergence(num_envs, **options))
        workloads[f"Vergence-v0, {name} (N = {num_envs})"] = lambda e=vectors[-1]: e.step(e.action_space.sample())
        sizes.append(num_envs)
    clock = time.process_time if os.environ.get("AECTORCH_BENCH_CLOCK") == "cpu" else time.perf_counter
    times = benchmark.pedantic(harness.interleaved, args=(workloads,), kwargs=dict(
        rounds=harness.size(1, 3), calls=harness.size(1, 8), warmup=harness.size(1, 3), clock=clock))
    for vector in vectors:
        vector.close()
    rows = [{"variant": name, "env_iterations_per_step": n, "median_step_s": statistics.median(times[name]),
             "env_iterations_per_s": n / statistics.median(times[name]), "clock": clock.__name__}
            for (name, n) in zip(workloads, sizes)]
    assert all(row["env_iterations_per_s"] > 0 for row in rows)
    harness.record("rl_envs", rows, benchmark)
