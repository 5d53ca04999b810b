"""NAC against PPO (or any groups of runs): final-state accuracy, wall time and learning curves.

    .venv/bin/python scripts/compare_agents.py nac=runs/agents_nac_s0,runs/agents_nac_s1,runs/agents_nac_s2 \
        ppo=runs/agents_ppo_s0,runs/agents_ppo_s1,runs/agents_ppo_s2 \
        --evals textures=final_textures.json choose=final_choose.json \
        --json benchmarks/results/agents.json --plot docs/figures/nac_vs_ppo.png

For every group (``name=run,run,...``) and every evaluation file of its runs (``set=file``,
relative to each run folder: ``python -m aectorch.evaluate`` of the run's final ``checkpoint.pt``),
the mean over the runs (and the standard deviation) of the final state's MAEs,
the fraction of fixation ends with both eyes within 0.22 deg (1 px) and beyond 2 deg, and the
training window at the end; the training seconds come from ``summary.json``. Prints a markdown
table, writes the numbers as JSON, and plots the training windows' pursuit and vergence MAE of
each group over iterations (mean of the runs, the runs' range shaded).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def _mean_sd(values):
    values = [v for v in values if v is not None]
    if not values:
        return None, None
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def _row(runs: list[Path], evaluation: str) -> dict:
    cells: dict[str, list] = {}
    for run in runs:
        result = json.loads((run / evaluation).read_text())
        summary = json.loads((run / "summary.json").read_text())
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


def _last(r: dict) -> str:
    if r["last5_pursuit_deg"]["mean"] is None:
        return "n/a"
    return (f"{r['last5_pursuit_deg']['mean']:.3f} / {r['last5_vergence_deg']['mean']:.3f}, "
            f"{r['last5_within_1px']['mean']:.1%}")


def _curves(runs: list[Path], key: str):
    series = []
    for run in runs:
        lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
        series.append({line["iteration"]: line[key] for line in lines if line.get(key) is not None})
    common = sorted(set.intersection(*(set(s) for s in series)))
    return common, [[s[i] for s in series] for i in common]


def plot(groups: dict[str, list[Path]], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for ax, key in zip(axes, ("pursuit_mae_deg", "vergence_mae_deg")):
        for name, runs in groups.items():
            x, values = _curves(runs, key)
            mean = [statistics.fmean(v) for v in values]
            line, = ax.plot(x, mean, label=f"{name} (mean of {len(runs)})")
            ax.fill_between(x, [min(v) for v in values], [max(v) for v in values], color=line.get_color(), alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("iteration")
        ax.set_title(f"training window {key.split('_')[0]} MAE", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("MAE (deg)")
    axes[0].legend()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("groups", nargs="+", help="name=run,run,...")
    parser.add_argument("--evals", nargs="+", default=["textures=evaluation.json"], help="set=file in each run")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path)
    args = parser.parse_args(argv)
    groups = {g.split("=", 1)[0]: [Path(r) for r in g.split("=", 1)[1].split(",")] for g in args.groups}
    evals = dict(e.split("=", 1) for e in args.evals)
    table = {s: {name: _row(runs, file) for name, runs in groups.items()} for s, file in evals.items()}
    head = ("| set | runs | pursuit MAE (deg) | vergence MAE (deg) | depth MAE (m) | both within 0.22 deg | "
            "either beyond 2 deg | last 5 iterations: pursuit / vergence (deg), within 0.22 deg | "
            "final window pursuit / vergence (deg) | training (s) |")
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for s, rows in table.items():
        for name, r in rows.items():
            def f(key, scale=1.0, digits=3):
                return f"{r[key]['mean'] * scale:.{digits}f} ({r[key]['sd'] * scale:.{digits}f})"
            print(f"| {s} | {name} | {f('pursuit_mae_deg')} | {f('vergence_mae_deg')} | {f('depth_mae_m')} | "
                  f"{r['within_1px']['mean']:.1%} | {r['beyond_2deg']['mean']:.1%} | {_last(r)} | "
                  f"{r['window_pursuit_deg']['mean']:.3f} / {r['window_vergence_deg']['mean']:.3f} | "
                  f"{r['train_s']['mean']:.0f} ({r['train_s']['sd']:.0f}) |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"groups": {k: [str(r) for r in v] for k, v in groups.items()},
                                         "evals": evals, "table": table}, indent=1) + "\n")
    if args.plot:
        plot(groups, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
