"""The tails of groups of runs: the precision-and-tails study's report. How many fixations end far
off, near against far, and the worst fixation ends with what their eyes saw at the trial's start.

    .venv/bin/python experiments/precision_tails/report.py NAME=RUN,RUN... [--eval FILE] [--worst N]
        [--json OUT]

A mean error is made by its tails: one trial 16 degrees off moves a 399-trial MAE by
0.02 degrees. This counts the fixation ends beyond each threshold (either eye), compares the near
trials with the far ones, and lists the worst ends with their texture statistics (the per-trial
rows' ``view_*``, `aectorch.evaluation.views`), so a failure can be told from its view (README.md
here says what it found). A missing file, a bad file or a bad argument prints one ``error:`` line
and exits with status 2 (`aectorch.report.command.run_command`, as ``python -m aectorch.report``
does).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections import Counter
from pathlib import Path
from typing import Mapping, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.evaluation.summary import WITHIN_DEG  # noqa: E402
from aectorch.report.command import run_command, study_parser, run_groups  # noqa: E402
from aectorch.runs import EVALUATION, Run  # noqa: E402

__all__ = ["FAR_FROM_M", "THRESHOLDS_DEG", "kind", "main", "parser", "tails", "tails_lines"]

#: Fixation ends are counted beyond each of these errors (degrees, either eye).
THRESHOLDS_DEG = (1.0, 2.0)
#: Trials from this distance on are "far"; those before it "near" (1.0-1.5 m with 0.1 m steps).
FAR_FROM_M = 1.55


def _ends(rows: list[dict]) -> list[dict]:
    """Every fixation end of ``rows``: its trial, fixation, each movement's error, the largest and
    its `kind`."""
    movements = [key[: -len("_errors_deg")] for key in rows[0] if key.endswith("_errors_deg")] if rows else []
    out = []
    for row in rows:
        for fixation in range(len(row[f"{movements[0]}_errors_deg"])):
            errors = {m: row[f"{m}_errors_deg"][fixation] for m in movements}
            out.append({"row": row, "fixation": fixation, "errors": errors,
                        "worst": max(abs(e) for e in errors.values()), "kind": kind(errors)})
    return out


def kind(errors: Mapping[str, float]) -> str:
    """What failed at a fixation end: the movement of the largest error and its sign,
    ``"<movement>+"`` or ``"<movement>-"`` (errors are actual - optimal; fixations start parallel,
    so ``vergence+`` is a vergence converged past its optimum and ``vergence-`` one short of it).

    Example:
        >>> kind({"pursuit": 0.1, "vergence": -12.0}), kind({"pursuit": 3.0, "vergence": 0.5})
        ('vergence-', 'pursuit+')
    """
    movement = max(errors, key=lambda m: abs(errors[m]))
    return f"{movement}{'+' if errors[movement] >= 0 else '-'}"


def _mae(ends: list[dict], movement: str) -> float:
    return statistics.fmean(abs(e["errors"][movement]) for e in ends) if ends else math.nan


def _run_numbers(rows: list[dict]) -> dict:
    ends = _ends(rows)
    near = [e for e in ends if e["row"]["distance_m"] < FAR_FROM_M]
    far = [e for e in ends if e["row"]["distance_m"] >= FAR_FROM_M]
    movements = list(ends[0]["errors"]) if ends else []
    out = {"ends": len(ends),
           "within": statistics.fmean(all(abs(v) <= WITHIN_DEG for v in e["errors"].values()) for e in ends)}
    out.update({f"beyond_{t:g}": sum(e["worst"] > t for e in ends) for t in THRESHOLDS_DEG})
    last = THRESHOLDS_DEG[-1]  # the ends beyond the last threshold, by what failed
    kinds = Counter(e["kind"] for e in ends if e["worst"] > last)
    out.update({f"beyond_{last:g}_{k}{sign}": kinds[f"{k}{sign}"] for k in movements for sign in "+-"})
    inside = [e for e in ends if e["worst"] <= THRESHOLDS_DEG[0]]
    for m in movements:
        out[f"{m}_mae_deg"] = _mae(ends, m)
        out[f"near_{m}_mae_deg"], out[f"far_{m}_mae_deg"] = _mae(near, m), _mae(far, m)
        out[f"inside_{m}_mae_deg"] = _mae(inside, m)  # the ends with every eye within the first threshold
    return out


def _views(ends: list[dict]) -> dict:
    """The median of each ``view_*`` statistic over the trials, and over those with an end beyond
    the first threshold (each trial once)."""
    trials = {id(e["row"]): e["row"] for e in ends}
    failed = {id(e["row"]): e["row"] for e in ends if e["worst"] > THRESHOLDS_DEG[0]}
    keys = [k for k in next(iter(trials.values()), {}) if k.startswith("view_")]
    return {which: {"trials": len(rows), **{k: statistics.median(r[k] for r in rows.values()) if rows else math.nan
                                           for k in keys}}
            for which, rows in (("all", trials), (f"beyond_{THRESHOLDS_DEG[0]:g}", failed))}


def tails(groups: Mapping[str, Sequence[Run]], evaluation: str, worst: int = 10) -> dict:
    """The tails of each group of runs on one evaluation (a file in each run folder).

    For each group: per run and summed or averaged over its runs, the fixation ends (two per trial),
    the fraction with every eye within ``WITHIN_DEG``, the counts of ends with either eye beyond
    each of :data:`THRESHOLDS_DEG` (those beyond the last also by `kind`: ``beyond_2_vergence+``,
    ...), each movement's MAE overall, near (before
    :data:`FAR_FROM_M`), far and over the ends with every eye within the first threshold
    (``inside_<movement>_mae_deg``: the precision without the tails); and the ``worst`` fixation ends of all its runs (largest error of
    either eye first) with their trial's texture, distance, errors and ``view_*`` statistics.
    """
    out = {}
    for name, runs in groups.items():
        per_run, ends = [], []
        for run in runs:
            rows = run.per_trial(evaluation)
            per_run.append(_run_numbers(rows))
            ends += [dict(e, run=run.name) for e in _ends(rows)]
        keys = per_run[0].keys()
        summed = {k: (sum(r[k] for r in per_run) if k == "ends" or k.startswith("beyond_")
                      else statistics.fmean(r[k] for r in per_run)) for k in keys}
        ends.sort(key=lambda e: -e["worst"])
        out[name] = {"runs": per_run, "all": summed, "views": _views(ends),
                     "worst": [{"run": e["run"], "texture": e["row"]["texture"], "distance_m": e["row"]["distance_m"],
                                "fixation": e["fixation"], "errors_deg": e["errors"],
                                **{k: v for k, v in e["row"].items() if k.startswith("view_")}}
                               for e in ends[:worst]]}
    return out


def _f(value, digits: int = 3) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def tails_lines(result: dict) -> list[str]:
    """`tails`' result as markdown: one row per group, then each group's worst fixation ends."""
    thresholds = " | ".join(f"beyond {t:g} deg" for t in THRESHOLDS_DEG)
    lines = [f"| group | fixation ends | both within {WITHIN_DEG} deg | {thresholds} | pursuit / vergence MAE (deg) | "
             f"near (< {FAR_FROM_M:g} m): pursuit / vergence | far: pursuit / vergence | vergence near / far |",
             "|" + "---|" * (8 + len(THRESHOLDS_DEG) - 2)]
    for name, group in result.items():
        a = group["all"]
        beyond = " | ".join(f"{a[f'beyond_{t:g}']} ({a[f'beyond_{t:g}'] / a['ends']:.1%})" for t in THRESHOLDS_DEG)
        ratio = a["near_vergence_mae_deg"] / a["far_vergence_mae_deg"] if a["far_vergence_mae_deg"] else math.nan
        lines.append(f"| {name} | {a['ends']} | {a['within']:.1%} | {beyond} | {_f(a['pursuit_mae_deg'])} / "
                     f"{_f(a['vergence_mae_deg'])} | {_f(a['near_pursuit_mae_deg'])} / {_f(a['near_vergence_mae_deg'])} | "
                     f"{_f(a['far_pursuit_mae_deg'])} / {_f(a['far_vergence_mae_deg'])} | {_f(ratio, 2)}x |")
    last = f"beyond_{THRESHOLDS_DEG[-1]:g}_"
    kinds = {name: {k[len(last):]: v for k, v in group["all"].items() if k.startswith(last) and v}
             for name, group in result.items()}
    lines += [""] * any(kinds.values()) + [
        f"{name}: the ends beyond {THRESHOLDS_DEG[-1]:g} deg by the movement of the largest error and its sign "
        "(vergence + past the optimum, - short of it): " + ", ".join(f"{k} {v}" for k, v in counts.items())
        for name, counts in kinds.items() if counts]
    views = next((list(g["views"]["all"]) for g in result.values() if len(g["views"]["all"]) > 1), [])[1:]
    if views:
        lines += ["", "| group | trials | median " + " | median ".join(views) + " |", "|" + "---|" * (2 + len(views))]
        for name, group in result.items():
            for which, v in group["views"].items():
                label = "all" if which == "all" else f"with an end beyond {THRESHOLDS_DEG[0]:g} deg"
                lines.append(f"| {name}, {label} | {v['trials']} | " + " | ".join(
                    f"{v.get(k, math.nan):.2g}" for k in views) + " |")
    lines += ["", f"| run | vergence MAE (deg) | of the ends with both eyes within {THRESHOLDS_DEG[0]:g} deg | "
              f"ends beyond {THRESHOLDS_DEG[0]:g} deg |", "|---|---|---|---|"]
    for name, group in result.items():
        for i, r in enumerate(group["runs"]):
            lines.append(f"| {name} {i} | {_f(r.get('vergence_mae_deg'))} | {_f(r.get('inside_vergence_mae_deg'))} | "
                         f"{r[f'beyond_{THRESHOLDS_DEG[0]:g}']} |")
    for name, group in result.items():
        if not group["worst"]:
            continue
        views = [k for k in group["worst"][0] if k.startswith("view_")]
        lines += ["", f"{name}: the worst fixation ends",
                  "| run | texture | distance (m) | fixation | errors (deg) | " + " | ".join(views) + " |",
                  "|" + "---|" * (5 + len(views))]
        for e in group["worst"]:
            errors = ", ".join(f"{m} {v:+.2f}" for m, v in e["errors_deg"].items())
            lines.append(f"| {e['run']} | {e['texture']} | {e['distance_m']:.1f} | {e['fixation']} | {errors} | "
                         + " | ".join(f"{e[k]:.2g}" for k in views) + " |")
    return lines


def _report(args) -> list[str]:
    result = tails(run_groups(args.groups), args.eval, args.worst)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return tails_lines(result)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `tails`' docstring."""
    out = study_parser("experiments/precision_tails/report.py", tails, _report)
    out.add_argument("groups", nargs="+", help="name=run,run,...")
    out.add_argument("--eval", default=EVALUATION, help=f"evaluation file in each run folder (default: {EVALUATION})")
    out.add_argument("--worst", type=int, default=10, help="list this many of the worst fixation ends (default 10)")
    out.add_argument("--json", type=Path, help="also write the numbers here")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
