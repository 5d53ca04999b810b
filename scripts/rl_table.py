"""Tabulate the RL clients on ``aectorch/Vergence-v0`` beside the project's own learner.

    .venv/bin/python scripts/rl_table.py runs/rl --own runs/rl/own_s0 runs/rl/own_s1 runs/rl/own_s2

Reads ``<client>_<reward>_s<seed>.json`` (written by ``examples/sb3_vergence.py``,
``examples/torchrl_vergence.py`` and ``examples/cleanrl_ppo_vergence.py`` with ``--out``; the
client ``sb3-activedepth`` is ``examples/sb3_vergence.py --env aectorch/ActiveDepth-v0``, tabulated
apart with both movements' errors) and, for the project's own learner, each run's
``final_choose.json`` and ``final_textures.json`` (``python -m aectorch.evaluate`` on the
choosing photographs and on the 40 test textures) and ``summary.json``. Prints one markdown row per client, reward and evaluation set: the mean over the
seeds of the mean |vergence error| at fixation ends, the fraction within 0.22 deg, the random
policy's error on the same set, and the training seconds.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from collections import defaultdict
from pathlib import Path


def _sets(result: dict, default_set: str) -> dict:
    """``{set: {"trained": ..., "random": ...}}`` of one example's result (older files: one set)."""
    if "eval" in result:
        return result["eval"]
    return {default_set: {"trained": result["trained"], "random": result["random"]}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--own", type=Path, nargs="*", default=[])
    parser.add_argument("--default-set", default="data/choose-photos",
                        help="the set of result files written before the examples evaluated several")
    args = parser.parse_args(argv)
    rows: dict = defaultdict(lambda: defaultdict(list))
    depth_rows: dict = defaultdict(list)
    for path in sorted(args.folder.glob("*_s[0-9]*.json")):
        match = re.fullmatch(r"(sb3|torchrl|cleanrl|sb3-activedepth)_(error|coding|improvement|scaled)_s(\d+)\.json",
                             path.name)
        if not match:
            continue
        result = json.loads(path.read_text())
        if match[1] == "sb3-activedepth":
            for name, pair in _sets(result, args.default_set).items():
                depth_rows[(match[2], name)].append((pair, result["train_s"]))
            continue
        client = {"sb3": "SB3 PPO", "torchrl": "TorchRL PPO", "cleanrl": "CleanRL-style PPO"}[match[1]]
        for name, pair in _sets(result, args.default_set).items():
            cell = rows[(client, match[2], name)]
            cell["mae"].append(pair["trained"]["vergence_mae_deg"])
            cell["within"].append(pair["trained"]["within_0.22_deg"])
            cell["random"].append(pair["random"]["vergence_mae_deg"])
            cell["train_s"].append(result["train_s"])
            cell["seeds"].append(int(match[3]))
    for run in args.own:
        summary = json.loads((run / "summary.json").read_text())
        for name, file in ((args.default_set, "final_choose.json"), ("test textures", "final_textures.json")):
            if not (run / file).exists():
                continue
            evaluation = json.loads((run / file).read_text())
            cell = rows[("aectorch NAC (vergence only)", "coding (improvement)", name)]
            cell["mae"].append(evaluation["vergence_mae_deg"])
            cell["within"].append(evaluation["fractions"]["vergence"]["within"])
            cell["random"].append(float("nan"))
            cell["train_s"].append(summary["train_seconds"])
            cell["seeds"].append(len(cell["seeds"]))
    print("| agent | reward | evaluated on | seeds | vergence MAE (deg) | within 0.22 deg | random policy (deg) | training (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for (client, reward, name), cell in sorted(rows.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1])):
        mae = cell["mae"]
        sd = f" ({statistics.stdev(mae):.3f})" if len(mae) > 1 else ""
        per_seed = " / ".join(f"{v:.2f}" for v in mae)
        random = [v for v in cell["random"] if v == v]
        print(f"| {client} | {reward} | {name} | {len(mae)} | {statistics.fmean(mae):.3f}{sd} [{per_seed}] | "
              f"{statistics.fmean(cell['within']):.1%} | {statistics.fmean(random):.2f} |" if random else
              f"| {client} | {reward} | {name} | {len(mae)} | {statistics.fmean(mae):.3f}{sd} [{per_seed}] | "
              f"{statistics.fmean(cell['within']):.1%} | - |", end="")
        print(f" {statistics.fmean(cell['train_s']):.0f} |")
    if depth_rows:
        _print_active_depth(depth_rows)
    return 0


def _print_active_depth(depth_rows: dict) -> None:
    """SB3's PPO on ``aectorch/ActiveDepth-v0``: both movements' mean |error|, beside random."""
    print("\n| agent | reward | evaluated on | seeds | pursuit MAE (deg) | random | vergence MAE (deg) | random | training (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (reward, name), runs in sorted(depth_rows.items()):
        cells = []
        for movement in ("pursuit", "vergence"):
            for policy in ("trained", "random"):
                values = [pair[policy][f"{movement}_mae_deg"] for pair, _ in runs]
                per_seed = " [" + " / ".join(f"{v:.2f}" for v in values) + "]" if policy == "trained" else ""
                cells.append(f"{statistics.fmean(values):.3f}{per_seed}")
        seconds = statistics.fmean(s for _, s in runs)
        print(f"| SB3 PPO, MultiDiscrete | {reward} | {name} | {len(runs)} | {' | '.join(cells)} | {seconds:.0f} |")


if __name__ == "__main__":
    raise SystemExit(main())
