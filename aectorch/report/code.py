"""The learned code of groups of runs (``python -m aectorch.report code``): its read-outs as one
table (`code_table`, from each run's ``summary.json``) and one read-out's histograms side by side
(`plot_code_comparison`). One run's read-outs are drawn by `aectorch.figures.plot_code`, whose
panels and checks these share.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from aectorch.figures import COLORS, save_figure
from aectorch.figures import _READOUTS, _as_float, _check_code  # plot_code's read-outs, shared

__all__ = ["code_dictionaries", "code_table", "plot_code_comparison"]


def _code_numbers(readout: dict) -> tuple[float, float, float, float]:
    """The code table's four numbers of one dictionary's read-out."""
    disparity = readout["disparity"]
    near = sum(c for d, c in zip(disparity["disparities_px"], disparity["counts"]) if abs(d) <= 1)
    return (readout["binocularity"]["mean_abs_index"], near, disparity["mean_modulation"],
            readout["orientation"]["mean_selectivity"])


def _code_cell(values: list[float], start: list[float], digits: int) -> str:
    text = f"{sum(values) / len(values):.{digits}f}"
    if len(values) > 1:
        text += f" ({min(values):.{digits}f}-{max(values):.{digits}f})"
    return f"{text} [{sum(start) / len(start):.{digits}f}]"


def code_dictionaries(codes: dict[str, list[dict]], cue: str | None) -> list[str]:
    """The dictionaries of the groups' first run (those of ``cue`` only, when given)."""
    first = next(iter(codes.values()))[0]
    return [name for name in first if name != "initial" and (cue is None or name.split("/")[0] == cue)]


def code_table(codes: dict[str, list[dict]], cue: str | None = None) -> list[str]:
    """The learned code's read-outs of groups of runs (``summary.json``'s ``"code"``).

    Each group is ``label=run,run,...`` (the runs of one condition, e.g. its seeds) or one run
    folder (its own group, labelled by the folder's name). For every group and dictionary the
    table gives, as the mean over the group's runs (with the smallest and largest run when there
    are several), the trained code's mean absolute binocularity index, its atoms whose preferred
    disparity is within 1 px of zero, the tuning curves' mean depth of modulation and the mean
    orientation selectivity, each beside the same read-out of the runs' random start in brackets
    (`aectorch.coding.readouts.code_summary`; docs/sensory-coding.md). ``--plot`` draws one
    read-out's histograms of the groups side by side (`plot_code_comparison`).
    """
    rows = ["| group | dictionary | mean abs. binocularity index | atoms within 1 px of zero disparity | "
            "mean modulation | mean orientation selectivity |", "|---|---|---|---|---|---|"]
    for label, runs in codes.items():
        for name in code_dictionaries({label: runs}, cue):
            trained = [_code_numbers(run[name]) for run in runs]
            start = [_code_numbers(run["initial"][name] if "initial" in run else run[name]) for run in runs]
            cells = [_code_cell([t[i] for t in trained], [s[i] for s in start], digits)
                     for i, digits in enumerate((3, 0, 3, 3))]
            rows.append(f"| {label} ({len(runs)}) | {name} | " + " | ".join(cells) + " |")
    return rows


def plot_code_comparison(groups: Mapping[str, Sequence[Mapping[str, Mapping]]], path: str | os.PathLike, *,
                         dictionaries: Sequence[str] | None = None, readout: str = "binocularity") -> Path:
    """One read-out's histograms of several groups of runs side by side (e.g. rearing conditions).

    One panel per dictionary; in each, one bar per group and bin: the share of the atoms in that
    bin, the mean over the group's runs (seeds), with the smallest and largest run as an error
    bar. The legend gives each group's mean absolute binocularity index (over its runs).

    Args:
        groups: ``{label: [code, ...]}``, each code a run's ``{dictionary: code_summary}``
            (`aectorch.runs.Run.code`), e.g. ``{"normal": [seed 0, seed 1, seed 2], "monocular": [...]}``.
        path: the image file to write.
        dictionaries: the dictionaries to show (default: every one the first run holds, but
            ``"initial"``).
        readout: ``"binocularity"`` (default), ``"disparity"`` or ``"orientation"``.

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> import torch
        >>> from aectorch.coding.readouts import code_summary
        >>> def run(seed):
        ...     atoms = torch.randn(200, 32, generator=torch.Generator().manual_seed(seed))
        ...     return {"stereo/fine": code_summary(atoms)}
        >>> groups = {"normal": [run(0), run(1)], "other": [run(2)]}
        >>> plot_code_comparison(groups, Path(tempfile.mkdtemp()) / "compare.png").exists()
        True
    """
    parts = {part: (bins, label) for part, bins, label in _READOUTS}
    if readout not in parts:
        raise ValueError(f"readout must be one of {sorted(parts)}, got {readout!r}")
    if not isinstance(groups, Mapping) or not groups:
        raise ValueError("groups must map labels to non-empty lists of runs' code read-outs")
    for label, runs in groups.items():
        if isinstance(runs, (str, bytes, Mapping)) or not isinstance(runs, Sequence) or not runs:
            raise ValueError(f"groups[{label!r}] must be a non-empty list of runs' code read-outs")
        for i, run in enumerate(runs):
            _check_code({k: v for k, v in run.items() if k != "initial"}, f"groups[{label!r}][{i}]")
    first = next(iter(groups.values()))[0]
    names = [k for k in first if k != "initial"] if dictionaries is None else list(dictionaries)
    for label, runs in groups.items():
        for i, run in enumerate(runs):
            missing = [n for n in names if n not in run]
            if missing:
                raise ValueError(f"groups[{label!r}][{i}] has no read-outs of {missing} (has {sorted(run)})")
    bins, axis_label = parts[readout]
    from matplotlib.figure import Figure  # Agg renders it on savefig; pyplot is never used

    fig = Figure(figsize=(4.2 * len(names), 3.6))
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    width = 0.8 / len(groups)
    for ax, name in zip(axes, names):
        x = np.asarray(first[name][readout][bins], dtype=float)
        centres = (x[:-1] + x[1:]) / 2 if bins == "edges" else x
        step = centres[1] - centres[0] if len(centres) > 1 else 1.0
        for g, (label, runs) in enumerate(groups.items()):
            shares = np.array([np.asarray(run[name][readout]["counts"], dtype=float)
                               / max(1.0, float(np.sum(run[name][readout]["counts"]))) for run in runs])
            if shares.shape[1] != len(centres):
                raise ValueError(f"groups[{label!r}] has {shares.shape[1]} {readout} bins for {name!r}, the first "
                                 f"run {len(centres)}: read-outs with different bins cannot share a panel")
            mean = shares.mean(0)
            # The bars' reach down to the smallest run and up to the largest; equal runs can put
            # the float mean a rounding error outside them, which matplotlib refuses.
            spread = np.clip(np.stack([mean - shares.min(0), shares.max(0) - mean]), 0.0, None)
            index = np.mean([_as_float(run[name]["binocularity"].get("mean_abs_index")) for run in runs])
            runs_text = f"{len(runs)} run" + ("" if len(runs) == 1 else "s")
            ax.bar(centres + (g - (len(groups) - 1) / 2) * width * step, mean, width=width * step,
                   yerr=spread, capsize=2, color=COLORS[g % len(COLORS)],
                   label=f"{label} ({runs_text}; mean |index| {index:.2f})", error_kw={"linewidth": 0.8})
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(axis_label, fontsize=8)
        ax.set_ylabel("share of the atoms", fontsize=8)
        ax.legend(fontsize=7)
    fig.suptitle(f"The learned code's {readout}, by group (mean of the runs; bars: smallest to largest run)")
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.45 / fig.get_figheight()))  # (room for the suptitle)
    return save_figure(fig, path)
