"""The recovery read-out of perturbed runs as one table: the roll-adaptation study's report.

    .venv/bin/python experiments/roll_adaptation/report.py RUN... --change N [--before CHECKPOINT]

(README.md here says what it measured.) A missing file, a change outside a run's logged iterations
or a bad argument prints one ``error:`` line and exits with status 2
(`aectorch.report.command.run_command`, as ``python -m aectorch.report`` does).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.evaluation import adaptation  # noqa: E402
from aectorch.evaluation.summary import WITHIN_DEG  # noqa: E402
from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.runs import Run  # noqa: E402

__all__ = ["adaptation_table", "before_line", "main"]


def before_line(checkpoint: Path, recent: int) -> dict:
    """The metrics line a run with perturbations would have logged at the checkpoint's iteration:
    the short window (the last ``recent`` fixation ends) of the checkpoint's metrics."""
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


def _readout(run: Run, change: int, before: Path | None) -> dict:
    lines = list(run.metrics)
    if before is not None:
        extra = before_line(before, run.config["train"]["recent_window"])
        lines = sorted([line for line in lines if line["iteration"] != extra["iteration"]] + [extra],
                       key=lambda line: line["iteration"])
    logged: list = [line.get("iteration") for line in lines]  # integers, checked next
    if not lines or not all(isinstance(i, int) and not isinstance(i, bool) for i in logged):
        raise ValueError(f"{run.path / 'metrics.jsonl'}: every line needs an integer 'iteration'")
    if not logged[0] <= change < logged[-1]:
        # (outside them the read-out has no window before or after the change: a table of dashes)
        raise ValueError(f"--change {change} is outside {run.path}'s logged iterations ({logged[0]} to "
                         f"{logged[-1]}): give the iteration its first event acts from, within them")
    return adaptation(lines, [(change, int(lines[-1]["iteration"]), "change")])["change"]


def _f(value, spec: str = ".3f") -> str:
    return "-" if value is None else format(value, spec)


def adaptation_table(runs: Sequence[Run], change: int, before: Path | None = None) -> list[str]:
    """The recovery read-out of perturbed runs (experiments/roll_adaptation/README.md).

    For each run: `aectorch.evaluation.adaptation` of its ``metrics.jsonl`` around the change at
    ``--change`` (the learner iteration its first event acts from) to the run's end, for vergence,
    pursuit and depth: the short window before, the peak and its ratio, the iterations until the
    window is back within 1.2x, the final window, and the fraction of fixation ends within one
    pixel before, at its lowest and the iterations until it is 95 % again. A run forked from an
    unperturbed one (``scripts/fork_run.py``) has no short window before the fork in its lines:
    ``--before`` takes it from the unperturbed run's checkpoint at the change (its metrics hold the
    last 1000 fixation ends, of which the window is the last ``train.recent_window``).
    """
    rows = ["| run | error | before | peak (x before, at) | iterations to 1.2x | final | within 1 px: before / lowest "
            "| iterations to 95 % |", "|---|---|---|---|---|---|---|---|"]
    for run in runs:
        out = _readout(run, change, before)
        for key in ("vergence", "pursuit", "depth"):
            e = out[key]
            rows.append(f"| {run.name} | {key} | {_f(e['before'])} | {_f(e['peak'])} ({_f(e['peak_ratio'], '.1f')}x, "
                        f"{e['peak_iteration']}) | {_f(e['iterations_to_recover'], 'd')} | {_f(e['final'])} | "
                        f"{_f(e.get('within_1px_before'), '.2f')} / {_f(e.get('within_1px_min'), '.2f')} | "
                        f"{_f(e.get('iterations_to_95pct'), 'd')} |")
    return rows


def _report(args) -> list[str]:
    return adaptation_table([Run(run) for run in args.runs], args.change, args.before)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `adaptation_table`'s docstring."""
    out = study_parser("experiments/roll_adaptation/report.py", adaptation_table, _report)
    out.add_argument("runs", nargs="+", type=Path, help="run folders")
    out.add_argument("--change", type=int, required=True, help="the iteration the first event acts from")
    out.add_argument("--before", type=Path, default=None,
                     help="the unperturbed run's checkpoint at the change (forked runs)")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
