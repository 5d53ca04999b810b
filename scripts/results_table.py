"""Tabulate finished training runs (the numbers in docs/results.md come from this script).

    .venv/bin/python scripts/results_table.py runs/seed0 runs/seed1 runs/seed2 [--eval heldout.json]

For every run folder it reads ``summary.json`` (training time, the last training window's
metrics; with ``train.keep_best`` the iteration of ``best.pt``, the state every evaluation is
of), ``evaluation.json`` (the held-out procedural textures evaluated at the end of training)
and, when present, the file named by ``--eval`` (e.g. an evaluation on unseen
photographs made with ``python -m aectorch.evaluate ... out=<run>/heldout.json``). It prints one
markdown row per run and, for two runs or more, the mean and standard deviation. Besides the
MAEs: the fraction of fixation ends with pursuit and vergence both within 0.22 deg (1 px), the
fraction with either beyond 2 deg, and the MAEs of the 1.0-1.5 m trials alone (from the
evaluation's ``per_trial`` rows).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

COLUMNS = [
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
    ("within", "both within 0.22 deg"),
    ("beyond", "either beyond 2 deg"),
    ("near_pursuit", "1.0-1.5 m pursuit MAE (deg)"),
    ("near_vergence", "1.0-1.5 m vergence MAE (deg)"),
    ("near_depth", "1.0-1.5 m depth MAE (m)"),
    ("trials", "trials"),
]
#: The near trials reported apart: distances up to this many metres.
NEAR_M = 1.5


def _near(evaluation: dict) -> dict:
    """MAEs of the trials at 1.0-1.5 m (both fixation ends of each), from ``per_trial``."""
    rows = [r for r in evaluation.get("per_trial", []) if r["distance_m"] <= NEAR_M + 1e-9]
    if not rows:
        return {"near_pursuit": math.nan, "near_vergence": math.nan, "near_depth": math.nan}
    pursuit = [abs(e) for r in rows for e in r["pursuit_errors_deg"]]
    vergence = [abs(e) for r in rows for e in r["vergence_errors_deg"]]
    depth = [abs(r["depth_error_m"]) for r in rows if r["depth_error_m"] is not None]
    return {"near_pursuit": statistics.mean(pursuit), "near_vergence": statistics.mean(vergence),
            "near_depth": statistics.mean(depth) if depth else math.nan}


def _row(run: Path, eval_name: str | None) -> dict:
    summary = json.loads((run / "summary.json").read_text())
    config = (run / "config.yaml").read_text()
    seed = next((line.split(":", 1)[1].strip() for line in config.splitlines() if line.startswith("seed:")), "?")
    evaluation_path = run / (eval_name or "evaluation.json")
    evaluation = json.loads(evaluation_path.read_text())
    final = summary["final"]
    return {
        "seed": seed,
        "iterations": summary["iterations"],
        "best": summary["best"]["iteration"] if summary.get("best") else "last",
        "train_min": summary["train_seconds"] / 60,
        "window_pursuit": final["pursuit_mae_deg"],
        "window_vergence": final["vergence_mae_deg"],
        "window_depth": final["depth_mae_m"],
        "pursuit": evaluation["pursuit_mae_deg"],
        "pursuit_median": evaluation["pursuit"]["median_abs"],
        "vergence": evaluation["vergence_mae_deg"],
        "vergence_median": evaluation["vergence"]["median_abs"],
        "depth": evaluation["depth_mae_m"],
        "depth_median": evaluation["depth"]["median_abs"],
        "vtest_rmse": evaluation.get("vergence_test", {}).get("degrees", {}).get("rmse", math.nan),
        "within": evaluation.get("fractions", {}).get("both", {}).get("within", math.nan),
        "beyond": evaluation.get("fractions", {}).get("both", {}).get("beyond", math.nan),
        **_near(evaluation),
        "trials": evaluation["trials"],
    }


def _fmt(value) -> str:
    if isinstance(value, float):
        return "n/a" if value is None or math.isnan(value) else f"{value:.3f}"
    return str(value)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders")
    parser.add_argument("--eval", default=None,
                        help="evaluation JSON inside each run folder (default: evaluation.json)")
    args = parser.parse_args(argv)
    rows = []
    for run in args.runs:
        try:
            rows.append(_row(run, args.eval))
        except (OSError, KeyError, json.JSONDecodeError) as err:
            print(f"error: {run}: {err}", file=sys.stderr)
            return 2
    print("| " + " | ".join(title for _, title in COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for row in rows:
        print("| " + " | ".join(_fmt(row[key]) for key, _ in COLUMNS) + " |")
    if len(rows) > 1:
        cells = []
        for key, _ in COLUMNS:
            values = [row[key] for row in rows if isinstance(row[key], float) and not math.isnan(row[key])]
            if key == "seed":
                cells.append("mean +- sd")
            elif len(values) == len(rows):
                cells.append(f"{statistics.mean(values):.3f} +- {statistics.stdev(values):.3f}")
            else:
                cells.append("")
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
