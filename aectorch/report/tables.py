"""Tables of finished runs: one row per run (``table``, ``ablation``) and a band of distances
(``band``). Each returns the markdown lines it prints.

The thresholds of "on target" and "failed" are the evaluation's (`aectorch.evaluation.summary`:
``WITHIN_DEG``, ``BEYOND_DEG``), and the fractions come from its `fractions`.
"""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Sequence

import torch

from aectorch.evaluation.summary import BEYOND_DEG, WITHIN_DEG, fractions
from aectorch.runs import EVALUATION, Run

__all__ = ["NEAR_M", "ablation_table", "band", "band_line", "results_row", "results_table"]

#: `results_table` reports the trials up to this distance (metres) apart.
NEAR_M = 1.5
#: Slack on the distances' ends (they are stored rounded to 1e-6 m).
_EPS_M = 1e-9

_COLUMNS = [
    ("seed", "seed"),
    ("iterations", "iterations"),
    ("best", "evaluated (best.pt: iteration)"),
    ("train_min", "train (min)"),
    ("window_pursuit", "train window pursuit (deg)"),
    ("window_vergence", "train window vergence (deg)"),
    ("window_depth", "train window depth (m)"),
    ("pursuit", "pursuit MAE (deg)"),
    ("pursuit_median", "pursuit median abs (deg)"),
    ("vergence", "vergence MAE (deg)"),
    ("vergence_median", "vergence median abs (deg)"),
    ("depth", "depth MAE (m)"),
    ("depth_median", "depth median abs (m)"),
    ("vtest_rmse", "vergence test RMSE (deg)"),
    ("within", f"both within {WITHIN_DEG} deg"),
    ("beyond", f"either beyond {BEYOND_DEG:g} deg"),
    ("near_pursuit", f"1.0-{NEAR_M} m pursuit MAE (deg)"),
    ("near_vergence", f"1.0-{NEAR_M} m vergence MAE (deg)"),
    ("near_depth", f"1.0-{NEAR_M} m depth MAE (m)"),
    ("trials", "trials"),
]


def _near(rows: list[dict]) -> dict:
    """MAEs of the trials at 1.0-1.5 m (both fixation ends of each), from ``per_trial``."""
    rows = [r for r in rows if r["distance_m"] <= NEAR_M + _EPS_M]
    if not rows:
        return {"near_pursuit": math.nan, "near_vergence": math.nan, "near_depth": math.nan}
    pursuit = [abs(e) for r in rows for e in r["pursuit_errors_deg"]]
    vergence = [abs(e) for r in rows for e in r["vergence_errors_deg"]]
    depth = [abs(r["depth_error_m"]) for r in rows if r["depth_error_m"] is not None]
    return {"near_pursuit": statistics.mean(pursuit), "near_vergence": statistics.mean(vergence),
            "near_depth": statistics.mean(depth) if depth else math.nan}


def results_row(run: Run, evaluation: str = EVALUATION) -> dict:
    """One run's row of `results_table`: training (``summary.json``) and an evaluation's numbers."""
    summary, result = run.summary, run.evaluation(evaluation)
    final = summary["final"]
    seed = run.config.get("seed", "?")
    row = {
        "seed": "null" if seed is None else str(seed),
        "iterations": summary["iterations"],
        "best": summary["best"]["iteration"] if summary.get("best") else "last",
        "train_min": summary["train_seconds"] / 60,
        "window_pursuit": final["pursuit_mae_deg"],
        "window_vergence": final["vergence_mae_deg"],
        "window_depth": final["depth_mae_m"],
        "pursuit": result["pursuit_mae_deg"],
        "pursuit_median": result["pursuit"]["median_abs"],
        "vergence": result["vergence_mae_deg"],
        "vergence_median": result["vergence"]["median_abs"],
        "depth": result["depth_mae_m"],
        "depth_median": result["depth"]["median_abs"],
        "vtest_rmse": result.get("vergence_test", {}).get("degrees", {}).get("rmse", math.nan),
        "within": result.get("fractions", {}).get("both", {}).get("within", math.nan),
        "beyond": result.get("fractions", {}).get("both", {}).get("beyond", math.nan),
        **_near(result.get("per_trial", [])),
        "trials": result["trials"],
    }
    _check_numbers(row, run.path / "summary.json", run.path / evaluation)
    return row


#: The cells of `results_row` that come from ``summary.json`` (the others: the evaluation's).
_FROM_SUMMARY = ("iterations", "train_min", "window_pursuit", "window_vergence", "window_depth")


def _check_numbers(row: dict, summary: Path, evaluation: Path) -> None:
    """Every cell but the seed's and the evaluated state's is a number (or null, shown n/a): a
    value of another type is a damaged or hand-edited file, named, not a cell of the table."""
    for key, value in row.items():
        if key in ("seed", "best") or value is None or isinstance(value, (int, float)) and not isinstance(value, bool):
            continue
        raise ValueError(f"{summary if key in _FROM_SUMMARY else evaluation}: {key} must be a number, got {value!r}")


def _fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.3f}"
    return str(value)


def results_table(runs: Sequence[Run], evaluation: str = EVALUATION) -> list[str]:
    """One markdown row per run (`results_row`) and, for two runs or more, mean +- sd."""
    rows = [results_row(run, evaluation) for run in runs]
    lines = ["| " + " | ".join(title for _, title in _COLUMNS) + " |", "|" + "---|" * len(_COLUMNS)]
    lines += ["| " + " | ".join(_fmt(row[key]) for key, _ in _COLUMNS) + " |" for row in rows]
    if len(rows) > 1:
        cells = []
        for key, _ in _COLUMNS:
            values = [row[key] for row in rows if isinstance(row[key], float) and not math.isnan(row[key])]
            if key == "seed":
                cells.append("mean +- sd")
            elif len(values) == len(rows):
                cells.append(f"{statistics.mean(values):.3f} +- {statistics.stdev(values):.3f}")
            else:
                cells.append("")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def band(rows: list[dict], low_m: float, high_m: float) -> dict:
    """The errors of the trials at ``low_m`` to ``high_m`` metres (both fixation ends of each):
    pursuit, vergence and depth MAE, the depth error's mean (its bias), and the fractions of
    fixation ends on target and failed (`aectorch.evaluation.summary.fractions` over every movement)."""
    rows = [r for r in rows if low_m - _EPS_M <= r["distance_m"] <= high_m + _EPS_M]
    if not rows:
        raise ValueError(f"no trial at {low_m}-{high_m} m")
    movements = [key[: -len("_errors_deg")] for key in rows[0] if key.endswith("_errors_deg")]
    ends = {m: [e for r in rows for e in r[f"{m}_errors_deg"]] for m in movements}
    depth = [r["depth_error_m"] for r in rows if r["depth_error_m"] is not None]
    both = fractions({m: torch.tensor(e, dtype=torch.float64) for m, e in ends.items()})["both"]
    return {"trials": len(rows),
            **{f"{m}_mae_deg": statistics.fmean(abs(e) for e in ends[m]) for m in movements},
            "depth_mae_m": statistics.fmean(abs(d) for d in depth) if depth else math.nan,
            "depth_bias_m": statistics.fmean(depth) if depth else math.nan,
            "within": both["within"], "beyond": both["beyond"]}


def band_line(runs: Sequence[Run], evaluation: str, low_m: float, high_m: float) -> str:
    """`band` of each run's evaluation, averaged over the runs, as one line."""
    if high_m < low_m:
        raise ValueError(f"--high must be >= --low, got {low_m} and {high_m}")
    per_run = [band(run.per_trial(evaluation), low_m, high_m) for run in runs]
    mean = {k: statistics.fmean(r[k] for r in per_run) for k in per_run[0]}
    return (f"{low_m}-{high_m} m, {evaluation}, mean of {len(per_run)} runs: pursuit {mean['pursuit_mae_deg']:.3f} deg, "
            f"vergence {mean['vergence_mae_deg']:.3f} deg, depth {mean['depth_mae_m']:.3f} m (bias "
            f"{mean['depth_bias_m']:+.3f} m), within {WITHIN_DEG} deg {mean['within']:.1%}, "
            f"beyond {BEYOND_DEG:g} deg {mean['beyond']:.1%} ({per_run[0]['trials']} trials each)")


def _ablation_cells(run: Run, name: str) -> list[str]:
    if not run.has(name):
        return ["n/a"] * 3
    r = run.evaluation(name)
    both = r["fractions"]["both"]
    last = r.get("last5")
    return [f"{r['pursuit_mae_deg']:.3f} / {r['vergence_mae_deg']:.3f} / {r['depth_mae_m']:.3f}",
            f"{both['within']:.1%} / {both['beyond']:.1%}",
            "n/a" if not last else f"{last['pursuit_mae_deg']:.3f} / {last['vergence_mae_deg']:.3f}"]


def ablation_table(specs: Sequence[str]) -> tuple[list[str], dict]:
    """One row per ``label=run[:suffix]``: the run's ``final_textures<suffix>.json`` and
    ``final_choose<suffix>.json`` (``python -m aectorch.evaluate`` of its checkpoint, as
    scripts/train_eval.sh writes them); returns the markdown lines and the cells by label."""
    lines = [f"| run | textures: pursuit / vergence (deg) / depth (m) | within {WITHIN_DEG} deg / beyond {BEYOND_DEG:g} deg "
             f"| last 5 | photographs: pursuit / vergence / depth | within {WITHIN_DEG} deg / beyond {BEYOND_DEG:g} deg "
             "| last 5 |", "|---|---|---|---|---|---|---|"]
    out = {}
    for spec in specs:
        label, equals, target = spec.rpartition("=")
        if not equals or not label:
            raise ValueError(f"rows are label=run[:suffix], got {spec!r}")
        folder, _, suffix = target.partition(":")
        run = Run(folder)
        cells = [c for s in ("textures", "choose") for c in _ablation_cells(run, f"final_{s}{suffix}.json")]
        out[label] = {"run": folder, "suffix": suffix, "cells": cells}
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines, out
