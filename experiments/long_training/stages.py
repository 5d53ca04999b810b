"""Train one run in stages and evaluate its state at the end of each: the learning curve on photographs.

    .venv/bin/python experiments/long_training/stages.py runs/long_s0 --seed 0 --stages 2400,4800,9600,24000 \
        --eval choose=data/choose-photos [key=value ...]

The run is trained with ``train.py`` to the first stage, then continued in place
(``train.resume``) to each later one, exactly as one run of the last stage's length (resuming is bit
for bit). At each stage the state is kept as ``ckpt_<iteration>.pt`` and evaluated, greedy and frozen,
with ``python -m aectorch.evaluate`` on every ``--eval NAME=FOLDER`` (``NAME=test`` for the 40 test
textures), written to ``<NAME>_<iteration>.json`` in the run folder. A stage whose files exist is
skipped, so the same command continues an interrupted study. ``key=value`` overrides are the
run's settings (``train.py``'s), given to the first stage only (a resume keeps the stored config).
The training uses one kernel thread (``train.threads=1``), so two studies share two cores.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(command: list[str], log: Path) -> None:
    with log.open("a") as out:
        out.write("$ " + " ".join(command) + "\n")
        out.flush()
        # one thread for torch's own operations, as the training's train.threads=1
        env = {"PYOPENGL_PLATFORM": "osmesa", "OMP_NUM_THREADS": "1", **os.environ}
        code = subprocess.call(command, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, env=env)
    if code:
        sys.exit(f"error: {command[1]} ended with status {code}; see {log}")


def _numbers(kind):
    def parse(text: str) -> list:
        return [kind(item) for item in text.split(",")]
    parse.__name__ = f"comma-separated {kind.__name__}s"
    return parse


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="run folder")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--stages", type=_numbers(int), required=True, help="iterations, increasing: 2400,4800")
    parser.add_argument("--eval", action="append", default=[], metavar="NAME=FOLDER",
                        help="an evaluation set: NAME=test (the 40 test textures) or NAME=<folder of photographs>")
    parser.add_argument("--depths", type=_numbers(float), help="the evaluations' distances, metres (default: the "
                        "evaluation's own, 1.0 to 3.0 m in 0.1 m steps for photographs, 5 distances for test): 1.0,2.0")
    parser.add_argument("overrides", nargs="*", help="train.py key=value settings of the run")
    args = parser.parse_intermixed_args(argv)
    if any(b <= a for a, b in zip(args.stages, args.stages[1:])) or args.stages[0] < 1:
        parser.error(f"--stages must be positive and increasing, got {args.stages}")
    for item in args.eval:
        name, _, folder = item.partition("=")
        if not name or not folder or "_" in name:
            parser.error(f"--eval takes NAME=FOLDER (NAME without '_'), got {item!r}")
        if folder != "test" and not (ROOT / folder).is_dir() and not Path(folder).is_dir():
            parser.error(f"--eval {item}: no such folder {folder!r}")
    for item in args.overrides:
        if "=" not in item:
            parser.error(f"overrides are key=value, got {item!r}")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse(argv)
    run = args.run.resolve()
    run.parent.mkdir(parents=True, exist_ok=True)
    log = run.parent / f"{run.name}.log"
    py = sys.executable
    for stage in args.stages:
        kept = run / f"ckpt_{stage}.pt"
        if not kept.exists():
            common = [f"train.iterations={stage}", "train.threads=1", "train.progress=false"]
            if (run / "checkpoint.pt").exists():
                _run([py, "train.py", f"train.resume={run}", *common], log)
            else:
                _run([py, "train.py", f"seed={args.seed}", "eval.enabled=false", "train.figures=false", *common,
                      *args.overrides, f"hydra.run.dir={run}"], log)
            tmp = kept.with_suffix(".tmp")
            tmp.write_bytes((run / "checkpoint.pt").read_bytes())
            tmp.replace(kept)
        for item in args.eval:
            name, _, folder = item.partition("=")
            out = run / f"{name}_{stage}.json"
            if out.exists():
                continue
            depths = args.depths or ([1.0, 1.5, 2.0, 2.5, 3.0] if folder == "test" else None)
            where = ([] if folder == "test" else [f"textures={folder}"]) + \
                ([f"depths=[{','.join(map(str, depths))}]"] if depths else [])
            _run([py, "-m", "aectorch.evaluate", f"checkpoint={kept}", *where, "progress=false", f"out={out}"], log)
        print(f"{run.name}: stage {stage} done", flush=True)


if __name__ == "__main__":
    main()
