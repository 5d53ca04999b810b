"""Encoding in one pass (``aectorch::encode``) against the four kernels it replaced, interleaved.

`SparseDictionary.forward_pooled` runs the Gram matrix, the pursuit, the reconstructions with their
eq. (4) errors and the pooled activities as one fused kernel (one OpenMP region, the atoms
transposed inside it); before, they were four operators (``aectorch::gram``, ``aectorch::pursuit``,
``aectorch::reconstruct_error`` after a torch copy of the transposed atoms,
``aectorch::pooled_power``). Both give the same bits (``tests/test_native.py``), so one learner can
switch between them mid-run.

1. One dictionary (288 atoms, 200-dimensional patches, k = 10 MP), the 32 x 49 patches of one
   scale at B = 32: ``--repeats`` interleaved timings of each, medians.
2. ``train.py``'s default learner and environments (B = 32, as `benchmarks/loop_ops.py` builds
   them): ``--rounds`` rounds of ``--iterations`` iterations with one and then the other (the order
   alternates), wall and CPU time; medians and the quartiles of the paired ratios.

Usage:
    python benchmarks/encode_ab.py [--rounds 30] [--iterations 20] [--json benchmarks/results/encode_ab.json]
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

from aectorch.coding.dictionary import SparseDictionary  # noqa: E402

ONE_PASS = SparseDictionary.forward_pooled


def four_kernels(self, signals, *, check=True, reduction="sum"):
    """What `forward_pooled` did before: `forward` (gram, pursuit, reconstruct_error), then pooled_power."""
    out = self(signals, check=check)
    return out, self.pooled_activity(out.code, reduction=reduction)


VARIANTS = {"one pass (aectorch::encode)": ONE_PASS, "four kernels": four_kernels}


def summary(values: dict[str, list[float]]) -> dict:
    (a, first), (b, second) = values.items()
    ratios = [x / y for x, y in zip(first, second)]
    return {"median_ms": {k: statistics.median(v) for k, v in values.items()},
            f"ratio {a} / {b}": {"median": statistics.median(ratios), "quartiles": statistics.quantiles(ratios, n=4)},
            "ms": values}


def one_dictionary(repeats: int) -> dict:
    g = torch.Generator().manual_seed(0)
    d = SparseDictionary(288, 200, 10, "mp", generator=g)
    x = torch.randn(32, 49, 200, generator=g)
    times: dict[str, list[float]] = {name: [] for name in VARIANTS}
    with torch.no_grad():
        for _ in range(repeats):
            for name, fn in VARIANTS.items():
                start = time.perf_counter()
                for _ in range(20):
                    fn(d, x, check=False, reduction="mean")
                times[name].append(1000 * (time.perf_counter() - start) / 20)
    return summary(times)


def loop(rounds: int, iterations: int, owner: type = SparseDictionary, attribute: str = "forward_pooled",
         variants: dict | None = None) -> dict:
    """Interleaved rounds of the default learner's iterations with ``owner.attribute`` set to each
    of ``variants`` (default: `VARIANTS` of ``SparseDictionary.forward_pooled``) in turn."""
    variants = VARIANTS if variants is None else variants
    original = getattr(owner, attribute)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from loop_ops import build

    torch.use_deterministic_algorithms(True, warn_only=True)  # as train.deterministic
    env, learner = build(32)
    for _ in range(30):
        learner.iteration(env)
    wall: dict[str, list[float]] = {name: [] for name in variants}
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    try:
        for r in range(rounds):
            for name in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
                setattr(owner, attribute, variants[name])
                start, start_cpu = time.perf_counter(), time.process_time()
                for _ in range(iterations):
                    learner.iteration(env)
                wall[name].append(1000 * (time.perf_counter() - start) / iterations)
                cpu[name].append(1000 * (time.process_time() - start_cpu) / iterations)
            print(f"round {r + 1} of {rounds}", file=sys.stderr, flush=True)
    finally:
        setattr(owner, attribute, original)
    return {"wall": summary(wall), "cpu (both threads)": summary(cpu)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "encode_ab.json")
    args = parser.parse_args()
    if min(args.repeats, args.rounds) < 2:
        parser.error(f"--repeats and --rounds must be at least 2 (quartiles of the paired ratios), got "
                     f"{args.repeats} and {args.rounds}")
    from aectorch.runtime.builders import set_threads
    from benchmarks.machine import machine_info

    set_threads(0, 1)  # as train.threads's default: the kernels on every core, torch on one thread
    report = {"benchmark": "encode_ab", "one_dictionary_32x49_patches": one_dictionary(args.repeats),
              "training_loop_B32": loop(args.rounds, args.iterations), "machine": machine_info()}
    write(report, "one dictionary, 32 x 49 patches, ms per call", report["one_dictionary_32x49_patches"], args.json)


def write(report: dict, label: str, part: dict, path: Path) -> None:
    """Print the medians and paired ratios of ``part`` and the training loop's, then write ``report``."""
    for label, part in ((label, part), ("training loop, ms per iteration (wall)", report["training_loop_B32"]["wall"]),
                        ("training loop, CPU ms per iteration", report["training_loop_B32"]["cpu (both threads)"])):
        medians = ", ".join(f"{k} {v:.3f}" for k, v in part["median_ms"].items())
        (key, ratio), = [(k, v) for k, v in part.items() if k.startswith("ratio")]
        print(f"{label}: {medians}; {key}: median {ratio['median']:.3f}, quartiles "
              f"{ratio['quartiles'][0]:.3f}-{ratio['quartiles'][2]:.3f}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
