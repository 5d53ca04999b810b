"""The dictionary step (sparse gradient and update) on one kernel thread against two, in the training loop.

``train.py``'s default learner and environments (B = 32, as `benchmarks/loop_ops.py` builds them,
the kernels on two threads): ``--rounds`` rounds of ``--iterations`` iterations with the dictionary
step as the kernels run it, then with it forced onto one thread (``aectorch.ops.native.set_threads(1)``
around `BinocularEncoder.learn_`), the order alternating; wall and CPU time, medians and the quartiles
of the paired ratios. The kernels give the same bits on any number of threads, so one learner
switches mid-run.

Since the commit that added this script the sparse-gradient kernel itself runs on one thread below
2^20 signal values (B = 32's scales), so both variants are the same there; the numbers in
docs/performance.md were measured with the kernels of commit f40706f, which split every call over
the kernels' threads: ``git checkout f40706f -- aectorch && python benchmarks/gradient_threads_ab.py``
(then ``git checkout HEAD -- aectorch``).

Usage:
    python benchmarks/gradient_threads_ab.py [--rounds 30] [--iterations 20] [--json benchmarks/results/gradient_threads_ab.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
# (loop_ops sets OMP_WAIT_POLICY and PYOPENGL_PLATFORM as train.py does, before torch starts)
from loop_ops import build  # noqa: E402

import torch  # noqa: E402

from aectorch.ops import native  # noqa: E402
from aectorch.coding.encoder import BinocularEncoder  # noqa: E402

AS_RUN = BinocularEncoder.learn_


def one_thread(self, *args, **kwargs):
    threads = native.get_threads()
    native.set_threads(1)
    try:
        return AS_RUN(self, *args, **kwargs)
    finally:
        native.set_threads(threads)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=30, help="at least 2")
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "gradient_threads_ab.json")
    args = parser.parse_args()
    if args.rounds < 2:
        parser.error(f"--rounds must be at least 2 (quartiles of the paired ratios), got {args.rounds}")
    from benchmarks.machine import machine_info

    torch.use_deterministic_algorithms(True, warn_only=True)  # as train.deterministic
    env, learner = build(32)
    native.set_threads(2)
    for _ in range(30):
        learner.iteration(env)
    variants = {"as the kernels run it": AS_RUN, "one thread": one_thread}
    wall: dict[str, list[float]] = {name: [] for name in variants}
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    try:
        for r in range(args.rounds):
            for name in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
                BinocularEncoder.learn_ = variants[name]
                start, start_cpu = time.perf_counter(), time.process_time()
                for _ in range(args.iterations):
                    learner.iteration(env)
                wall[name].append(1000 * (time.perf_counter() - start) / args.iterations)
                cpu[name].append(1000 * (time.process_time() - start_cpu) / args.iterations)
            print(f"round {r + 1} of {args.rounds}", file=sys.stderr, flush=True)
    finally:
        BinocularEncoder.learn_ = AS_RUN
    report = {"benchmark": "gradient_threads_ab", "machine": machine_info()}
    for label, times in (("wall", wall), ("cpu", cpu)):
        ratios = [b / a for a, b in zip(*times.values())]
        report[label] = {"median_ms": {k: statistics.median(v) for k, v in times.items()},
                         "ratio one thread / as run": {"median": statistics.median(ratios),
                                                       "quartiles": statistics.quantiles(ratios, n=4)},
                         "ms": times}
        q = report[label]["ratio one thread / as run"]
        print(f"{label} ms per iteration: " + ", ".join(f"{k} {v:.2f}" for k, v in report[label]["median_ms"].items())
              + f"; one thread / as run: median {q['median']:.3f}, quartiles {q['quartiles'][0]:.3f}-{q['quartiles'][2]:.3f}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
