"""``python -m aectorch.report <command> ...``: tables and plots of finished runs (see ``--help``)."""

from __future__ import annotations

import argparse
import inspect
import json
import sys
from pathlib import Path
from typing import Sequence

from aectorch.report import code, compare, depth, matcher, offsets, tables
from aectorch.report.command import pairs, run_command, run_groups
from aectorch.runs import EVALUATION, Run
from aectorch.sim import DEFAULT_DISTANCES_M, DEFAULT_PROTOCOL

__all__ = ["main"]


def _write_json(path: Path | None, data, indent: int = 1) -> None:
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=indent) + "\n")


def _table(args) -> list[str]:
    return tables.results_table([Run(run) for run in args.runs], args.eval)


def _compare(args) -> list[str]:
    groups = run_groups(args.groups)
    evaluations = dict(pairs(args.evals, "--evals are set=file"))
    table = compare.compare_groups(groups, evaluations)
    _write_json(args.json, {"groups": {k: [str(r.path) for r in v] for k, v in groups.items()},
                            "evals": evaluations, "table": table})
    if args.plot:
        compare.plot_groups(groups, args.plot)
    return compare.group_table(table)


def _curves(args) -> list[str]:
    names = args.names or [run.name for run in args.runs]
    if len(names) != len(args.runs):
        raise ValueError(f"--names needs one name per run ({len(args.runs)}), got {len(names)}")
    if len(set(names)) != len(names):
        raise ValueError(f"--names must be distinct, got {names}")
    runs = {name: Run(run) for name, run in zip(names, args.runs)}
    last = args.last if args.last is not None else max(max(run.metrics_at, default=0) for run in runs.values())
    lines = compare.curves_table(runs, args.keys, args.first, last, args.every)
    if args.plot is not None:
        compare.plot_curves(runs, args.keys, args.first, last, args.plot)
        lines.append(f"wrote {args.plot}")
    return lines


def _band(args) -> list[str]:
    return [tables.band_line([Run(run) for run in args.runs], args.eval, args.low, args.high)]


def _trials(args) -> list[str]:
    result = compare.compare_trials(args.first, args.second, args.tolerance)
    _write_json(args.json, result, indent=2)
    return compare.trials_lines(result)


def _ablation(args) -> list[str]:
    lines, cells = tables.ablation_table(args.rows)
    _write_json(args.json, cells)
    return lines


def _code_groups(items: Sequence[str]) -> dict[str, list[Run]]:
    groups: dict[str, list[Run]] = {}
    for item in items:
        label, _, folders = item.rpartition("=") if "=" in item else (Path(item).name, "", item)
        if not label or not folders:
            raise ValueError(f"a group must be label=run[,run...] or a run folder, got {item!r}")
        if label in groups:
            raise ValueError(f"group labels must be distinct, {label!r} is given twice")
        groups[label] = [Run(folder) for folder in folders.split(",") if folder]
        if not groups[label]:
            raise ValueError(f"group {label!r} names no run folder")
    return groups


def _code(args) -> list[str]:
    codes = {label: [run.code for run in runs] for label, runs in _code_groups(args.groups).items()}
    lines = code.code_table(codes, args.cue)
    if args.plot is not None:
        code.plot_code_comparison(codes, args.plot, dictionaries=code.code_dictionaries(codes, args.cue),
                                  readout=args.readout)
        lines.append(f"wrote {args.plot}")
    return lines


def _threads(count: int) -> None:
    """The computing commands' torch threads (default 1: their batches are small, and a second
    thread on a busy machine costs more than it gives)."""
    import torch

    if count < 1:
        raise ValueError(f"--threads must be >= 1, got {count}")
    torch.set_num_threads(count)


def _matcher(args) -> list[str]:
    _threads(args.threads)
    results = matcher.matcher_table(args.textures, args.depths, free=args.free, renderer=args.renderer,
                                    progress=args.progress)
    _write_json(args.json, results)
    return matcher.matcher_rows(results)


def _offsets(args) -> list[str]:
    items = pairs(args.learners, "learners are label=checkpoint.pt or label=measurement.json")
    computed = [path for _, path in items if not path.endswith(".json")]
    if (args.json or args.plot) and (len(items) != 1 or not computed):
        raise ValueError("--json and --plot take one learner, label=checkpoint.pt")
    _threads(args.threads)
    measurements = {}
    for label, path in items:
        if path.endswith(".json"):
            measurements[label] = offsets.read_measurement(path)
        else:
            measurements[label] = offsets.offset_measurement(path, args.textures, args.depths, step_deg=args.step,
                                                             span_deg=args.span, progress=args.progress, plot=args.plot)
            _write_json(args.json, measurements[label])
    return offsets.offsets_table(measurements)


def _depth_readout(args) -> list[str]:
    _threads(args.threads)
    result = depth.depth_readout(args.checkpoint, args.photos, args.calibration, args.cache)
    _write_json(args.json, result)
    return depth.readout_lines(result)


def _depth_tolerance(args) -> list[str]:
    return depth.tolerance_lines(depth.tolerance_table(args.distances, depth_m=args.depth_m, shift_m=args.shift_m),
                                 args.depth_m)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m aectorch.report", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, metavar="command")

    def command(name, run, documented):
        # Each command's help is the docstring of the function that computes its numbers.
        doc = inspect.cleandoc(documented.__doc__)
        sub = commands.add_parser(name, help=doc.splitlines()[0], description=doc,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        sub.set_defaults(run=run)
        return sub

    sub = command("table", _table, tables.results_table)
    sub.add_argument("runs", nargs="+", type=Path, help="run folders")
    sub.add_argument("--eval", default=EVALUATION, help=f"evaluation file in each run folder (default: {EVALUATION})")

    sub = command("compare", _compare, compare.compare_groups)
    sub.add_argument("groups", nargs="+", help="name=run,run,...")
    sub.add_argument("--evals", nargs="+", default=[f"textures={EVALUATION}"], help="set=file in each run")
    sub.add_argument("--json", type=Path, help="also write the numbers here")
    sub.add_argument("--plot", type=Path, help="also draw each group's training curves into this PNG")

    sub = command("curves", _curves, compare.curves_table)
    sub.add_argument("runs", nargs="+", type=Path, help="run folders")
    sub.add_argument("--names", nargs="+", default=None, help="a label per run (default: folder names)")
    sub.add_argument("--keys", nargs="+", default=list(compare.DEFAULT_KEYS), help="metrics.jsonl keys")
    sub.add_argument("--from", dest="first", type=int, default=0, help="first iteration")
    sub.add_argument("--to", dest="last", type=int, default=None, help="last iteration")
    sub.add_argument("--every", type=int, default=100, help="show iterations divisible by this")
    sub.add_argument("--plot", type=Path, default=None, help="also draw the curves into this PNG")

    sub = command("band", _band, tables.band)
    sub.add_argument("runs", nargs="+", type=Path, help="run folders")
    sub.add_argument("--eval", default=EVALUATION, help=f"evaluation file in each run folder (default: {EVALUATION})")
    sub.add_argument("--low", type=float, required=True, help="nearest distance (m)")
    sub.add_argument("--high", type=float, required=True, help="farthest distance (m)")

    sub = command("trials", _trials, compare.compare_trials)
    sub.add_argument("first", type=Path, help="an evaluation (JSON with per_trial rows)")
    sub.add_argument("second", type=Path, help="another evaluation of the same trials")
    sub.add_argument("--tolerance", type=float, default=0.05, help="degrees (default 0.05)")
    sub.add_argument("--json", type=Path, default=None, help="also write the comparison here")

    sub = command("ablation", _ablation, tables.ablation_table)
    sub.add_argument("rows", nargs="+", help="label=run[:suffix]")
    sub.add_argument("--json", type=Path, help="also write the cells here")

    sub = command("code", _code, code.code_table)
    sub.add_argument("groups", nargs="+", help="label=run[,run...] or a run folder")
    sub.add_argument("--cue", default=None, help="only this cue's dictionaries (e.g. stereo)")
    sub.add_argument("--plot", type=Path, default=None, help="also draw one read-out's histograms side by side")
    sub.add_argument("--readout", default="binocularity", choices=("binocularity", "disparity", "orientation"))

    _diagnostic_commands(command)
    return parser


def _diagnostic_commands(command) -> None:
    """The commands that compute on checkpoints or the head's geometry: the classical matcher, the
    offset diagnostic and the depth read-outs."""
    sub = command("matcher", _matcher, matcher.matcher_table)
    sub.add_argument("--textures", default=None, help="a folder of images (default: the 40 test textures)")
    sub.add_argument("--depths", type=float, nargs="+", default=list(DEFAULT_DISTANCES_M), help="distances (m)")
    sub.add_argument("--free", action="store_true", help="also the unconstrained matcher")
    sub.add_argument("--renderer", default="torch", choices=("torch", "pyrender"))
    sub.add_argument("--json", type=Path, help="also write the evaluations here")
    sub.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    sub.add_argument("--progress", action="store_true", help="show a progress bar")

    sub = command("offsets", _offsets, offsets.offsets_table)
    sub.add_argument("learners", nargs="+", help="label=checkpoint.pt or label=measurement.json")
    sub.add_argument("--textures", default=None, help="a folder of images (default: the 40 test textures)")
    sub.add_argument("--depths", type=float, nargs="+", default=[1.0, 1.5, 2.0, 2.5, 3.0], help="distances (m)")
    sub.add_argument("--step", type=float, default=0.02, help="the offsets' step (deg; default 0.02; rounded to divide the span)")
    sub.add_argument("--span", type=float, default=1.0, help="the offsets reach -span to +span (deg; default 1)")
    sub.add_argument("--json", type=Path, help="write the one learner's measurement here")
    sub.add_argument("--plot", type=Path, help="draw the one learner's sweeps into this PNG")
    sub.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    sub.add_argument("--progress", action="store_true", help="show a progress bar")

    sub = command("depth-readout", _depth_readout, depth.depth_readout)
    sub.add_argument("checkpoint", type=Path, help="a run's checkpoint (best.pt or checkpoint.pt)")
    sub.add_argument("--photos", default=None, help="also run on this folder of images")
    sub.add_argument("--calibration", type=int, nargs="*", default=[], help="calibration trial counts (each >= 10)")
    sub.add_argument("--cache", type=Path, default=None, help="keep the trials in this file (and reuse it)")
    sub.add_argument("--json", type=Path, help="also write the result here")
    sub.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")

    sub = command("depth-tolerance", _depth_tolerance, depth.tolerance_table)
    sub.add_argument("--distances", type=float, nargs="+", default=[1.0, 1.5, 2.0, 2.5, 3.0], help="metres")
    sub.add_argument("--depth-m", type=float, default=0.05, help="the depth error (m; default 0.05)")
    sub.add_argument("--shift-m", type=float, default=DEFAULT_PROTOCOL.shift_m,
                     help=f"the body's shift (m; default {DEFAULT_PROTOCOL.shift_m:g})")


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; a missing file, a bad file or a bad argument prints one ``error:`` line
    and exits with status 2 (``AECTORCH_DEBUG=1`` shows the traceback)."""
    return run_command(_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
