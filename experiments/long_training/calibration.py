"""Self-calibration: a run whose plant changed part-way against a run trained in the changed plant from its start.

    .venv/bin/python experiments/long_training/calibration.py \
        "roll 10 deg=runs/cal_roll10_s0:runs/calscratch_roll10_s0" ... --change 2400 [--cue stereo]
        [--json out.json [--update]] [--plot out.png]

Each ``LABEL=ADAPTED:SCRATCH`` pair: ADAPTED was trained in the unchanged plant to ``--change``, then on
in the changed one (``scripts/fork_run.py`` with a perturbation event at ``--change``); SCRATCH was
trained in the changed plant from iteration 0 for as many iterations as ADAPTED had after the change.
Read from each run's ``metrics.jsonl``: the short window (``train.recent_window``, the last 128
fixation ends) at each run's end, the ratio adapted / scratch for vergence and depth (the target: at
most 1.2), the iterations after the change until the adapted window, past its peak (the window
still holds fixations from before the change at first), comes within 1.2x of the scratch run's final
one (``-``: never), with ``--cue C`` how far the cue C's coding reward fell with the change (its mean
over the first 100 iterations after it against the 400 before) and the iterations after the change
until C, closed before it, learns again (``reopen_drop``), and pursuit's short window just before the change (the
adapted run's first window after it, the change's first 125 iterations) and at the end: whether the
movement the change does not act on stays where it was. ``--update`` keeps the other labels an
existing ``--json`` file holds (the pairs given replace theirs), so changes measured at different
times share one file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _rows(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except (OSError, ValueError) as err:
        sys.exit(f"error: cannot read {path}: {err}")


def _last(rows: list[dict], key: str, run: Path) -> float:
    values = [r[key] for r in rows if r.get(key) is not None]
    if not values:
        sys.exit(f"error: {run}/metrics.jsonl has no {key!r} (a run without a perturbation event logs no short window)")
    return float(values[-1])


def relearned(rows: list[dict], change: int, cue: str) -> int | None:
    """Iterations after ``change`` until ``cue`` learns again (the first logged window with its TD
    error; a closed cue logs none), ``None`` if it never does: when a closed cue reopened
    (``reopen_drop``), to the logging interval."""
    return next((r["iteration"] - change for r in rows
                 if r["iteration"] > change and r.get(f"{cue}/td_error") is not None), None)


def reward_fall(rows: list[dict], change: int, cue: str) -> float | None:
    """How far ``cue``'s coding reward fell with the change: its mean over the first 100 iterations
    after it against the 400 before, as a fraction of the latter's size (positive: a fall)."""
    before = [r[f"{cue}/reward"] for r in rows if change - 400 < r["iteration"] <= change and f"{cue}/reward" in r]
    after = [r[f"{cue}/reward"] for r in rows if change < r["iteration"] <= change + 100 and f"{cue}/reward" in r]
    if not before or not after:
        return None
    b, a = sum(before) / len(before), sum(after) / len(after)
    return (b - a) / abs(b)


def pair(adapted: Path, scratch: Path, change: int, cue: str | None = None) -> dict:
    a, s = _rows(adapted), _rows(scratch)
    out: dict = {} if cue is None else {"relearned_after": relearned(a, change, cue),
                                        "reward_fall": reward_fall(a, change, cue)}
    for movement, key in (("vergence", "vergence_recent_deg"), ("depth", "depth_recent_m"),
                          ("pursuit", "pursuit_recent_deg")):
        final_a, final_s = _last(a, key, adapted), _last(s, key, scratch)
        after = [r for r in a if r["iteration"] > change and r.get(key) is not None]
        # the window still holds fixations from before the change at first: count from its peak
        peak = max(range(len(after)), key=lambda i: after[i][key]) if after else 0
        within = next((r["iteration"] - change for r in after[peak:] if r[key] <= 1.2 * final_s), None)
        out[movement] = {"adapted": final_a, "scratch": final_s, "ratio": final_a / final_s if final_s else None,
                         "iterations_to_1.2x": within, "first_after_change": after[0][key] if after else None}
    return out


def plot(pairs: dict[str, tuple[Path, Path]], change: int, path: Path) -> None:
    """The adapted runs' short windows of vergence and depth against iterations after the change,
    one colour per change (the label before ", seed"), each scratch run's final window dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(dict.fromkeys(label.split(", seed")[0] for label in pairs))
    colours = {group: f"C{i}" for i, group in enumerate(groups)}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, (key, unit) in zip(axes, (("vergence_recent_deg", "vergence, last 128 ends (deg)"),
                                      ("depth_recent_m", "depth, last 128 ends (m)"))):
        for label, (adapted, scratch) in pairs.items():
            group = label.split(", seed")[0]
            rows = [r for r in _rows(adapted) if r["iteration"] > change and r.get(key) is not None]
            ax.plot([r["iteration"] - change for r in rows], [r[key] for r in rows], color=colours[group], lw=1,
                    label=group if label.startswith(group) and group not in ax.get_legend_handles_labels()[1] else None)
            ax.axhline(_last(_rows(scratch), key, scratch), color=colours[group], ls="--", lw=0.8)
        ax.set_xlabel("iterations after the change")
        ax.set_ylabel(unit)
        ax.set_yscale("log")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle("after the change (solid, one line per seed) against training in the changed plant from scratch "
                 "(dashed, its final window)", fontsize=9)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="+", metavar="LABEL=ADAPTED:SCRATCH")
    parser.add_argument("--change", type=int, required=True, help="the iteration of the adapted runs' change")
    parser.add_argument("--cue", default=None,
                        help="a cue closed before the change (learn_until): add how many iterations after the "
                             "change it learned again (reopen_drop), '-' if never")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path, default=None, help="draw the adapted runs' windows into this PNG")
    parser.add_argument("--update", action="store_true", help="keep the other labels of an existing --json file")
    args = parser.parse_args(argv)
    if args.update and not args.json:
        parser.error("--update needs --json FILE")
    results, runs_of = {}, {}
    for item in args.pairs:
        label, _, runs = item.partition("=")
        adapted, _, scratch = runs.partition(":")
        if not label or not adapted or not scratch:
            parser.error(f"pairs are LABEL=ADAPTED:SCRATCH, got {item!r}")
        for run in (adapted, scratch):
            if not Path(run, "metrics.jsonl").is_file():
                parser.error(f"{label}: {run!r} holds no metrics.jsonl")
        results[label] = pair(Path(adapted), Path(scratch), args.change, args.cue)
        runs_of[label] = (Path(adapted), Path(scratch))
    print("| change | vergence: adapted / scratch (deg) | ratio | iterations to 1.2x | depth: adapted / scratch (m) "
          "| ratio | iterations to 1.2x | pursuit: at the change / end / scratch (deg) |"
          + (f" {args.cue}'s reward falls (%) | {args.cue} learns again after (iterations) |" if args.cue else ""))
    print("|---|---|---|---|---|---|---|---|" + ("---|---|" if args.cue else ""))
    for label, r in results.items():
        v, d, p = r["vergence"], r["depth"], r["pursuit"]
        cell = lambda x: "-" if x is None else str(x)  # noqa: E731
        pct = lambda x: "-" if x is None else f"{100 * x:.1f}"  # noqa: E731
        print(f"| {label} | {v['adapted']:.3f} / {v['scratch']:.3f} | {v['ratio']:.2f} | {cell(v['iterations_to_1.2x'])} "
              f"| {d['adapted']:.3f} / {d['scratch']:.3f} | {d['ratio']:.2f} | {cell(d['iterations_to_1.2x'])} "
              f"| {p['first_after_change']:.3f} / {p['adapted']:.3f} / {p['scratch']:.3f} |"
              + (f" {pct(r['reward_fall'])} | {cell(r['relearned_after'])} |" if args.cue else ""))
    if args.plot:
        plot(runs_of, args.change, args.plot)
    if args.json:
        kept = {}
        if args.update and args.json.is_file():
            try:
                kept = json.loads(args.json.read_text())
            except ValueError as err:
                sys.exit(f"error: --update: cannot read {args.json}: {err}")
        args.json.write_text(json.dumps({**kept, **results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
