"""The lineage's binocularity measure beside ours, on the same atoms of the rearing suite.

    PYTHONPATH=. .venv/bin/python experiments/rearing/gabor.py runs/rearing2a runs/rearing2b \
        --json experiments/rearing/gabor.json

For every run of the suite (`report.rearing_runs`, this folder's) and stereo dictionary, from the
run's final ``checkpoint.pt``: our index (`binocularity_index`, the halves' norms) and the
lineage's (`gabor_binocularity`: a 2-D Gabor fitted to the dominant half and shown to both,
Klimmasch et al. 2021; fits with a relative residual above 0.2 are not valid). Per condition and
dictionary, means over the seeds: the share of valid fits, and on the valid atoms the shares
dominated by each eye (|index| > 3/7) by either measure and the two measures' correlation.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from aectorch.coding.readouts import binocularity_index, gabor_binocularity  # noqa: E402
from report import DOMINANCE, rearing_runs  # noqa: E402  (this folder's report.py)
from aectorch.runtime import load_checkpoint  # noqa: E402

PREFIX = "cues.stereo.encoder.dictionaries."


def measures(atoms: torch.Tensor) -> dict[str, float]:
    """Both measures on one dictionary ``[P, N]``: the share of valid Gabor fits and, on the valid
    atoms, each measure's shares of left- and right-dominated atoms and their correlation."""
    ours = binocularity_index(atoms)
    lineage = gabor_binocularity(atoms)
    valid = lineage.valid
    out = {"valid": float(valid.float().mean()), "ours_left_all": float((ours < -DOMINANCE).float().mean()),
           "ours_right_all": float((ours > DOMINANCE).float().mean())}
    if int(valid.sum()) >= 2:
        a, b = ours[valid], lineage.binocularity[valid]
        out |= {"ours_left": float((a < -DOMINANCE).float().mean()), "ours_right": float((a > DOMINANCE).float().mean()),
                "gabor_left": float((b < -DOMINANCE).float().mean()),
                "gabor_right": float((b > DOMINANCE).float().mean()),
                "correlation": float(torch.corrcoef(torch.stack([a, b]))[0, 1])}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, nargs="+", help="the suite's sweep folders")
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    table: dict[str, dict[str, list[dict]]] = {}
    for condition, runs in rearing_runs(*args.folder).items():
        for run in runs:
            state = load_checkpoint(run.path / "checkpoint.pt")["learner"]
            for key in sorted(k for k in state if k.startswith(PREFIX) and k.endswith(".atoms")):
                scale = key[len(PREFIX):-len(".atoms")]
                table.setdefault(condition, {}).setdefault(scale, []).append(measures(state[key].double()))
    print("| condition | dictionary | valid Gabor fits % | on them, ours: left / right-dominated % | "
          "the lineage's: left / right-dominated % | correlation | ours on all atoms: left / right % |")
    print("|---|---|---|---|---|---|---|")

    def cell(rows, key, percent=True):
        values = [r[key] for r in rows if key in r]
        return "-" if not values else f"{statistics.fmean(values) * (100 if percent else 1):.{0 if percent else 2}f}"

    for condition, scales in table.items():
        for scale, rows in scales.items():
            print(f"| {condition} ({len(rows)}) | stereo/{scale} | {cell(rows, 'valid')} | {cell(rows, 'ours_left')} / "
                  f"{cell(rows, 'ours_right')} | {cell(rows, 'gabor_left')} / {cell(rows, 'gabor_right')} | "
                  f"{cell(rows, 'correlation', False)} | {cell(rows, 'ours_left_all')} / {cell(rows, 'ours_right_all')} |")
    if args.json is not None:
        args.json.write_text(json.dumps(table, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
