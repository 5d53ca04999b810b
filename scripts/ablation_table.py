"""One row per single run: the final state's errors on the test textures and the choosing photographs.

    .venv/bin/python scripts/ablation_table.py "NAC (old default)=runs/agents_nac_s0" \
        "PPO, mean read-out=runs/agents_ppo_s0:_mean" ... [--json out.json]

Each argument is ``label=run[:suffix]``: the run folder's ``final_textures<suffix>.json`` and
``final_choose<suffix>.json`` (``python -m aectorch.evaluate`` of its ``checkpoint.pt``, as
scripts/train_eval.sh writes them; the suffix names re-evaluations, e.g. with ``readout=mean``).
Prints a markdown table: pursuit / vergence / depth MAE, both eyes within 0.22 deg and either
beyond 2 deg, for each set, and the last-5 means' pursuit / vergence where recorded.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _cells(path: Path) -> list[str]:
    if not path.is_file():
        return ["n/a"] * 3
    r = json.loads(path.read_text())
    both = r["fractions"]["both"]
    last = r.get("last5")
    return [f"{r['pursuit_mae_deg']:.3f} / {r['vergence_mae_deg']:.3f} / {r['depth_mae_m']:.3f}",
            f"{both['within']:.1%} / {both['beyond']:.1%}",
            "n/a" if not last else f"{last['pursuit_mae_deg']:.3f} / {last['vergence_mae_deg']:.3f}"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="+", help="label=run[:suffix]")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    print("| run | textures: pursuit / vergence (deg) / depth (m) | within 1 px / beyond 2 deg | last 5 | "
          "photographs: pursuit / vergence / depth | within 1 px / beyond 2 deg | last 5 |")
    print("|---|---|---|---|---|---|---|")
    out = {}
    for row in args.rows:
        label, _, spec = row.rpartition("=")
        run, _, suffix = spec.partition(":")
        cells = [c for s in ("textures", "choose") for c in _cells(Path(run) / f"final_{s}{suffix}.json")]
        out[label] = {"run": run, "suffix": suffix, "cells": cells}
        print(f"| {label} | " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
