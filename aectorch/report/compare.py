"""Runs side by side: groups of runs (``compare``), training curves (``curves``) and two
evaluations of the same trials (``trials``). Each returns what it prints; the plots are drawn on a
:class:`matplotlib.figure.Figure` never attached to pyplot.
"""

from __future__ import annotations

import os
import statistics
from pathlib import Path
from typing import Any, Mapping, Sequence

from aectorch.evaluation.summary import BEYOND_DEG, WITHIN_DEG
from aectorch.figures import save_figure
from aectorch.runs import Run, per_trial_rows, read_json

__all__ = ["DEFAULT_KEYS", "compare_groups", "compare_trials", "curves_table", "group_table", "plot_curves",
           "plot_groups", "trials_lines"]

#: The ``metrics.jsonl`` keys `curves_table` shows unless told.
DEFAULT_KEYS = ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m")


def _mean_sd(values):
    values = [v for v in values if v is not None]
    if not values:
        return None, None
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def _group_row(runs: Sequence[Run], evaluation: str) -> dict:
    cells: dict[str, list] = {}
    for run in runs:
        result, summary = run.evaluation(evaluation), run.summary
        both = result["fractions"]["both"]
        last = result.get("last5") or {}
        values = {"pursuit_mae_deg": result["pursuit_mae_deg"], "vergence_mae_deg": result["vergence_mae_deg"],
                  "depth_mae_m": result["depth_mae_m"], "within_1px": both["within"], "beyond_2deg": both["beyond"],
                  "last5_pursuit_deg": last.get("pursuit_mae_deg"), "last5_vergence_deg": last.get("vergence_mae_deg"),
                  "last5_within_1px": (last.get("fractions") or {}).get("both", {}).get("within"),
                  "train_s": summary.get("train_seconds"),
                  "window_pursuit_deg": summary["final"].get("pursuit_mae_deg"),
                  "window_vergence_deg": summary["final"].get("vergence_mae_deg")}
        for key, value in values.items():
            cells.setdefault(key, []).append(value)
    return {key: dict(zip(("mean", "sd"), _mean_sd(v)), runs=v) for key, v in cells.items()}


def compare_groups(groups: Mapping[str, Sequence[Run]], evaluations: Mapping[str, str]) -> dict:
    """``{set: {group: {key: {"mean", "sd", "runs"}}}}``: for every evaluation set (``set: file``
    in each run folder) and group of runs, the mean and sd over the runs of the final state's
    MAEs, the fractions on target and failed, the last 5 iterations' means, the training window
    at the end and the training seconds (the JSON that ``compare --json`` writes as ``table``)."""
    return {s: {name: _group_row(runs, file) for name, runs in groups.items()} for s, file in evaluations.items()}


def _last(r: dict) -> str:
    if r["last5_pursuit_deg"]["mean"] is None:
        return "n/a"
    return (f"{r['last5_pursuit_deg']['mean']:.3f} / {r['last5_vergence_deg']['mean']:.3f}, "
            f"{r['last5_within_1px']['mean']:.1%}")


def group_table(table: dict) -> list[str]:
    """`compare_groups`' result as markdown lines, one row per set and group."""
    head = (f"| set | runs | pursuit MAE (deg) | vergence MAE (deg) | depth MAE (m) | both within {WITHIN_DEG} deg | "
            f"either beyond {BEYOND_DEG:g} deg | last 5 iterations: pursuit / vergence (deg), within {WITHIN_DEG} deg | "
            "final window pursuit / vergence (deg) | training (s) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for s, rows in table.items():
        for name, r in rows.items():
            def f(key, digits=3):
                return f"{r[key]['mean']:.{digits}f} ({r[key]['sd']:.{digits}f})"
            lines.append(f"| {s} | {name} | {f('pursuit_mae_deg')} | {f('vergence_mae_deg')} | {f('depth_mae_m')} | "
                         f"{r['within_1px']['mean']:.1%} | {r['beyond_2deg']['mean']:.1%} | {_last(r)} | "
                         f"{r['window_pursuit_deg']['mean']:.3f} / {r['window_vergence_deg']['mean']:.3f} | "
                         f"{r['train_s']['mean']:.0f} ({r['train_s']['sd']:.0f}) |")
    return lines


def _common_curve(runs: Sequence[Run], key: str):
    series = [{i: line[key] for i, line in run.metrics_at.items() if line.get(key) is not None} for run in runs]
    common = sorted(set.intersection(*(set(s) for s in series)))
    return common, [[s[i] for s in series] for i in common]


def plot_groups(groups: Mapping[str, Sequence[Run]], path: str | os.PathLike) -> Path:
    """The training windows' pursuit and vergence MAE of each group over iterations (the mean of
    its runs, their range shaded), on a log scale."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for ax, key in zip(axes, ("pursuit_mae_deg", "vergence_mae_deg")):
        for name, runs in groups.items():
            x, values = _common_curve(runs, key)
            mean = [statistics.fmean(v) for v in values]
            line, = ax.plot(x, mean, label=f"{name} (mean of {len(runs)})")
            ax.fill_between(x, [min(v) for v in values], [max(v) for v in values], color=line.get_color(), alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("iteration")
        ax.set_title(f"training window {key.split('_')[0]} MAE", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("MAE (deg)")
    axes[0].legend()
    return save_figure(fig, path, dpi=110)


def curves_table(runs: Mapping[str, Run], keys: Sequence[str], first: int, last: int, every: int) -> list[str]:
    """The runs' ``metrics.jsonl`` side by side: a row per iteration from ``first`` to ``last``
    divisible by ``every``, a column per key and run (``-`` where a run has no line)."""
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    names = list(runs)
    header = ["iteration"] + [f"{key} {name}" for key in keys for name in names]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    iterations = sorted({i for run in runs.values() for i in run.metrics_at if first <= i <= last and i % every == 0})
    for i in iterations:
        cells = [str(i)]
        for key in keys:
            for name in names:
                value = runs[name].metrics_at.get(i, {}).get(key)
                cells.append("-" if value is None else f"{value:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def plot_curves(runs: Mapping[str, Run], keys: Sequence[str], first: int, last: int,
                path: str | os.PathLike) -> Path:
    """A panel per key with a curve per run, and each run's perturbation events
    (``summary.json``) as dotted lines."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 2.6 * len(keys)), layout="tight")
    axes = fig.subplots(len(keys), 1, sharex=True, squeeze=False)
    for ax, key in zip(axes[:, 0], keys):
        for name, run in runs.items():
            points = [(i, line[key]) for i, line in sorted(run.metrics_at.items())
                      if first <= i <= last and line.get(key) is not None]
            if points:
                ax.plot(*zip(*points), label=name)
        ax.set_ylabel(key)
        ax.grid(alpha=0.3)
    for name, run in runs.items():
        events = (run.summary.get("perturbation") or {}).get("events", []) if run.has("summary.json") else []
        for event in events:
            for ax in axes[:, 0]:
                ax.axvline(event["iteration"], color="grey", linestyle=":")
            axes[0, 0].annotate(f"{name}: {event['label']}", (event["iteration"], 1.0),
                                xycoords=("data", "axes fraction"), rotation=90, va="top",
                                ha="right", fontsize=7, color="grey")
    axes[0, 0].legend()
    axes[-1, 0].set_xlabel("learner iteration")
    return save_figure(fig, path, dpi=110)


def _trial_rows(path: str | os.PathLike) -> dict[tuple[str, float], dict]:
    rows = per_trial_rows(read_json(path), path)
    return {(r["texture"], round(r["distance_m"], 6)): r for r in rows}


def compare_trials(first: str | os.PathLike, second: str | os.PathLike, tolerance_deg: float) -> dict:
    """Agreement of two evaluations of the same trials (``per_trial`` rows matched by texture and
    distance), e.g. the torch renderer's and pyrender's: for pursuit and vergence, the fraction of
    fixation ends whose errors agree within ``tolerance_deg``, the largest difference and the
    trials that differ most; and the fraction of trials agreeing in both at both ends."""
    if not tolerance_deg >= 0:
        raise ValueError(f"--tolerance must be >= 0 degrees, got {tolerance_deg}")
    a, b = _trial_rows(first), _trial_rows(second)
    if set(a) != set(b):
        raise ValueError(f"the two evaluations hold different trials ({len(a)} and {len(b)}, "
                         f"{len(set(a) ^ set(b))} not in both)")
    out: dict[str, Any] = {"trials": len(a), "tolerance_deg": tolerance_deg}
    for cue in ("pursuit", "vergence"):
        diffs = sorted(((abs(x - y), key) for key in a
                        for x, y in zip(a[key][f"{cue}_errors_deg"], b[key][f"{cue}_errors_deg"])), reverse=True)
        out[cue] = {
            "agree": sum(d <= tolerance_deg for d, _ in diffs) / len(diffs),
            "max_difference_deg": diffs[0][0],
            "worst": [{"texture": k[0], "distance_m": k[1], "difference_deg": d} for d, k in diffs[:5]],
        }
    both = [all(abs(x - y) <= tolerance_deg for cue in ("pursuit", "vergence")
                for x, y in zip(a[k][f"{cue}_errors_deg"], b[k][f"{cue}_errors_deg"])) for k in a]
    out["both_agree_trials"] = sum(both) / len(both)
    return out


def trials_lines(result: dict) -> list[str]:
    """`compare_trials`' result as the lines ``trials`` prints."""
    lines = [f"{result['trials']} trials; errors agree within {result['tolerance_deg']} deg:"]
    for cue in ("pursuit", "vergence"):
        r = result[cue]
        worst = ", ".join(f"{w['texture']} {w['distance_m']} m ({w['difference_deg']:.3f})" for w in r["worst"][:3])
        lines.append(f"  {cue:9s} {r['agree']:.1%} of fixation ends; largest difference {r['max_difference_deg']:.3f} "
                     f"deg: {worst}")
    lines.append(f"  trials with both cues agreeing at both fixation ends: {result['both_agree_trials']:.1%}")
    return lines
