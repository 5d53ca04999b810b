"""Env-iterations per second of ``python train.py`` itself, today's code against an older commit, interleaved.

What a user sees: each configuration runs ``train.py`` in a fresh process twice, for ``short`` and
``long`` iterations (evaluation, figures, TensorBoard and the progress bar off); the rate is
``(long - short) * B / (wall(long) - wall(short))``, so start-up (imports, textures, the native
kernels, ``torch.compile``'s compilation) cancels. Every round runs every configuration once, in
turn, so the virtual machine's drift (25 % within minutes) hits all of them alike; the table
shows each configuration's median over the rounds and its ratio to the first configuration.

The older commit (``--baseline``, default b39d619: main before issue 21) is checked out into a
git worktree (``--worktree``, made once) and run with this checkout's Python; its ``train.py``
imports its own ``aectorch`` (the script's folder comes first on ``sys.path``).

A configuration is ``LABEL=WHERE[:override,override,...]`` with ``WHERE`` ``new`` (this checkout),
``old`` (the worktree) or a commit hash (a worktree of its own beside it); overrides are train.py's
``key=value`` (commas inside ``[...]`` belong to a list), or ``env:NAME=VALUE`` for an environment
variable of that configuration's processes (``AVX2`` below). ``@short/long`` after the label sets
its iteration counts (default ``--short``/``--long``).

``AVX2`` runs what a CPU without AVX-512 executes, on this machine's cores: the fused kernels built
for x86-64-v3, torch's kernels dispatched at AVX2, MKL and oneDNN limited to it, e.g.
``"defaults, AVX2=new:env:AECTORCH_NATIVE_MARCH=x86-64-v3,env:ATEN_CPU_CAPABILITY=avx2,env:MKL_ENABLE_INSTRUCTIONS=AVX2,env:ONEDNN_MAX_CPU_ISA=AVX2"``.

Usage:
    python benchmarks/train_rate.py                       # the issue-21 set (about 15 minutes on 2 cores)
    python benchmarks/train_rate.py --rounds 1 --configs "old=old" "new=new"
    python benchmarks/train_rate.py --json benchmarks/results/train_rate.json

Writes a table to stdout and JSON (``--json``) with every wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BASELINE = "b39d619"

#: The configurations of issue 21's table.
DEFAULT_CONFIGS = (
    "old defaults=old",
    "new defaults=new",
    "new, 1 thread=new:train.threads=1",
    "new, compiled=new:train.compile=true",
    # b39d619's defaults diverge at B = 1 (its watchdog stops the run): time it anyway
    "old B=1 pyrender@10/160=old:env.num_envs=1,env.renderer=pyrender,watchdog.mode=warn",
    "new B=1 pyrender@10/160=new:env.num_envs=1,env.renderer=pyrender,watchdog.mode=warn",
    "new B=256@5/45=new:env.num_envs=256",
)
QUIET = ["eval.enabled=false", "train.figures=false", "train.progress=false", "train.tensorboard=false",
         "train.checkpoint_every=100000"]


def parse(text: str, short: int, long: int) -> dict:
    import re

    match = re.fullmatch(r"(.+?)(?:@(\d+)/(\d+))?=(new|old|[0-9a-f]{7,40})(?::(.*))?", text)
    if match is None:
        raise SystemExit(f"configuration {text!r}: expected LABEL[@SHORT/LONG]=new|old|COMMIT[:key=value,...]")
    label, short_text, long_text, where, overrides = match.groups()
    overrides = overrides or ""
    if short_text:
        short, long = int(short_text), int(long_text)
    # Commas inside [...] belong to a list value (learner.cues.stereo.scales=[wide,coarse,fine]).
    items = [o for o in re.split(r",(?![^\[]*\])", overrides) if o]
    env = dict(o[len("env:"):].split("=", 1) for o in items if o.startswith("env:"))
    return {"label": label, "where": where, "overrides": [o for o in items if not o.startswith("env:")],
            "env": env, "short": short, "long": long}


def batch_size(config: dict) -> int:
    for override in config["overrides"]:
        if override.startswith("env.num_envs="):
            return int(override.split("=", 1)[1])
    return 32  # EnvConfig.num_envs (both commits)


def worktree(commit: str, folder: Path) -> Path:
    if not (folder / "train.py").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(folder), commit], check=True,
                       stdout=subprocess.DEVNULL)
    return folder


def run(config: dict, iterations: int, cwd: Path, scratch: Path) -> float:
    import re

    out = scratch / f"{re.sub(r'[^A-Za-z0-9]+', '_', config['label'])}_{iterations}"
    command = [sys.executable, "train.py", f"hydra.run.dir={out}", f"train.iterations={iterations}",
               *QUIET, *config["overrides"]]
    # Each commit's train.py chooses how idle OpenMP threads wait (b39d619: libgomp's default;
    # today: see train.py), as for a user.
    env = dict(os.environ, PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"), **config.get("env", {}))
    start = time.perf_counter()
    result = subprocess.run(command, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    if result.returncode:
        raise SystemExit(f"{config['label']}: train.py failed ({result.returncode}):\n{result.stderr[-2000:]}")
    return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS))
    parser.add_argument("--baseline", default=DEFAULT_BASELINE, help="the older commit ('old')")
    parser.add_argument("--worktree", type=Path, default=Path(tempfile.gettempdir()) / "aectorch-baseline")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--short", type=int, default=20)
    parser.add_argument("--long", type=int, default=220)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "train_rate.json")
    args = parser.parse_args()
    configs = [parse(text, args.short, args.long) for text in args.configs]
    folders = {"new": ROOT}
    for config in configs:  # a git worktree per older commit ('old' is --baseline)
        where = config["where"]
        if where not in folders:
            commit = args.baseline if where == "old" else where
            folders[where] = worktree(commit, args.worktree if where == "old" else args.worktree.with_name(
                f"aectorch-{commit}"))
    rows = {c["label"]: {**c, "B": batch_size(c), "walls": [], "rates": []} for c in configs}
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        for config in configs:  # once untimed: builds the native kernels and warms the caches
            run(config, 1, folders[config["where"]], scratch)
        for round_ in range(args.rounds):
            for config in configs:
                cwd = folders[config["where"]]
                short = run(config, config["short"], cwd, scratch)
                long = run(config, config["long"], cwd, scratch)
                row = rows[config["label"]]
                rate = (config["long"] - config["short"]) * row["B"] / (long - short)
                row["walls"].append([short, long])
                row["rates"].append(rate)
                print(f"round {round_ + 1}: {config['label']}: {rate:,.1f} env-iterations/s", file=sys.stderr, flush=True)
    first = statistics.median(rows[configs[0]["label"]]["rates"])
    print(f"\n{args.rounds} round(s); rate = (long - short) x B / (wall(long) - wall(short)), medians; "
          f"'old' = {args.baseline}\n")
    print("| configuration | B | env-iterations/s | x first |\n|---|---:|---:|---:|")
    for row in rows.values():
        row["env_iterations_per_s"] = statistics.median(row["rates"])
        row["ratio_to_first"] = row["env_iterations_per_s"] / first
        print(f"| {row['label']} | {row['B']} | {row['env_iterations_per_s']:,.1f} | {row['ratio_to_first']:.2f}x |")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    report = {"benchmark": "train_rate", "baseline": args.baseline, "rounds": args.rounds,
              "machine": machine_info(), "rows": list(rows.values())}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
