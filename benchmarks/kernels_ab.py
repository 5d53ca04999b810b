"""Two commits' patch cutting, encoding and scale blurring side by side: ``aectorch::pair_patches``,
``aectorch::encode`` and `aectorch.sim.env.pyramid_blur`, each commit's own code, interleaved rounds.

Each round runs, for every commit in turn (the order alternates), a fresh process with that
commit's checkout first on ``sys.path`` (a git worktree beside this one, made once, as
`benchmarks/train_rate.py` makes them; its kernels are built for its own sources), which times on
``--threads`` kernel threads, medians of ``--calls`` calls, at B = 32:

* ``pair_patches``: the coarse scale's 7 x 7 patches of 10 x 10 pixels from 16 x 16 image pairs and
  the fine scale's 8 x 8 (stride 4) from 40 x 40 pairs, the default coder's geometry;
* ``encode``: ``aectorch::encode`` of the fine scale's 2048 patches (B = 32) with 288 atoms, MP,
  k = 10 (the Gram matrix, the pursuit, reconstructions, errors, pooling);
* ``pyramid_blur``: what the environment blurs per stereo frame, ``[32, 2, 42, 42]`` (the fine and
  full scales, 2 levels) and ``[32, 2, 18, 18]`` (coarse, 3 levels): the torch code before
  ``aectorch::pyramid_blur``, the kernel after (the same bits: ``tests/test_sim.py``).

The table gives each commit's median over the rounds and the median of the paired per-round
ratios (second / first).

Usage:
    python benchmarks/kernels_ab.py --commits e28d2c9 HEAD [--rounds 9] [--json benchmarks/results/kernels_ab.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Run in the child: times the calls with the checkout at argv[1]; prints one JSON line.
CHILD = r"""
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
import torch
from aectorch.ops import native
from aectorch.sim.env import pyramid_blur
torch.set_num_threads(1)
assert native.load(), "the fused kernels did not build"
native.set_threads(int(sys.argv[2]))
calls = int(sys.argv[3])
g = torch.Generator().manual_seed(0)


def timed(f):
    for _ in range(20):
        f()
    times = []
    for _ in range(calls):
        start = time.perf_counter(); f(); times.append(time.perf_counter() - start)
    return 1e6 * statistics.median(times)


out = {}
for name, (images, offset, p, stride, grid) in {
        "pair_patches coarse (32 x 49 patches)": (torch.rand(64, 16, 16, generator=g), 0, 10, 1, 7),
        "pair_patches fine (32 x 64 patches)": (torch.rand(64, 40, 40, generator=g), 0, 10, 4, 8)}.items():
    out[name] = timed(lambda: torch.ops.aectorch.pair_patches(images, offset, p, stride, grid, 1e-6, 1e-5))
for name, (shape, levels) in {"pyramid_blur [32, 2, 42, 42]": ((32, 2, 42, 42), 2),
                              "pyramid_blur [32, 2, 18, 18]": ((32, 2, 18, 18), 3)}.items():
    images = torch.rand(*shape, generator=g)
    out[name] = timed(lambda: pyramid_blur(images, levels))
atoms = torch.randn(200, 288, generator=g)
atoms = atoms / atoms.norm(dim=0)
signals = torch.randn(2048, 200, generator=g)
out["encode fine (2048 x 288 atoms, MP k = 10)"] = timed(
    lambda: torch.ops.aectorch.encode(signals, atoms, None, 10, False, 512, 32))
print(json.dumps(out))
"""


def short(commit: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", commit], check=True,
                          capture_output=True, text=True).stdout.strip()


def checkout(full: str) -> Path:
    """This checkout for HEAD (with its uncommitted changes), else a git worktree of commit ``full``
    beside the baseline's (made once)."""
    if full == short("HEAD"):
        return ROOT
    folder = Path(tempfile.gettempdir()) / f"aectorch-{full}"
    if not (folder / "train.py").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(folder), full], check=True,
                       stdout=subprocess.DEVNULL)
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--commits", nargs=2, default=["e28d2c9", "HEAD"], metavar=("FIRST", "SECOND"))
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "kernels_ab.json")
    args = parser.parse_args()
    if args.rounds < 1 or args.calls < 1 or any(t < 1 for t in args.threads):
        parser.error("--rounds, --calls and --threads must be >= 1")
    args.commits = [short(commit) for commit in args.commits]
    if args.commits[0] == args.commits[1]:
        parser.error(f"--commits names one commit twice ({args.commits[0]})")
    folders = {commit: checkout(commit) for commit in args.commits}
    env = dict(os.environ, OMP_WAIT_POLICY=os.environ.get("OMP_WAIT_POLICY", "PASSIVE"))
    times: dict[int, dict[str, list[dict]]] = {t: {c: [] for c in args.commits} for t in args.threads}
    for round_ in range(args.rounds):
        for threads in args.threads:
            order = args.commits if round_ % 2 == 0 else args.commits[::-1]
            for commit in order:
                done = subprocess.run([sys.executable, "-c", CHILD, str(folders[commit]), str(threads), str(args.calls)],
                                      check=True, capture_output=True, text=True, env=env, cwd=folders[commit])
                times[threads][commit].append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(f"round {round_ + 1} of {args.rounds}", file=sys.stderr)
    first, second = args.commits
    rows = []
    for threads in args.threads:
        for name in times[threads][first][0]:
            a = [r[name] for r in times[threads][first]]
            b = [r[name] for r in times[threads][second]]
            rows.append({"call": name, "threads": threads, f"{first} us": statistics.median(a),
                         f"{second} us": statistics.median(b),
                         "ratio": statistics.median(y / x for x, y in zip(a, b)), "rounds": {first: a, second: b}})
    print(f"\n| call | kernel threads | {first} (us) | {second} (us) | ratio {second} / {first} |")
    print("|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['call']} | {r['threads']} | {r[f'{first} us']:.1f} | {r[f'{second} us']:.1f} | {r['ratio']:.3f} |")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"benchmark": "kernels_ab", "commits": args.commits, "rounds": args.rounds,
                                     "calls": args.calls, "machine": machine_info(), "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
