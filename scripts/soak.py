"""A soak run: the default training for many iterations, with resident memory logged alongside.

    .venv/bin/python scripts/soak.py runs/soak                    # 100,000 iterations, defaults
    .venv/bin/python scripts/soak.py runs/soak --iterations 200000  # longer (resumes if it can)
    .venv/bin/python scripts/soak.py runs/soak48k --iterations 48000 env.num_envs=8   # key=value overrides
    .venv/bin/python scripts/soak.py runs/soak_lifelong --iterations 48000 +experiment=lifelong  # a group's option

Runs `aectorch.runtime.run_experiment` with the default `ExperimentConfig` (the watchdog on,
in mode ``stop``), except ``train.iterations``, the ``key=value`` overrides given, no final
evaluation and figures only at the end. ``train.resume=auto``: if the folder already holds a
checkpoint the run is resumed, so a soak can be spread over several sessions (Ctrl-C or SIGTERM
leaves a checkpoint). Every ``--memory-every`` iterations the process's resident set (VmRSS) and
the run folder's size are appended to ``memory.jsonl`` in the run folder; ``--report`` prints a
summary of both logs (non-finite metrics, the ranges of the TD errors, errors and entropies, the
resident memory and its growth per 10k iterations for every process of the run, the growth after
the first tenth of the run, the folder's size, and the training window's errors over the run's
quarters);
``--plot <png>`` also draws the curves (errors, rewards, entropies, TD errors, resident memory).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


def _slope_per_10k(points: list[tuple[float, float]]) -> float:
    """Least-squares slope of (iteration, MB) points, in MB per 10,000 iterations."""
    if len(points) < 2:
        return math.nan
    mx = sum(x for x, _ in points) / len(points)
    my = sum(y for _, y in points) / len(points)
    var = sum((x - mx) ** 2 for x, _ in points)
    return sum((x - mx) * (y - my) for x, y in points) / var * 10_000 if var else math.nan


def processes(memory: list[dict], starts: list[float] = ()) -> list[list[dict]]:
    """The memory samples split by the process that took them: a sample belongs to the last
    process started (``starts``: the run's session start times, from ``provenance.json``) before
    its time; a new process is also where the iteration does not increase (a resume starts at its
    checkpoint)."""
    runs: list[list[dict]] = []
    owner = None
    for sample in memory:
        mine = sum(1 for t in starts if t <= sample["time"])
        previous = runs[-1][-1] if runs else None
        if previous is None or mine != owner or sample["iteration"] <= previous["iteration"]:
            runs.append([])
        owner = mine
        runs[-1].append(sample)
    return runs


def session_starts(run: Path) -> list[float]:
    """Start times (Unix seconds) of the run's sessions in ``provenance.json`` (none if absent)."""
    from datetime import datetime

    from aectorch.runs import Run

    folder = Run(run)
    if not folder.has("provenance.json"):
        return []
    sessions = folder.provenance.get("sessions", [])
    return [datetime.fromisoformat(s["started"]).timestamp() for s in sessions if s.get("started")]


def _range(lines: list[dict], key: str, since: int = 0) -> list[float] | None:
    values = [line[key] for line in lines if line["iteration"] >= since and isinstance(line.get(key), float)]
    return [min(values), max(values)] if values else None


def folder_mb(run: Path) -> float:
    """The run folder's size on disk (its files' sizes), MB."""
    return sum(p.stat().st_size for p in run.rglob("*") if p.is_file()) / 2**20


def _quarters(lines: list[dict], key: str) -> list[float | None]:
    """The mean of ``key`` over each quarter of the run's metrics lines (the learning curve, coarse)."""
    out = []
    for q in range(4):
        part = lines[q * len(lines) // 4:(q + 1) * len(lines) // 4]
        values = [line[key] for line in part if isinstance(line.get(key), float) and math.isfinite(line[key])]
        out.append(sum(values) / len(values) if values else None)
    return out


def report(run: Path, since: int = 10_000) -> dict:
    """Summary of a soak folder: iterations, non-finite metrics, the ranges of the health signals
    (over the whole run, and the errors and entropies from iteration ``since`` on), and the
    resident memory of every process with its least-squares growth."""
    from aectorch.runs import Run, read_metrics

    lines, memory = Run(run).metrics, read_metrics(run / "memory.jsonl")
    nonfinite = sum(1 for line in lines for k, v in line.items()
                    if k != "depth_mae_m" and isinstance(v, float) and not math.isfinite(v))
    nulls = sum(1 for line in lines for k, v in line.items() if v is None and k != "depth_mae_m")
    out = {"iterations": lines[-1]["iteration"] if lines else 0, "metrics_lines": len(lines),
           "nonfinite_values": nonfinite, "null_values_besides_early_depth": nulls,
           "td_error_range": {cue: _range(lines, f"{cue}/td_error") for cue in ("parallax", "stereo")},
           f"from_iteration_{since}": {key: _range(lines, key, since) for key in (
               "pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m", "parallax/entropy", "stereo/entropy")},
           "last": {key: lines[-1].get(key) for key in ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m")}
           if lines else {},
           "quarters": {key: _quarters(lines, key) for key in ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m")}}
    if memory:
        # Single samples jump by tens of MB when a depth refit's Jacobian workspace is held by the
        # allocator, and every process starts at its own level: slopes are per process.
        out["memory_by_process"] = [{
            "iterations": [part[0]["iteration"], part[-1]["iteration"]],
            "rss_min_max_mb": [min(m["rss_mb"] for m in part), max(m["rss_mb"] for m in part)],
            "growth_mb_per_10k": _slope_per_10k([(m["iteration"], m["rss_mb"]) for m in part]),
        } for part in processes(memory, session_starts(run))]
        # Growth after the first tenth: the last sample against the first one past a tenth of the run.
        tenth = memory[-1]["iteration"] / 10
        after = [m for m in memory if m["iteration"] >= tenth]
        if after:
            out["rss_growth_after_first_tenth_pct"] = 100 * (after[-1]["rss_mb"] / after[0]["rss_mb"] - 1)
        sized = [m for m in memory if "folder_mb" in m]
        if sized:
            out["folder_mb"] = {"after_first_tenth": next(m["folder_mb"] for m in sized if m["iteration"] >= tenth),
                                "end": sized[-1]["folder_mb"]}
    return out


def plot(run: Path, path: Path) -> None:
    """The soak's curves: eq. (9) errors and depth MAE, rewards, entropies, |TD error|, memory."""
    from matplotlib.figure import Figure

    from aectorch.runs import Run, read_metrics

    lines, memory = Run(run).metrics, read_metrics(run / "memory.jsonl")
    it = [line["iteration"] for line in lines]

    def series(key):
        return [math.nan if line.get(key) is None else line[key] for line in lines]

    fig = Figure(figsize=(13, 7), dpi=110)
    axes = fig.subplots(2, 3).ravel()
    panels = [
        ("eye errors (eq. 9, deg)", ["pursuit_mae_deg", "vergence_mae_deg"]),
        ("depth MAE (m, 1000-trial window)", ["depth_mae_m"]),
        ("coding reward", ["parallax/reward", "stereo/reward"]),
        ("policy entropy (nats)", ["parallax/entropy", "stereo/entropy"]),
        ("mean |TD error|", ["parallax/td_error", "stereo/td_error"]),
    ]
    for ax, (title, keys) in zip(axes, panels):
        for key in keys:
            ax.plot(it, series(key), label=key, lw=0.8)
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    ax = axes[-1]
    ax.plot([m["iteration"] for m in memory], [m["rss_mb"] for m in memory], lw=0.8)
    ax.set_title("resident memory (MB)", fontsize=10)
    ax.grid(alpha=0.3)
    for ax in axes:
        ax.set_xlabel("learner iteration", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def is_group(override: str) -> bool:
    """Whether ``override`` chooses a config group's option (``+experiment=lifelong``, ``preset=paper``)."""
    from aectorch.runtime.presets import GROUPS

    return override.lstrip("+").split("=", 1)[0] in GROUPS


def group_keys(overrides: list[str]) -> list[str]:
    """The dotted ``key=value`` overrides of the config groups chosen in ``overrides``, in order
    (``--iterations`` and the other ``key=value`` overrides are applied after them)."""
    from aectorch.runtime.presets import GROUPS

    keys = []
    for override in filter(is_group, overrides):
        group, option = override.lstrip("+").split("=", 1)
        if option not in GROUPS[group]:
            raise SystemExit(f"{override}: {group} has the options {sorted(GROUPS[group])}")
        keys += [f"{key}={json.dumps(value)}" for key, value in GROUPS[group][option].items()]
    return keys


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="the run folder (resumed when it holds a checkpoint)")
    parser.add_argument("--iterations", type=int, default=100_000)
    parser.add_argument("--memory-every", type=int, default=500)
    parser.add_argument("--report", action="store_true", help="only print the summary of the folder")
    parser.add_argument("--plot", type=Path, default=None, help="with --report: draw the curves into this PNG")
    parser.add_argument("overrides", nargs="*", help="key=value overrides of the config (e.g. env.num_envs=8)")
    args = parser.parse_intermixed_args()
    if args.report:
        print(json.dumps(report(args.run), indent=2))
        if args.plot is not None:
            plot(args.run, args.plot)
            print(f"wrote {args.plot}")
        return
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    from omegaconf import OmegaConf

    from aectorch.runtime.config import to_experiment_config
    from aectorch.runtime import run_experiment

    overrides = [*group_keys(args.overrides), f"train.iterations={args.iterations}", "eval.enabled=false",
                 "train.checkpoint_every=1000", "train.log_every=100", "train.resume=auto",
                 *(o for o in args.overrides if not is_group(o))]
    cfg = to_experiment_config(OmegaConf.from_dotlist(overrides))
    args.run.mkdir(parents=True, exist_ok=True)
    memory = (args.run / "memory.jsonl").open("a")

    def sample(done: int, record) -> None:
        if done % args.memory_every == 0:
            memory.write(json.dumps({"iteration": done, "rss_mb": rss_mb(), "folder_mb": folder_mb(args.run),
                                     "time": time.time()}) + "\n")
            memory.flush()

    try:
        run_experiment(cfg, args.run, callback=sample)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: run_experiment wrote the checkpoint
        print(f"the same command continues it: python scripts/soak.py {args.run}", file=sys.stderr)
        sys.exit(130)
    finally:
        memory.close()
    print(json.dumps(report(args.run), indent=2))


if __name__ == "__main__":
    main()
