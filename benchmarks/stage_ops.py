"""What a stage of the default training iteration is made of: torch's operators inside each stage,
and the pursuit kernel beside the matrix products it calls.

1. torch's profiler over ``--iterations`` learner iterations (after ``--warmup``; B = ``--num-envs``,
   ``train.py``'s default environments and learner, torch on one thread and the fused kernels on
   ``--kernel-threads``, the heap frozen as in training), each stage of
   :mod:`aectorch.profiling` marked as a ``record_function`` range: per stage (``--stages``), its
   time per iteration under the profiler, the self CPU time of the operators inside it (the rest
   is Python: the learner's and TorchRL's own code, and the profiler's), how many operator calls
   that is, and the ``--top`` operators. Operators that the fused kernels call from their worker
   threads (the encoder's products) have no parent range there: only the calling thread's count.
2. The encoder's pursuit split in two, on one thread: ``aectorch::pursuit`` (OMP, k = 10, the
   default scale's P = 200, N = 288, on M = ``--rows`` random signals and a random unit-norm
   dictionary, in tiles of 512 rows) against its correlations alone (the same products, tile by
   tile, in oneDNN as the kernel calls them, or torch's where oneDNN is missing); the difference is the selection steps (each reads up
   to k rows of the Gram matrix), which the stage table's matmul floor does not count. Medians of
   ``--repeats``.

Usage:
    PYOPENGL_PLATFORM=osmesa OMP_WAIT_POLICY=PASSIVE python benchmarks/stage_ops.py
    python benchmarks/stage_ops.py --stages rl dictionary --json benchmarks/results/stage_ops.json
"""

from __future__ import annotations

import argparse
import collections
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile, record_function  # noqa: E402

from machine import machine_info  # noqa: E402


def stage_profile(num_envs: int, kernel_threads: int, warmup: int, iterations: int, stages: list[str],
                  top: int) -> dict:
    from aectorch import profiling
    from aectorch.ops import native
    from aectorch.runtime.loop import frozen_heap
    from loop_ops import build  # train.py's default environments and learner at B = num_envs

    env, learner = build(num_envs)
    torch.set_num_threads(1)
    native.set_threads(kernel_threads)
    for _ in range(warmup):
        learner.iteration(env)

    class Ranges(profiling.StageTimer):  # each stage also a profiler range
        def __init__(self):
            super().__init__()
            self._ranges = []

        def _push(self, name):
            rf = record_function("stage:" + name)
            rf.__enter__()
            self._ranges.append(rf)
            super()._push(name)

        def _pop(self, name):
            super()._pop(name)
            self._ranges.pop().__exit__(None, None, None)

    with frozen_heap(), profile(activities=[ProfilerActivity.CPU]) as prof, Ranges() as timer:
        for _ in range(iterations):
            learner.iteration(env)

    def stage_of(event) -> str | None:
        parent = event.cpu_parent
        while parent is not None:
            if parent.name.startswith("stage:"):
                return parent.name[len("stage:"):]
            parent = parent.cpu_parent
        return None

    self_us: dict[str, collections.Counter] = {s: collections.Counter() for s in stages}
    calls: dict[str, collections.Counter] = {s: collections.Counter() for s in stages}
    for event in prof.events():
        if event.name.startswith("stage:"):
            continue
        where = stage_of(event)
        if where in self_us:
            self_us[where][event.name] += event.self_cpu_time_total
            calls[where][event.name] += 1
    out = {}
    for s in stages:
        total = sum(self_us[s].values())
        out[s] = {"ms_per_iteration_profiled": 1e3 * timer.seconds.get(s, 0.0) / iterations,
                  "operator_self_cpu_ms_per_iteration": total / 1e3 / iterations,
                  "operator_calls_per_iteration": sum(calls[s].values()) / iterations,
                  "top": [{"op": op, "self_cpu_ms_per_iteration": us / 1e3 / iterations,
                           "calls_per_iteration": calls[s][op] / iterations}
                          for op, us in self_us[s].most_common(top)]}
    return out


def pursuit_split(rows: int, repeats: int) -> dict:
    from aectorch.ops import native

    if not native.load():
        return {"skipped": "the fused kernels are not available"}
    torch.set_num_threads(1)
    native.set_threads(1)
    g = torch.Generator().manual_seed(0)
    p, n, k = 200, 288, 10
    d = torch.randn(p, n, generator=g)
    d = d / d.norm(dim=0)
    gram = d.T @ d
    x = torch.randn(rows, p, generator=g)
    d_t = d.T.contiguous()
    onednn = hasattr(torch.ops.mkldnn, "_linear_pointwise")
    block = 512  # the kernel's tiles: one product per tile of at most `block` rows

    def products():
        for start in range(0, rows, block):
            tile = x[start:start + block]
            if onednn:
                torch.ops.mkldnn._linear_pointwise(tile, d_t, None, "none", [], "")
            else:
                torch.mm(tile, d)

    def pursuit():
        return torch.ops.aectorch.pursuit(x, d, gram, k, True, block)

    def median_ms(fn) -> float:
        for _ in range(3):
            fn()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            for _ in range(10):
                fn()
            times.append((time.perf_counter() - start) / 10)
        return 1e3 * statistics.median(times)

    whole, corr = [], []
    for _ in range(3):  # interleaved
        whole.append(median_ms(pursuit))
        corr.append(median_ms(products))
    w, c = statistics.median(whole), statistics.median(corr)
    return {"rows": rows, "P": p, "N": n, "k": k, "library": "onednn" if onednn else "torch",
            "pursuit_ms": w, "correlations_ms": c, "selection_ms": w - c, "selection_over_correlations": (w - c) / c,
            "us_per_row_selection": 1e3 * (w - c) / rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--kernel-threads", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=30)
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--stages", nargs="+", default=["rl", "dictionary", "encode", "render"])
    parser.add_argument("--top", type=int, default=8)
    parser.add_argument("--rows", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "stage_ops.json")
    args = parser.parse_args()
    if args.num_envs < 1 or args.iterations < 1 or args.rows < 1 or args.repeats < 1:
        parser.error("--num-envs, --iterations, --rows and --repeats must be >= 1")

    stages = stage_profile(args.num_envs, args.kernel_threads, args.warmup, args.iterations, args.stages, args.top)
    for name, s in stages.items():
        print(f"\nstage {name}: {s['ms_per_iteration_profiled']:.3f} ms per iteration under the profiler; "
              f"operators' self CPU {s['operator_self_cpu_ms_per_iteration']:.3f} ms in "
              f"{s['operator_calls_per_iteration']:.0f} calls\n")
        print("| operator | ms / iteration | calls / iteration |\n|---|---:|---:|")
        for row in s["top"]:
            print(f"| `{row['op']}` | {row['self_cpu_ms_per_iteration']:.3f} | {row['calls_per_iteration']:.1f} |")
    split = pursuit_split(args.rows, args.repeats)
    if "skipped" in split:
        print(f"\npursuit split: skipped ({split['skipped']})")
    else:
        print(f"\npursuit of {split['rows']} x {split['P']} signals, N = {split['N']}, k = {split['k']}, one thread: "
              f"{split['pursuit_ms']:.3f} ms; its correlations alone ({split['library']}) {split['correlations_ms']:.3f} ms; "
              f"the selection steps {split['selection_ms']:.3f} ms ({split['selection_over_correlations']:.2f}x the "
              f"correlations, {split['us_per_row_selection']:.2f} us per signal)")
    result = {"benchmark": "stage_ops", "num_envs": args.num_envs, "kernel_threads": args.kernel_threads,
              "iterations": args.iterations, "machine": machine_info(), "stages": stages, "pursuit_split": split}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
