"""Self-calibration: a run whose plant changed part-way against a run trained in the changed plant from its start.

    .venv/bin/python experiments/long_training/calibration.py \
        "roll 10 deg=runs/cal_roll10_s0:runs/calscratch_roll10_s0" ... --change 2400 [--cue stereo]
        [--json out.json [--update]]

Each ``LABEL=ADAPTED:SCRATCH`` pair: ADAPTED was trained in the unchanged plant to ``--change``, then on
in the changed one (``scripts/fork_run.py`` with a perturbation event at ``--change``); SCRATCH was
trained in the changed plant from iteration 0 for as many iterations as ADAPTED had after the change.
Read from each run's ``metrics.jsonl``: the short window (``train.recent_window``, the last 128
fixation ends) at each run's end, the ratio adapted / scratch for vergence and depth (the target: at
most 1.2), the iterations after the change until the adapted window, past its peak (the window
still holds fixations from before the change at first), comes within 1.2x of the scratch run's final
one (``-``: never), with ``--cue C`` the iterations after the change until the cue C, closed
before it, learns again (``reopen_drop``), and pursuit's short window just before the change (the
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


def pair(adapted: Path, scratch: Path, change: int, cue: str | None = None) -> dict:
    a, s = _rows(adapted), _rows(scratch)
    out: dict = {} if cue is None else {"relearned_after": relearned(a, change, cue)}
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="+", metavar="LABEL=ADAPTED:SCRATCH")
    parser.add_argument("--change", type=int, required=True, help="the iteration of the adapted runs' change")
    parser.add_argument("--cue", default=None,
                        help="a cue closed before the change (learn_until): add how many iterations after the "
                             "change it learned again (reopen_drop), '-' if never")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--update", action="store_true", help="keep the other labels of an existing --json file")
    args = parser.parse_args(argv)
    if args.update and not args.json:
        parser.error("--update needs --json FILE")
    results = {}
    for item in args.pairs:
        label, _, runs = item.partition("=")
        adapted, _, scratch = runs.partition(":")
        if not label or not adapted or not scratch:
            parser.error(f"pairs are LABEL=ADAPTED:SCRATCH, got {item!r}")
        for run in (adapted, scratch):
            if not Path(run, "metrics.jsonl").is_file():
                parser.error(f"{label}: {run!r} holds no metrics.jsonl")
        results[label] = pair(Path(adapted), Path(scratch), args.change, args.cue)
    print("| change | vergence: adapted / scratch (deg) | ratio | iterations to 1.2x | depth: adapted / scratch (m) "
          "| ratio | iterations to 1.2x | pursuit: at the change / end / scratch (deg) |"
          + (f" {args.cue} learns again after (iterations) |" if args.cue else ""))
    print("|---|---|---|---|---|---|---|---|" + ("---|" if args.cue else ""))
    for label, r in results.items():
        v, d, p = r["vergence"], r["depth"], r["pursuit"]
        cell = lambda x: "-" if x is None else str(x)  # noqa: E731
        print(f"| {label} | {v['adapted']:.3f} / {v['scratch']:.3f} | {v['ratio']:.2f} | {cell(v['iterations_to_1.2x'])} "
              f"| {d['adapted']:.3f} / {d['scratch']:.3f} | {d['ratio']:.2f} | {cell(d['iterations_to_1.2x'])} "
              f"| {p['first_after_change']:.3f} / {p['adapted']:.3f} / {p['scratch']:.3f} |"
              + (f" {cell(r['relearned_after'])} |" if args.cue else ""))
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
