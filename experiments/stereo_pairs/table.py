"""The stereo pairs' table: each policy's final errors per pixel scale and start, mean over seeds.

    .venv/bin/python experiments/stereo_pairs/table.py runs/pairs_default_s0 runs/pairs_default_s1 \
        runs/pairs_default_s2 --json experiments/stereo_pairs/results.json

Each run folder holds ``pairs_ps<k>.json`` (``python -m aectorch.evaluate pairs=... pair_scale=k``).
For every pixel scale, start kind and policy one markdown row: the mean over the runs of the median
|error| (eye pixels), the fraction within 1 px, the fraction beyond 5 px and the fraction beyond 5 px
past the match (converged too far), the median over the fixations whose ground truth is within the
training's largest disparity (the optimum at 1 m, 15.4 eye px) and over the nearer ones, each run's
value in brackets (in the runs' order; one value where the runs agree), then the policy's on smooth
windows, on windows across a depth edge and on the visible fixation points, those the right
photograph does not hide (`aectorch.evaluation.stereo_pairs`). ``--json`` keeps the rows and every
run's summary.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

MEASURES = (("median_abs_px", "median \\|error\\| (px)", 1.0, "{:.2f}"), ("within_1px", "within 1 px (%)", 100.0, "{:.0f}"),
            ("beyond_5px", "beyond 5 px (%)", 100.0, "{:.0f}"))
POLICIES = ("learner", "matcher", "no_movement")
#: The largest disparity of training, eye pixels: the vergence optimum at 1 m, the nearest default
#: distance (3.43 deg at the camera's focal length of 257.34 px).
TRAINED_PX = 15.4
STARTS = ("protocol", "vergence_test")
#: The parts of the fixations with columns of their own (`aectorch.evaluation.stereo_pairs.PARTS`).
WINDOWS = ("smooth", "edge", "visible")


def evaluations(runs: list[Path]) -> dict[int, list[dict]]:
    """``{pair_scale: [each run's evaluation]}`` for the scales every run has."""
    found: dict[int, dict[Path, dict]] = {}
    for run in runs:
        for path in sorted(run.glob("pairs_ps*.json")):
            match = re.fullmatch(r"pairs_ps(\d+)\.json", path.name)
            if match:
                found.setdefault(int(match.group(1)), {})[run] = json.loads(path.read_text())
    return {scale: [by_run[r] for r in runs] for scale, by_run in sorted(found.items()) if len(by_run) == len(runs)}


def cell(values: list[float], scale: float, form: str) -> str:
    mean = sum(values) / len(values)
    each = " / ".join(form.format(v * scale) for v in values)
    return f"{form.format(mean * scale)} ({each})" if len(set(values)) > 1 else form.format(mean * scale)


def past(result: dict, policy: str, start: str) -> float:
    """The fraction of the fixations that end more than 5 px past the match (converged too far)."""
    key = "start_error_px" if policy == "no_movement" else "vergence_error_px"
    chosen = [r[key] for r in result["per_fixation"]
              if r["policy"] == ("learner" if policy == "no_movement" else policy) and r["start"] == start]
    return sum(e > result["beyond_px"] for e in chosen) / len(chosen)


def median_by_range(result: dict, policy: str, start: str) -> list[float]:
    """The median |error| of the fixations whose ground truth is within `TRAINED_PX` and beyond it."""
    key = "start_error_px" if policy == "no_movement" else "vergence_error_px"
    chosen = [r for r in result["per_fixation"]
              if r["policy"] == ("learner" if policy == "no_movement" else policy) and r["start"] == start]
    out = []
    for inside in (True, False):
        errors = sorted(abs(r[key]) for r in chosen if (r["ground_truth_px"] <= TRAINED_PX) == inside)
        n = len(errors)
        out.append(float("nan") if n == 0 else (errors[(n - 1) // 2] + errors[n // 2]) / 2)
    return out


def rows(found: dict[int, list[dict]]) -> list[dict]:
    out = []
    for scale, results in found.items():
        for start in STARTS:
            for policy in POLICIES:
                parts = [r["summary"][policy][start] for r in results]
                row = {"pair_scale": scale, "start": start, "policy": policy,
                       **{key: [p["all"][key] for p in parts] for key, *_ in MEASURES},
                       "past_5px": [past(r, policy, start) for r in results],
                       "trained_median_abs_px": [median_by_range(r, policy, start)[0] for r in results],
                       "nearer_median_abs_px": [median_by_range(r, policy, start)[1] for r in results]}
                if policy != "no_movement":
                    for window in WINDOWS:
                        if any(window not in p for p in parts):  # an evaluation made before visible points
                            continue
                        row[f"{window}_median_abs_px"] = [p[window]["median_abs_px"] for p in parts]
                        row[f"{window}_beyond_5px"] = [p[window]["beyond_5px"] for p in parts]
                        row[f"{window}_n"] = [p[window]["n"] for p in parts]
                out.append(row)
    return out


def markdown(table: list[dict]) -> str:
    head = ["pixel scale", "start", "policy", *(label for _, label, *_ in MEASURES), "beyond 5 px past the match (%)",
            f"median, ground truth <= {TRAINED_PX} px", f"median, ground truth > {TRAINED_PX} px",
            *(f"{window}: median, beyond 5 px" for window in WINDOWS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in table:
        cells = [str(row["pair_scale"]), row["start"].replace("_", " "), row["policy"].replace("_", " ")]
        cells += [cell(row[key], scale, form) for key, _, scale, form in MEASURES]
        cells.append(cell(row["past_5px"], 100.0, "{:.0f}"))
        cells += [cell(row[key], 1.0, "{:.2f}") for key in ("trained_median_abs_px", "nearer_median_abs_px")]
        for window in WINDOWS:
            if f"{window}_n" in row and not any(row[f"{window}_n"]):
                cells.append("no window")
            elif f"{window}_n" in row:
                cells.append(f"{cell(row[f'{window}_median_abs_px'], 1.0, '{:.2f}')}, "
                             f"{cell(row[f'{window}_beyond_5px'], 100.0, '{:.0f}')} % (n {row[f'{window}_n'][0]})")
            else:
                cells.append("")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run folders holding pairs_ps<k>.json")
    parser.add_argument("--json", type=Path, help="write the rows and each run's summaries here")
    args = parser.parse_args(argv)
    found = evaluations(args.runs)
    if not found:
        print("error: no pixel scale has a pairs_ps<k>.json in every run", file=sys.stderr)
        return 2
    table = rows(found)
    print(markdown(table))
    if args.json:
        first = next(iter(found.values()))[0]
        args.json.write_text(json.dumps({
            "runs": [str(r) for r in args.runs], "rows": table,
            "settings": {k: first[k] for k in ("steps", "scales", "start_kinds", "seed", "min_contrast",
                                               "edge_residual_px", "edge_unknown_fraction", "pairs")},
            "summaries": {str(scale): [r["summary"] for r in results] for scale, results in found.items()}},
            indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
