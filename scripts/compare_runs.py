"""Print (and plot) the training metrics of runs side by side, iteration by iteration.

    .venv/bin/python scripts/compare_runs.py runs/roll200 runs/win200_s0 --names rolled control \
        --from 700 --to 1500 --every 50 [--keys pursuit_mae_deg vergence_mae_deg] [--plot out.png]

Reads each run's ``metrics.jsonl``; a run that has no line at an iteration shows ``-``. With
``--plot`` every key gets a panel with one curve per run, and the perturbation events of a run
(``summary.json``) are drawn as dotted lines. Used for paired comparisons such as a perturbed run
against the unperturbed run of the same seed (``docs/results.md``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

DEFAULT_KEYS = ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m")


def read_metrics(run: Path) -> dict[int, dict]:
    path = run / "metrics.jsonl"
    if not path.is_file():
        raise ValueError(f"run {str(run)!r} has no metrics.jsonl")
    return {line["iteration"]: line for line in map(json.loads, path.read_text().splitlines())}


def table(runs: dict[str, dict[int, dict]], keys, first: int, last: int, every: int) -> str:
    names = list(runs)
    header = ["iteration"] + [f"{key} {name}" for key in keys for name in names]
    rows = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    iterations = sorted({i for lines in runs.values() for i in lines if first <= i <= last and i % every == 0})
    for i in iterations:
        cells = [str(i)]
        for key in keys:
            for name in names:
                value = runs[name].get(i, {}).get(key)
                cells.append("-" if value is None else f"{value:.3f}")
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def plot(runs: dict[str, dict[int, dict]], folders: dict[str, Path], keys, first: int, last: int,
         out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(keys), 1, figsize=(8, 2.6 * len(keys)), sharex=True, squeeze=False)
    for ax, key in zip(axes[:, 0], keys):
        for name, lines in runs.items():
            points = [(i, line[key]) for i, line in sorted(lines.items())
                      if first <= i <= last and line.get(key) is not None]
            if points:
                ax.plot(*zip(*points), label=name)
        ax.set_ylabel(key)
        ax.grid(alpha=0.3)
    for name, folder in folders.items():
        summary = folder / "summary.json"
        if summary.is_file():
            events = (json.loads(summary.read_text()).get("perturbation") or {}).get("events", [])
            for event in events:
                for ax in axes[:, 0]:
                    ax.axvline(event["iteration"], color="grey", linestyle=":")
                axes[0, 0].annotate(f"{name}: {event['label']}", (event["iteration"], 1.0),
                                    xycoords=("data", "axes fraction"), rotation=90, va="top",
                                    ha="right", fontsize=7, color="grey")
    axes[0, 0].legend()
    axes[-1, 0].set_xlabel("learner iteration")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders")
    parser.add_argument("--names", nargs="+", default=None, help="a label per run (default: folder names)")
    parser.add_argument("--keys", nargs="+", default=list(DEFAULT_KEYS), help="metrics.jsonl keys")
    parser.add_argument("--from", dest="first", type=int, default=0, help="first iteration")
    parser.add_argument("--to", dest="last", type=int, default=None, help="last iteration")
    parser.add_argument("--every", type=int, default=100, help="print iterations divisible by this")
    parser.add_argument("--plot", type=Path, default=None, help="also draw the curves into this PNG")
    args = parser.parse_args(argv)
    try:
        names = args.names or [run.name for run in args.runs]
        if len(names) != len(args.runs):
            raise ValueError(f"--names needs one name per run ({len(args.runs)}), got {len(names)}")
        if len(set(names)) != len(names):
            raise ValueError(f"--names must be distinct, got {names}")
        if args.every < 1:
            raise ValueError(f"--every must be >= 1, got {args.every}")
        runs = {name: read_metrics(run) for name, run in zip(names, args.runs)}
    except ValueError as err:
        print(f"Error: {err}", file=sys.stderr)
        return 2
    last = args.last if args.last is not None else max(max(lines, default=0) for lines in runs.values())
    print(table(runs, args.keys, args.first, last, args.every))
    if args.plot is not None:
        plot(runs, dict(zip(names, args.runs)), args.keys, args.first, last, args.plot)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
