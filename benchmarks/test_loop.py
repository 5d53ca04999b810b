"""The training loop in one process: env-iterations/s of train.py's default run, each stage's ms per
env-iteration beside the floor of its matrix-product FLOPs at the matmul rate measured in the same
process (docs/performance.md), and the peak memory's rise (on CUDA, ``max_memory_allocated``).

``AECTORCH_BENCH_DEVICE=cuda`` runs on a GPU, where ``mode=compile`` is ``train.compile=true``.
"""

import os
import statistics
from pathlib import Path

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from aectorch import profiling
from aectorch.ops import native, use_backend
from aectorch.runtime.builders import compile_hot_path
from aectorch.runtime.loop import frozen_heap
from benchmarks import harness

DEVICE = os.environ.get("AECTORCH_BENCH_DEVICE", "cpu")
STAGES = ("render", "encode", "dictionary", "rl", "env", "metrics", "depth")


class FlopStages(profiling.StageTimer):
    def __init__(self):  # one FlopCounterMode per stage
        super().__init__()
        self.flops: dict[str, int] = {}
        self._counters: list[FlopCounterMode] = []

    def _push(self, name):
        self._counters.append(FlopCounterMode(display=False).__enter__())
        super()._push(name)

    def _pop(self, name):
        super()._pop(name)
        counter = self._counters.pop()
        counter.__exit__(None, None, None)
        self.flops[name] = self.flops.get(name, 0) + counter.get_total_flops()


def _rss_mb(field: str) -> float:
    return next(int(line.split()[1]) / 1024 for line in Path("/proc/self/status").read_text().splitlines()
                if line.startswith(field + ":"))


def flops_per_env_iteration(learner, env, batch: int) -> dict[str, float]:
    """Each stage's matrix-product FLOPs per env-iteration, the dictionary step's as its sparse gradient."""
    with use_backend("torch"), FlopStages() as counted:
        learner.iteration(env)
    counted.flops["dictionary"] = sum(2 * batch * scale.num_patches * cue.encoder.dictionaries[scale.name].sparsity
                                      * cue.encoder.dictionaries[scale.name].dim
                                      for cue in learner.cues.values() for scale in cue.encoder.scales)
    return {k: counted.flops.get(k, 0) / batch for k in STAGES}


def matmul_rates(batch: int, device: str) -> dict[str, float]:
    """float32 FLOP/s of the loop's largest product ``[B x 122, 200] x [200, 288]``, per library."""
    a, b = torch.randn(batch * 122, 200, device=device), torch.randn(200, 288, device=device)
    out, b_t = torch.empty(batch * 122, 288, device=device), b.t().contiguous()
    products = {"mm": lambda: torch.mm(a, b, out=out)}
    if device == "cpu" and hasattr(torch.ops.mkldnn, "_linear_pointwise"):
        products["onednn"] = lambda: torch.ops.mkldnn._linear_pointwise(a, b_t, None, "none", [], "")
    flops = 2 * a.shape[0] * 200 * 288
    return {name: flops / harness.median_seconds(product, harness.size(None, 0.5)) for name, product in products.items()}


@pytest.mark.parametrize("mode", ["eager", "compile"])
@pytest.mark.parametrize("kernel_threads", harness.size([1], [1, 2]))
@pytest.mark.parametrize("batch", harness.size([2], [32, 256] if DEVICE == "cpu" else [256, 1024, 4096, 16384]))
def test_loop(benchmark, batch, kernel_threads, mode):
    if mode == "compile" and DEVICE == "cpu":
        pytest.skip("train.compile compiles nothing on CPU, where the hot paths are the fused kernels")
    torch.set_num_threads(1)
    native.set_threads(kernel_threads)
    if DEVICE == "cpu":
        Path("/proc/self/clear_refs").write_text("5")  # the peak resident set starts here
    base = _rss_mb("VmRSS")
    env, learner = harness.default_run(batch, DEVICE)
    if mode == "compile":
        compile_hot_path(learner, env)
    sync = torch.cuda.synchronize if DEVICE != "cpu" else (lambda: None)
    iterations = harness.size(2, max(8, 40 * 32 // batch))
    for _ in range(harness.size(1, 5)):
        learner.iteration(env)
    with frozen_heap(), profiling.StageTimer(DEVICE) as stages:
        times = harness.interleaved({"iteration": lambda: (learner.iteration(env), sync())}, rounds=iterations,
                                    warmup=0)["iteration"]
    benchmark.pedantic(learner.iteration, args=(env,), rounds=harness.size(1, 5))
    peak = torch.cuda.max_memory_allocated() / 2**20 if DEVICE != "cpu" else _rss_mb("VmHWM") - base
    rates = matmul_rates(batch, DEVICE)
    row = {"variant": f"B={batch}, kernel threads {kernel_threads}, {harness.isa()}, {mode}, {DEVICE}",
           "B": batch, "kernel_threads": kernel_threads, "isa": harness.isa(), "mode": mode, "device": DEVICE,
           "env_iterations_per_s": batch / statistics.median(times),
           "ms_per_env_iteration": {k: 1e3 * stages.seconds.get(k, 0.0) / iterations / batch for k in STAGES},
           "flops_per_env_iteration": flops_per_env_iteration(learner, env, batch),
           "matmul_flops_per_s": max(rates.values()), "matmul_flops_per_s_by_library": rates, "peak_memory_mb": peak}
    assert sum(row["flops_per_env_iteration"].values()) > 0 and row["ms_per_env_iteration"]["encode"] > 0
    harness.record("loop", [row], benchmark, DEVICE)
