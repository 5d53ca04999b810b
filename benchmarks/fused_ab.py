"""Issue 33's fused kernels, each switched off in turn, in one process, interleaved.

``train.py``'s default environments and learner (``ExperimentConfig()``, B = 32, torch's operations
on one thread, the fused kernels on ``--kernel-threads``); every round times ``--iterations``
learner iterations of each variant in turn, so the machine's drift hits all alike; medians.

Variants: ``all fused`` (today); ``no fused dictionary step`` (reconstruction, error, pooled
activities, gradient and update by torch's operations: `SparseDictionary`'s fallback); ``no fused
patches`` (the patch cut by torch's operations); ``neither`` (what the loop was before issue 33,
with the same pursuit and renderer kernels).

Usage:
    python benchmarks/fused_ab.py [--rounds 6] [--iterations 8] [--json benchmarks/results/fused_ab.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--kernel-threads", type=int, default=2)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "fused_ab.json")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    import torch

    import aectorch.coding.dictionary as dictionary
    import aectorch.coding.pursuit as pursuit
    import aectorch.ops.backend as backend
    from aectorch.ops import native
    from aectorch.runtime import build_env, build_learner
    from aectorch.runtime.config import ExperimentConfig
    from benchmarks.machine import machine_info

    torch.set_num_threads(1)
    native.set_threads(args.kernel_threads)
    env, learner = build_env(ExperimentConfig()), build_learner(ExperimentConfig())
    fused = pursuit.fused_kernels_apply
    off = lambda tensor: False  # noqa: E731
    variants = {  # (the dictionary's switch, the patches' and the Gram matrix's: they read backend's and pursuit's)
        "all fused": (fused, fused),
        "no fused dictionary step": (off, fused),
        "no fused patches": (fused, off),
        "neither": (off, off),
    }
    for _ in range(3):
        learner.iteration(env)
    times: dict[str, list[float]] = {name: [] for name in variants}
    for round_ in range(args.rounds):
        for name, (dictionary_switch, patch_switch) in variants.items():
            dictionary.fused_kernels_apply, pursuit.fused_kernels_apply, backend.fused_kernels_apply = \
                dictionary_switch, patch_switch, patch_switch
            start = time.perf_counter()
            for _ in range(args.iterations):
                learner.iteration(env)
            times[name].append((time.perf_counter() - start) / args.iterations)
        print(f"round {round_ + 1} of {args.rounds}", file=sys.stderr, flush=True)
    dictionary.fused_kernels_apply = pursuit.fused_kernels_apply = backend.fused_kernels_apply = fused
    batch = env.num_envs
    base = statistics.median(times["neither"])
    rows = []
    print(f"| variant | ms / iteration (B = {batch}) | env-iterations/s | x neither |\n|---|---:|---:|---:|")
    for name, values in times.items():
        median = statistics.median(values)
        rows.append({"variant": name, "seconds": values, "median_s": median, "env_iterations_per_s": batch / median,
                     "speedup_over_neither": base / median})
        print(f"| {name} | {median * 1e3:.1f} | {batch / median:,.0f} | {base / median:.2f}x |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"benchmark": "fused_ab", "machine": machine_info(), "B": batch,
                                     "kernel_threads": args.kernel_threads, "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
