"""Tabulate (and plot) the learned code's read-outs of groups of runs (``summary.json``'s ``"code"``).

    .venv/bin/python scripts/code_table.py runs/code/default runs/code/seed1 runs/code/seed2 \
        [--cue stereo] [--plot out.png --readout binocularity]
    .venv/bin/python scripts/code_table.py normal=runs/normal_s0,runs/normal_s1 monocular=runs/mono_s0 --plot cmp.png

Each argument is a group ``label=folder,folder,...`` (the runs of one condition, e.g. its seeds) or
one folder (its own group, labelled by the folder's name). For every group and dictionary the table
gives, as the mean over the group's runs (with the smallest and largest run when there are several),
the trained code's mean absolute binocularity index, its atoms whose preferred disparity is within
1 px of zero, the tuning curves' mean depth of modulation and the mean orientation selectivity,
each beside the same read-out of the runs' random start in brackets
(:func:`aectorch.coding.readouts.code_summary`; docs/sensory-coding.md). ``--plot`` draws one
read-out's histograms of the groups side by side (:func:`aectorch.figures.plot_code_comparison`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _groups(arguments: list[str]) -> dict[str, list[Path]]:
    groups: dict[str, list[Path]] = {}
    for argument in arguments:
        label, _, folders = argument.rpartition("=") if "=" in argument else (Path(argument).name, "", argument)
        if not label or not folders:
            raise ValueError(f"a group must be label=folder[,folder...] or a folder, got {argument!r}")
        if label in groups:
            raise ValueError(f"group labels must be distinct, {label!r} is given twice")
        groups[label] = [Path(f) for f in folders.split(",") if f]
        if not groups[label]:
            raise ValueError(f"group {label!r} names no run folder")
    return groups


def _numbers(readout: dict) -> tuple[float, float, float, float]:
    """The table's four numbers of one dictionary's read-out."""
    disparity = readout["disparity"]
    near = sum(c for d, c in zip(disparity["disparities_px"], disparity["counts"]) if abs(d) <= 1)
    return (readout["binocularity"]["mean_abs_index"], near, disparity["mean_modulation"],
            readout["orientation"]["mean_selectivity"])


def _cell(values: list[float], start: list[float], digits: int) -> str:
    mean = sum(values) / len(values)
    text = f"{mean:.{digits}f}"
    if len(values) > 1:
        text += f" ({min(values):.{digits}f}-{max(values):.{digits}f})"
    return f"{text} [{sum(start) / len(start):.{digits}f}]"


def table(codes: dict[str, list[dict]], cue: str | None) -> str:
    rows = ["| group | dictionary | mean abs. binocularity index | atoms within 1 px of zero disparity | "
            "mean modulation | mean orientation selectivity |", "|---|---|---|---|---|---|"]
    for label, runs in codes.items():
        names = [n for n in runs[0] if n != "initial" and (cue is None or n.split("/")[0] == cue)]
        for name in names:
            trained = [_numbers(run[name]) for run in runs]
            start = [_numbers(run["initial"][name]) if "initial" in run else _numbers(run[name]) for run in runs]
            cells = [_cell([t[i] for t in trained], [s[i] for s in start], digits)
                     for i, digits in enumerate((3, 0, 3, 3))]
            rows.append(f"| {label} ({len(runs)}) | {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("groups", nargs="+", help="label=folder[,folder...] or a run folder")
    parser.add_argument("--cue", default=None, help="only this cue's dictionaries (e.g. stereo)")
    parser.add_argument("--plot", type=Path, default=None, help="draw one read-out's histograms side by side")
    parser.add_argument("--readout", default="binocularity", choices=("binocularity", "disparity", "orientation"))
    args = parser.parse_args(argv)
    from aectorch.figures import plot_code_comparison, read_code

    try:
        codes = {label: [read_code(folder) for folder in folders] for label, folders in _groups(args.groups).items()}
        print(table(codes, args.cue))
        if args.plot is not None:
            names = [n for n in next(iter(codes.values()))[0]
                     if n != "initial" and (args.cue is None or n.split("/")[0] == args.cue)]
            plot_code_comparison(codes, args.plot, dictionaries=names, readout=args.readout)
    except ValueError as err:
        print(f"code_table.py: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
