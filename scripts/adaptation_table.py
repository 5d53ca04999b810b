"""The recovery read-out of perturbed runs as one table (docs/results.md, "Adaptation to a roll").

    .venv/bin/python scripts/adaptation_table.py runs/r10_decay_s0 runs/r10_raise_s0 --change 1200 \\
        --before runs/base_s0/checkpoint.pt

For each run: `aectorch.evaluation.adaptation` of its ``metrics.jsonl`` around the change at
``--change`` (the learner iteration its first event acts from) to the run's end, for vergence,
pursuit and depth: the short window before, the peak and its ratio, the iterations until the
window is back within 1.2x, the final window, and the fraction of fixation ends within one pixel
before, at its lowest and the iterations until it is 95 % again. A run forked from an unperturbed
one (``scripts/fork_run.py``) has no short window before the fork in its lines: ``--before`` takes
it from the unperturbed run's checkpoint at the change (its metrics hold the last 1000 fixation
ends, of which the window is the last ``train.recent_window``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def before_line(checkpoint: Path, recent: int) -> dict:
    """The metrics line a run with perturbations would have logged at the checkpoint's iteration:
    the short window of the checkpoint's metrics."""
    import torch

    from aectorch.evaluation.summary import WITHIN_DEG
    from aectorch.runtime import load_checkpoint

    payload = load_checkpoint(checkpoint)
    metrics = payload["metrics"]
    line: dict = {"iteration": int(payload["iteration"])}
    for movement, window in metrics["errors"].items():
        last = window[-recent:]
        line[f"{movement}_recent_deg"] = float(last.mean())
        line[f"{movement}_recent_1px"] = float((last <= WITHIN_DEG).to(torch.float64).mean())
    line["depth_recent_m"] = float(metrics["depth"][-max(1, recent // 2):].mean())
    return line


def readout(run: Path, change: int, before: Path | None = None) -> dict:
    from aectorch.evaluation import adaptation

    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    if before is not None:
        import yaml

        window = yaml.safe_load((run / "config.yaml").read_text())["train"]["recent_window"]
        extra = before_line(before, window)
        lines = sorted([line for line in lines if line["iteration"] != extra["iteration"]] + [extra],
                       key=lambda line: line["iteration"])
    return adaptation(lines, [(change, int(lines[-1]["iteration"]), "change")])["change"]


def _f(value, spec: str = ".3f") -> str:
    return "-" if value is None else format(value, spec)


def table(runs: list[Path], change: int, before: Path | None) -> str:
    rows = ["| run | error | before | peak (x before, at) | iterations to 1.2x | final | within 1 px: before / lowest "
            "| iterations to 95 % |", "|---|---|---|---|---|---|---|---|"]
    for run in runs:
        out = readout(run, change, before)
        for key in ("vergence", "pursuit", "depth"):
            e = out[key]
            rows.append(f"| {run.name} | {key} | {_f(e['before'])} | {_f(e['peak'])} ({_f(e['peak_ratio'], '.1f')}x, "
                        f"{e['peak_iteration']}) | {_f(e['iterations_to_recover'], 'd')} | {_f(e['final'])} | "
                        f"{_f(e.get('within_1px_before'), '.2f')} / {_f(e.get('within_1px_min'), '.2f')} | "
                        f"{_f(e.get('iterations_to_95pct'), 'd')} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run folders")
    parser.add_argument("--change", type=int, required=True, help="the iteration the first event acts from")
    parser.add_argument("--before", type=Path, help="the unperturbed run's checkpoint at the change (forked runs)")
    args = parser.parse_args(argv)
    print(table(args.runs, args.change, args.before))
    return 0


if __name__ == "__main__":
    sys.exit(main())
