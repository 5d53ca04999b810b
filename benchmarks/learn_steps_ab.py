"""The dictionaries of a coder learning together (``aectorch::learn_steps_``) against one by one, interleaved.

`BinocularEncoder.learn_` hands its scales' dictionaries to `learn_together_`: one kernel call that
spreads them over the kernels' threads, each dictionary's sparse gradient (its scatter-add with the
next rows prefetched), scaling and step on one thread. Before, each dictionary ran
``aectorch::sparse_gradient`` (one thread at B = 32), torch's scaling and ``aectorch::dictionary_step_``
in turn. Both give the same bits (``tests/test_native.py``), so one learner can switch mid-run.

1. One coder's four default scales (288 atoms, MP, k = 10) at B = 32: ``--repeats`` interleaved
   timings of each, medians.
2. ``train.py``'s default learner and environments (B = 32): ``--rounds`` rounds of ``--iterations``
   iterations with one and then the other (the order alternates), wall and CPU time.

Usage:
    python benchmarks/learn_steps_ab.py [--rounds 30] [--iterations 20] [--json benchmarks/results/learn_steps_ab.json]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as train.py
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import torch  # noqa: E402

from aectorch.coding import BinocularEncoder  # noqa: E402
from aectorch.coding.patches import as_scale  # noqa: E402
from encode_ab import loop, summary, write  # noqa: E402

TOGETHER = BinocularEncoder.learn_


@torch.no_grad()
def one_by_one(self, output, lr=None, *, reduce=None):
    """What `BinocularEncoder.learn_` did before: `SparseDictionary.learn_` of each scale in turn."""
    lr = self.rate() if lr is None else lr
    for scale, x, out in zip(self.scales, output.patches, output.codes):
        self.dictionaries[scale.name].learn_(x, out, lr, reduce=reduce)
    self.steps += 1
    return self


VARIANTS = {"together (aectorch::learn_steps_)": TOGETHER, "one by one": one_by_one}


def one_coder(repeats: int) -> dict:
    names = ("wide", "coarse", "fine", "full")
    g = torch.Generator().manual_seed(0)
    enc = BinocularEncoder(scales=names, num_atoms=288, algorithm="mp", symmetry="mirror", generator=g)
    obs = {n: torch.rand(32, 2, as_scale(n).side, as_scale(n).side, generator=g) for n in names}
    with torch.no_grad():
        out = enc(obs)
    times: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for _ in range(repeats):
        for name, fn in VARIANTS.items():
            start = time.perf_counter()
            for _ in range(20):
                fn(enc, out, 1e-3)
            times[name].append(1000 * (time.perf_counter() - start) / 20)
    return summary(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "learn_steps_ab.json")
    args = parser.parse_args()
    if min(args.repeats, args.rounds) < 2:
        parser.error(f"--repeats and --rounds must be at least 2 (quartiles of the paired ratios), got "
                     f"{args.repeats} and {args.rounds}")
    from aectorch.runtime.builders import set_threads
    from benchmarks.machine import machine_info

    set_threads(0, 1)  # as train.threads's default: the kernels on every core, torch on one thread
    report = {"benchmark": "learn_steps_ab", "one_coder_four_scales_B32": one_coder(args.repeats),
              "training_loop_B32": loop(args.rounds, args.iterations, BinocularEncoder, "learn_", VARIANTS),
              "machine": machine_info()}
    write(report, "one coder's four scales, ms per learn_", report["one_coder_four_scales_B32"], args.json)


if __name__ == "__main__":
    main()
