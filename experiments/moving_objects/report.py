"""A moving object's tracking error per speed over runs, as one table: the moving-object study's report.

    .venv/bin/python experiments/moving_objects/report.py RUN... [--eval tracking.json] [--within DEG]
        [--plot PNG] [--target DEG]

Each run folder holds an evaluation of ``python -m aectorch.evaluate ... tracking=[...]`` (README.md
here says what it measured). A missing file, an evaluation without the tracking test or of another
checkpoint, or a bad argument prints one ``error:`` line and exits with status 2
(`aectorch.report.command.run_command`, as ``python -m aectorch.report`` does).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.runs import Run  # noqa: E402

__all__ = ["main", "parser", "tracking_table"]


def _stats(values: list[float], digits: int = 3) -> str:
    mean = sum(values) / len(values)
    if len(values) < 2:
        return f"{mean:.{digits}f}"
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    return f"{mean:.{digits}f} +- {sd:.{digits}f}"


def _within(per_trial: list[dict], speed: float, key: str, limit_deg: float) -> float:
    """The percentage of fixations (two per trial) at ``|speed|`` whose mean ``key`` is within ``limit_deg``."""
    values = [e for row in per_trial if abs(row["speed_deg"]) == speed for e in row[key]]
    return 100.0 * sum(e <= limit_deg for e in values) / len(values)


def tracking_table(runs: Sequence[Run], evaluation: str, plot: Path | None = None,
                   target_deg: float | None = None, within_deg: float | None = None) -> list[str]:
    """The tracking errors of a moving object per speed: mean +- standard deviation over runs.

    Reads ``evaluation`` (``python -m aectorch.evaluate ... tracking=[...]``'s JSON) in each run
    folder: for each sideways speed (degrees per iteration) every eye movement's mean |error| after
    each fixation's first ``skip`` iterations, over all trials of a run, then over the runs (one
    value per run: the seeds' spread). ``--plot`` draws the error against speed
    (`aectorch.figures.plot_tracking`), ``--target`` a dotted line at that error. ``--within X``
    adds, for each movement, the percentage of fixations whose mean |error| is within X (from the
    per-trial rows: a few lost fixations and a spread of small errors can have the same mean).
    """
    results = [run.evaluation(evaluation) for run in runs]
    if not results:
        raise ValueError("tracking needs at least one run folder")
    missing = [str(run.path) for run, result in zip(runs, results) if "tracking" not in result]
    if missing:
        raise ValueError(f"{evaluation} holds no tracking test (python -m aectorch.evaluate ... tracking=[...]) in "
                         f"{missing[0]}")
    per_run = [result["tracking"]["per_speed"] for result in results]
    for run, result, rows in zip(runs, results, per_run):
        # Every row holds every movement's error: a row without one would drop its column unseen.
        held = {key for row in rows + result["tracking"].get("per_trial", []) for key in row
                if key.endswith("_tracking_deg")}
        lacking = sorted(held - set(key for row in rows for key in row) | {key for row in rows for key in held - set(row)})
        if not rows or lacking:
            raise ValueError(f"{run.path / evaluation}: its tracking.per_speed rows "
                             + (f"lack {lacking[0]}" if lacking else "are empty"))
    keys = [key for key in per_run[0][0] if key.endswith("_tracking_deg")]
    speeds = [row["speed_deg"] for row in per_run[0]]
    if any([row["speed_deg"] for row in rows] != speeds for rows in per_run):
        raise ValueError(f"the runs' {evaluation} were made at different speeds")
    first = results[0]["tracking"]
    lines = [f"{len(runs)} runs, mean |error| (deg) after each fixation's first {first['skip']} iterations, "
             f"depth speed {first['depth_speed_m']:g} m per iteration",
             "| speed (deg/iteration) | " + " | ".join(k[: -len("_tracking_deg")] for k in keys) + " |",
             "|---|" + "---|" * len(keys)]
    plain = [k for k in keys if not k.endswith(("_lead_tracking_deg", "_speed_tracking_deg"))] if within_deg else []
    if plain:
        lines[1] = lines[1] + "".join(f" {k[: -len('_tracking_deg')]} within {within_deg:g} (%) |" for k in plain)
        lines[2] = lines[2] + "---|" * len(plain)
    for i, speed in enumerate(speeds):
        within = [_stats([_within(result["tracking"]["per_trial"], speed, k, within_deg)  # type: ignore[arg-type]
                          for result in results], 1)  # (plain is empty without within_deg)
                  for k in plain]
        cells = [_stats([rows[i][k] for rows in per_run]) for k in keys] + within
        lines.append(f"| {speed:g} | " + " | ".join(cells) + " |")
    if plot is not None:
        from aectorch.figures import plot_tracking

        plot_tracking(per_run, plot, target_deg=target_deg)
        lines.append(f"wrote {plot}")
    return lines


def _report(args) -> list[str]:
    return tracking_table([Run(run) for run in args.runs], args.eval, args.plot, args.target, args.within)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `tracking_table`'s docstring."""
    out = study_parser("experiments/moving_objects/report.py", tracking_table, _report)
    out.add_argument("runs", nargs="+", type=Path, help="run folders")
    out.add_argument("--eval", default="tracking.json", help="the tracking test's file in each run folder")
    out.add_argument("--plot", type=Path, default=None, help="also draw the error against speed into this PNG")
    out.add_argument("--target", type=float, default=None, help="draw a target error (deg)")
    out.add_argument("--within", type=float, default=None,
                     help="also the percentage of fixations whose mean |error| is within this many degrees")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table (and draw the figure); 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
