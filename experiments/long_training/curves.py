"""The learning curves of groups of staged runs (``stages.py``): errors against iterations, per set.

    .venv/bin/python experiments/long_training/curves.py defaults=runs/long_s0,runs/long_s1,runs/long_s2 \
        robust=runs/ll_s0,runs/ll_s1,runs/ll_s2 --sets choose report [--json out.json] [--plot curves.png]

For every set (the NAME of ``stages.py --eval NAME=...``) and every stage that all runs of a group
reached, one markdown row: the mean over the group's runs (standard deviation in brackets) of the
final-state errors (pursuit and vergence MAE, depth MAE, both eyes within 1 px, either beyond
2 deg) and of the earlier models' vergence test (MAE, RMSE, the largest end; starts +-2 deg around
the optimum).
``--plot`` draws pursuit and vergence MAE against iterations, a panel per set and measure.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

MEASURES = {  # name: (label, read from an evaluation JSON)
    "pursuit": ("pursuit MAE (deg)", lambda d: d["pursuit_mae_deg"]),
    "vergence": ("vergence MAE (deg)", lambda d: d["vergence_mae_deg"]),
    "depth": ("depth MAE (m)", lambda d: d["depth_mae_m"]),
    "within_1px": ("both within 1 px (%)", lambda d: 100 * d["fractions"]["both"]["within"]),
    "beyond_2deg": ("either beyond 2 deg (%)", lambda d: 100 * d["fractions"]["both"]["beyond"]),
    "vtest_mae": ("vergence test MAE (deg)", lambda d: d["vergence_test"]["degrees"]["mae"]),
    "vtest_rmse": ("vergence test RMSE (deg)", lambda d: d["vergence_test"]["degrees"]["rmse"]),
    # (evaluations written before the test kept its largest end read as nan)
    "vtest_max": ("vergence test largest end (deg)", lambda d: d["vergence_test"].get("max_abs_deg", math.nan)),
}


def stages(run: Path, name: str) -> dict[int, Path]:
    """The run's evaluations of set ``name`` by iteration."""
    found = {}
    for path in run.glob(f"{name}_*.json"):
        match = re.fullmatch(rf"{re.escape(name)}_(\d+)\.json", path.name)
        if match:
            found[int(match.group(1))] = path
    return found


def collect(groups: dict[str, list[Path]], sets: list[str]) -> dict:
    """``{set: {group: {iteration: {measure: {"mean", "sd", "runs"}}}}}`` over the stages every run reached."""
    out: dict = {}
    for name in sets:
        for group, runs in groups.items():
            per_run = [stages(run, name) for run in runs]
            common = sorted(set.intersection(*(set(s) for s in per_run))) if per_run else []
            for iteration in common:
                docs = []
                for run, found in zip(runs, per_run):
                    try:
                        docs.append(json.loads(found[iteration].read_text()))
                    except (OSError, ValueError) as err:
                        sys.exit(f"error: cannot read {found[iteration]}: {err}")
                row = {}
                for key, (_, read) in MEASURES.items():
                    values = [float(read(d)) for d in docs]
                    mean = sum(values) / len(values)
                    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else 0.0
                    row[key] = {"mean": mean, "sd": sd, "runs": values}
                out.setdefault(name, {}).setdefault(group, {})[iteration] = row
    return out


def table(results: dict) -> str:
    lines = []
    for name, groups in results.items():
        lines += [f"\n{name}:\n", "| group | iterations | " + " | ".join(label for label, _ in MEASURES.values()) + " |",
                  "|---|---|" + "---|" * len(MEASURES)]
        for group, rows in groups.items():
            for iteration, row in rows.items():
                cells = [f"{row[k]['mean']:.3f} ({row[k]['sd']:.3f})" if k not in ("within_1px", "beyond_2deg")
                         else f"{row[k]['mean']:.1f} ({row[k]['sd']:.1f})" for k in MEASURES]
                lines.append(f"| {group} | {iteration} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = list(results)
    fig, axes = plt.subplots(len(sets), 2, figsize=(10, 3.2 * len(sets)), squeeze=False)
    for row, name in enumerate(sets):
        for col, key in enumerate(("pursuit", "vergence")):
            ax = axes[row][col]
            for group, rows in results[name].items():
                its = list(rows)
                mean = [rows[i][key]["mean"] for i in its]
                sd = [rows[i][key]["sd"] for i in its]
                line, = ax.plot(its, mean, "o-", label=group)
                ax.fill_between(its, [m - s for m, s in zip(mean, sd)], [m + s for m, s in zip(mean, sd)],
                                color=line.get_color(), alpha=0.15)
            ax.set_xscale("log")
            ax.set_xlabel("iterations")
            ax.set_ylabel(MEASURES[key][0])
            ax.set_title(f"{name}: {key}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("groups", nargs="+", metavar="NAME=RUN,RUN,...")
    parser.add_argument("--sets", nargs="+", default=["choose"], help="evaluation set names (stages.py --eval)")
    parser.add_argument("--json", type=Path, help="write the numbers here")
    parser.add_argument("--plot", type=Path, help="draw the curves into this .png")
    args = parser.parse_args(argv)
    groups = {}
    for item in args.groups:
        name, _, runs = item.partition("=")
        if not name or not runs:
            parser.error(f"groups are NAME=RUN,RUN,..., got {item!r}")
        groups[name] = [Path(r) for r in runs.split(",")]
        for run in groups[name]:
            if not run.is_dir():
                parser.error(f"group {name}: no such run folder {str(run)!r}")
    results = collect(groups, args.sets)
    if not results:
        sys.exit(f"error: no evaluation of the sets {args.sets} that every run of a group reached")
    print(table(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    if args.plot:
        plot(results, args.plot)


if __name__ == "__main__":
    main()
