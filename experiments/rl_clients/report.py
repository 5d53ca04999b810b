"""The RL clients on ``aectorch/Vergence-v0`` beside the project's learner, as one table: the RL
clients study's report.

    .venv/bin/python experiments/rl_clients/report.py runs/rl [--own RUN...] [--default-set NAME]

The clients are the examples (``examples/sb3_vergence.py``, ``examples/torchrl_vergence.py``,
``examples/cleanrl_ppo_vergence.py``) run with ``--out``; README.md here says what they measured.
A missing folder or file, a damaged one or a bad argument prints one ``error:`` line and exits
with status 2 (`aectorch.report.command.run_command`, as ``python -m aectorch.report`` does).
"""

from __future__ import annotations

import argparse
import math
import re
import statistics
import sys
from collections import defaultdict
from pathlib import Path
from typing import Sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.evaluation.summary import WITHIN_DEG  # noqa: E402
from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.runs import Run, read_json  # noqa: E402

__all__ = ["main", "parser", "rl_table"]


def _rl_sets(result: dict, default_set: str) -> dict:
    """``{set: {"trained": ..., "random": ...}}`` of one example's result (older files: one set)."""
    if "eval" in result:
        return result["eval"]
    return {default_set: {"trained": result["trained"], "random": result["random"]}}


def rl_table(folder: Path, own: Sequence[Run] = (), default_set: str = "data/choose-photos") -> list[str]:
    """The RL clients on ``aectorch/Vergence-v0`` (``<client>_<reward>_s<seed>.json`` in ``folder``,
    written by ``examples/sb3_vergence.py``, ``examples/torchrl_vergence.py`` and
    ``examples/cleanrl_ppo_vergence.py`` with ``--out``) beside the project's learner (each of
    ``own``'s ``final_choose.json`` and ``final_textures.json``, and ``summary.json``): per client,
    reward and evaluation set, the mean over the seeds of the vergence MAE at fixation ends, the
    fraction on target, the random policy's error and the training seconds. The client
    ``sb3-activedepth`` (``examples/sb3_vergence.py --env aectorch/ActiveDepth-v0``) gets a table
    of its own, with both movements' errors beside a random policy's."""
    if not Path(folder).is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    rows: dict = defaultdict(lambda: defaultdict(list))
    depth_rows: dict = defaultdict(list)
    for path in sorted(Path(folder).glob("*_s[0-9]*.json")):
        match = re.fullmatch(r"(sb3|torchrl|cleanrl|sb3-activedepth)_(error|coding|improvement|scaled)_s(\d+)\.json",
                             path.name)
        if not match:
            continue
        result = read_json(path)
        if match[1] == "sb3-activedepth":
            for name, pair in _rl_sets(result, default_set).items():
                depth_rows[(match[2], name)].append((pair, result["train_s"]))
            continue
        client = {"sb3": "SB3 PPO", "torchrl": "TorchRL PPO", "cleanrl": "CleanRL-style PPO"}[match[1]]
        for name, pair in _rl_sets(result, default_set).items():
            cell = rows[(client, match[2], name)]
            cell["mae"].append(pair["trained"]["vergence_mae_deg"])
            cell["within"].append(pair["trained"]["within_0.22_deg"])  # (the examples' files name their threshold)
            cell["random"].append(pair["random"]["vergence_mae_deg"])
            cell["train_s"].append(result["train_s"])
    for run in own:
        for name, file in ((default_set, "final_choose.json"), ("test textures", "final_textures.json")):
            if not run.has(file):
                continue
            evaluation = run.evaluation(file)
            cell = rows[("aectorch NAC (vergence only)", "coding (improvement)", name)]
            cell["mae"].append(evaluation["vergence_mae_deg"])
            cell["within"].append(evaluation["fractions"]["vergence"]["within"])
            cell["random"].append(math.nan)
            cell["train_s"].append(run.summary["train_seconds"])
    lines = [f"| agent | reward | evaluated on | seeds | vergence MAE (deg) | within {WITHIN_DEG} deg | random policy (deg) "
             "| training (s) |", "|---|---|---|---|---|---|---|---|"]
    for (client, reward, name), cell in sorted(rows.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1])):
        mae = cell["mae"]
        sd = f" ({statistics.stdev(mae):.3f})" if len(mae) > 1 else ""
        per_seed = " / ".join(f"{v:.2f}" for v in mae)
        random = [v for v in cell["random"] if v == v]
        lines.append(f"| {client} | {reward} | {name} | {len(mae)} | {statistics.fmean(mae):.3f}{sd} [{per_seed}] | "
                     f"{statistics.fmean(cell['within']):.1%} | "
                     + (f"{statistics.fmean(random):.2f} |" if random else "- |")
                     + f" {statistics.fmean(cell['train_s']):.0f} |")
    return lines + (_active_depth_table(depth_rows) if depth_rows else [])


def _active_depth_table(depth_rows: dict) -> list[str]:
    """SB3's PPO on ``aectorch/ActiveDepth-v0``: both movements' mean |error|, beside random."""
    lines = ["", "| agent | reward | evaluated on | seeds | pursuit MAE (deg) | random | vergence MAE (deg) | random "
             "| training (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for (reward, name), runs in sorted(depth_rows.items()):
        cells = []
        for movement in ("pursuit", "vergence"):
            for policy in ("trained", "random"):
                values = [pair[policy][f"{movement}_mae_deg"] for pair, _ in runs]
                per_seed = " [" + " / ".join(f"{v:.2f}" for v in values) + "]" if policy == "trained" else ""
                cells.append(f"{statistics.fmean(values):.3f}{per_seed}")
        seconds = statistics.fmean(s for _, s in runs)
        lines.append(f"| SB3 PPO, MultiDiscrete | {reward} | {name} | {len(runs)} | {' | '.join(cells)} | {seconds:.0f} |")
    return lines


def _report(args) -> list[str]:
    return rl_table(args.folder, [Run(run) for run in args.own], args.default_set)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `rl_table`'s docstring."""
    out = study_parser("experiments/rl_clients/report.py", rl_table, _report)
    out.add_argument("folder", type=Path, help="the examples' result files")
    out.add_argument("--own", type=Path, nargs="*", default=[], help="the project's own runs")
    out.add_argument("--default-set", default="data/choose-photos",
                     help="the set of result files written before the examples evaluated several")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
