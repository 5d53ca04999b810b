"""The accommodation runs against plain ones, as one table: the accommodation study's report.

    .venv/bin/python experiments/accommodation/report.py NAME=RUN,RUN... [--eval FILE] [--per-distance]

(README.md here says what it measured; ``focus_curve.py`` draws the rewards against defocus and
``policy.py`` reads what a trained accommodation cue does.) A missing file, a run without the
accommodation cue's errors or a bad argument prints one ``error:`` line and exits with status 2
(`aectorch.report.command.run_command`, as ``python -m aectorch.report`` does).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Mapping, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.report.command import run_command, study_parser, run_groups  # noqa: E402
from aectorch.runs import EVALUATION, Run  # noqa: E402
from aectorch.sim import PinholeCamera  # noqa: E402

__all__ = ["accommodation_table", "distance_table", "main", "parser"]

_KEYS = (("vergence MAE (deg)", lambda e: e["vergence_mae_deg"]),
         ("pursuit MAE (deg)", lambda e: e["pursuit_mae_deg"]),
         ("depth MAE (m)", lambda e: e["depth_mae_m"]),
         ("accommodation MAE (deg of blur)", lambda e: e.get("accommodation_mae_deg")),
         ("accommodation MAE (D)", lambda e: e.get("accommodation_focus", {}).get("mae_D")),
         ("accommodation MAE (px, full scale)", lambda e: e.get("accommodation_focus", {}).get("mae_px")),
         ("fixation ends within 0.25 px", lambda e: e.get("accommodation_focus", {}).get("within_0.25px")),
         ("fixation ends within 0.5 px", lambda e: e.get("accommodation_focus", {}).get("within_0.5px")))


def _mean_sd(values: Sequence) -> tuple[float, float] | tuple[None, None]:
    values = [v for v in values if v is not None]
    if not values:
        return None, None
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def accommodation_table(groups: Mapping[str, Sequence[Run]], evaluation: str = EVALUATION,
                        per_distance: bool = False) -> list[str]:
    """Groups of runs side by side (e.g. with the accommodation cue and plain): the mean +- sd over
    each group's runs of the final state's vergence, pursuit and depth MAE and accommodation error
    (blur-disc degrees, dioptres, full-scale pixels, fractions within 0.25 and 0.5 px); with
    ``per_distance``, then per distance and group the accommodation error at the fixation ends in
    pixels: the mean |error| and the signed mean (negative: focused beyond the object), over the
    runs' trials (`distance_table`)."""
    evals = {name: [run.evaluation(evaluation) for run in runs] for name, runs in groups.items()}
    lines = ["| | " + " | ".join(f"{name} ({len(e)} seeds)" for name, e in evals.items()) + " |",
             "|---" * (len(evals) + 1) + "|"]
    for label, read in _KEYS:
        cells = []
        for results in evals.values():
            mean, sd = _mean_sd([read(result) for result in results])
            cells.append("-" if mean is None else f"{mean:.3f} +- {sd:.3f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + (["", *distance_table(evals)] if per_distance else [])


def distance_table(evals: Mapping[str, Sequence[Mapping]]) -> list[str]:
    """Per distance (rows) and group (columns): the accommodation error of the per-trial rows'
    fixation ends (``accommodation_errors_deg``) in full-scale pixels, mean |error| / signed mean
    over all the group's trials; groups without the error get ``-``."""
    per_px = PinholeCamera().degrees_per_pixel
    errors: dict[str, dict[float, list[float]]] = {}
    for name, results in evals.items():
        for result in results:
            for row in result.get("per_trial", []):
                if row.get("accommodation_errors_deg") is not None:
                    errors.setdefault(name, {}).setdefault(float(row["distance_m"]), []).extend(
                        e / per_px for e in row["accommodation_errors_deg"])
    if not errors:
        raise KeyError("no per-trial accommodation errors in these evaluations (a run with the accommodation cue)")
    distances = sorted({d for rows in errors.values() for d in rows})
    lines = ["| distance (m) | " + " | ".join(f"{name}: px, mean abs. / signed" for name in evals) + " |",
             "|---" * (len(evals) + 1) + "|"]
    for d in distances:
        cells = [f"{statistics.fmean(abs(e) for e in errors[n][d]):.2f} / {statistics.fmean(errors[n][d]):+.2f}"
                 if d in errors.get(n, {}) else "-" for n in evals]
        lines.append(f"| {d:g} | " + " | ".join(cells) + " |")
    return lines


def _report(args) -> list[str]:
    return accommodation_table(run_groups(args.groups), args.eval, args.per_distance)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `accommodation_table`'s docstring."""
    out = study_parser("experiments/accommodation/report.py", accommodation_table, _report)
    out.add_argument("groups", nargs="+", help="name=run,run,...")
    out.add_argument("--eval", default=EVALUATION, help=f"evaluation file in each run folder (default: {EVALUATION})")
    out.add_argument("--per-distance", action="store_true",
                     help="also the accommodation error per distance (px: mean abs. / signed)")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
