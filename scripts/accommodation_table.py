"""The accommodation runs against the plain ones: mean +- sd over seeds of the final state's
evaluation (``evaluation.json``, or ``--eval`` in each run folder), docs/results.md, "Accommodation".

    PYTHONPATH=. .venv/bin/python scripts/accommodation_table.py \\
        accommodation=runs/acc600_s0,runs/acc600_s1,runs/acc600_s2 plain=runs/plain600_s0,...
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

KEYS = (("vergence MAE (deg)", lambda e: e["vergence_mae_deg"]),
        ("pursuit MAE (deg)", lambda e: e["pursuit_mae_deg"]),
        ("depth MAE (m)", lambda e: e["depth_mae_m"]),
        ("accommodation MAE (deg of blur)", lambda e: e.get("accommodation_mae_deg")),
        ("accommodation MAE (D)", lambda e: e.get("accommodation_focus", {}).get("mae_D")),
        ("accommodation MAE (px, full scale)", lambda e: e.get("accommodation_focus", {}).get("mae_px")),
        ("fixation ends within 0.25 px", lambda e: e.get("accommodation_focus", {}).get("within_0.25px")),
        ("fixation ends within 0.5 px", lambda e: e.get("accommodation_focus", {}).get("within_0.5px")))


def _mean_sd(values: list[float]) -> str:
    if not values:
        return "-"
    mean = sum(values) / len(values)
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else 0.0
    return f"{mean:.3f} +- {sd:.3f}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("groups", nargs="+", help="name=run,run,...")
    parser.add_argument("--eval", default="evaluation.json", help="the evaluation file in each run folder")
    args = parser.parse_args(argv)
    groups = {}
    for group in args.groups:
        name, _, runs = group.partition("=")
        groups[name] = [json.loads((Path(run) / args.eval).read_text()) for run in runs.split(",")]
    print("| | " + " | ".join(f"{name} ({len(evals)} seeds)" for name, evals in groups.items()) + " |")
    print("|---" * (len(groups) + 1) + "|")
    for label, read in KEYS:
        cells = [_mean_sd([v for v in map(read, evals) if v is not None]) for evals in groups.values()]
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
