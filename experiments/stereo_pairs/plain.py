"""The plain-plane evaluation of groups of runs: one markdown row per group, mean over its runs.

    .venv/bin/python experiments/stereo_pairs/plain.py choose.json \
        default=runs/pairs_default_s0,runs/pairs_default_s1,runs/pairs_default_s2 \
        depth=runs/ds_s0,runs/ds_s1,runs/ds_s2

Each run folder holds the named evaluation (``python -m aectorch.evaluate checkpoint=... textures=...
out=<run>/<name>``). The columns: pursuit, vergence and depth MAE at the fixations' ends, the
fraction of trials with both eye movements within 0.22 deg (1 px), and the lineage's vergence test
(the optimum +-2 deg): its MAE and the fraction of its ends beyond 1 deg; each run's value in brackets.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from table import cell

COLUMNS = (("pursuit MAE (deg)", lambda r: r["pursuit_mae_deg"], 1.0, "{:.3f}"),
           ("vergence MAE (deg)", lambda r: r["vergence_mae_deg"], 1.0, "{:.3f}"),
           ("depth MAE (m)", lambda r: r["depth_mae_m"], 1.0, "{:.3f}"),
           ("within 1 px (%)", lambda r: r["fractions"]["both"]["within"], 100.0, "{:.1f}"),
           ("vergence test MAE (deg)", lambda r: r["vergence_test"]["degrees"]["mae"], 1.0, "{:.3f}"),
           ("vergence test beyond 1 deg (%)", lambda r: r["vergence_test"]["beyond_1deg"], 100.0, "{:.1f}"))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("name", help="the evaluation's file name in each run folder")
    parser.add_argument("groups", nargs="+", help="label=run,run,...")
    args = parser.parse_args(argv)
    print("| runs | " + " | ".join(c[0] for c in COLUMNS) + " |")
    print("|---|" + "---|" * len(COLUMNS))
    for group in args.groups:
        label, _, runs = group.partition("=")
        results = [json.loads((Path(run) / args.name).read_text()) for run in runs.split(",")]
        cells = [cell([get(r) for r in results], scale, form) for _, get, scale, form in COLUMNS]
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
