"""The stereo pairs' visible fixation points by group of runs: one markdown row per group, pixel
scale and start, the mean over the group's runs (each run's value in brackets).

    .venv/bin/python experiments/stereo_pairs/visible.py \
        default=runs/pairs_default_s0,runs/pairs_default_s1,runs/pairs_default_s2 \
        fovea=runs/fov12_s0,runs/fov12_s1,runs/fov12_s2

Each run folder holds ``pairs_ps<k>.json`` (``python -m aectorch.evaluate pairs=... pair_scale=k``)
made with the occlusion test (its summaries have a ``visible`` part). The columns: how many of the
fixation points are visible, the learner's median |error| (eye pixels) and fraction beyond 5 px
over the visible fixation points, the same over all of them, and the matcher's over the visible
ones (the matcher does not depend on the run).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from table import STARTS, cell, evaluations


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("groups", nargs="+", help="label=run,run,...")
    args = parser.parse_args(argv)
    head = ["runs", "pixel scale", "start", "visible points", "visible: median (px)", "visible: beyond 5 px (%)",
            "all: median (px)", "all: beyond 5 px (%)", "matcher, visible: median (px)", "matcher, visible: beyond 5 px (%)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group in args.groups:
        label, _, runs = group.partition("=")
        found = evaluations([Path(run) for run in runs.split(",")])
        if not found or any("visible" not in r["summary"]["learner"][STARTS[0]] for rs in found.values() for r in rs):
            print(f"error: {label}: every run needs pairs_ps<k>.json with visible points (evaluate again)",
                  file=sys.stderr)
            return 2
        for scale, results in found.items():
            for start in STARTS:
                learner = [r["summary"]["learner"][start] for r in results]
                matcher = [r["summary"]["matcher"][start]["visible"] for r in results]
                shown = f"{learner[0]['visible']['n']} of {learner[0]['all']['n']}"
                cells = [label, str(scale), start.replace("_", " "), shown,
                         cell([s["visible"]["median_abs_px"] for s in learner], 1.0, "{:.2f}"),
                         cell([s["visible"]["beyond_5px"] for s in learner], 100.0, "{:.1f}"),
                         cell([s["all"]["median_abs_px"] for s in learner], 1.0, "{:.2f}"),
                         cell([s["all"]["beyond_5px"] for s in learner], 100.0, "{:.1f}"),
                         cell([m["median_abs_px"] for m in matcher], 1.0, "{:.2f}"),
                         cell([m["beyond_5px"] for m in matcher], 100.0, "{:.1f}")]
                lines.append("| " + " | ".join(cells) + " |")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
