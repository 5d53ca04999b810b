"""The rearing suite as one table and one figure: the rearing study's report.

    .venv/bin/python experiments/rearing/report.py runs/rearing2a runs/rearing2b ... [--scales fine full]
        [--cue stereo] [--plot rearing.png] [--curves curves.png]

The suite is ``python train.py -m seed=0,1,2 rearing=normal,monocular,...`` (README.md here, "The
suite"): one run folder per condition and seed. Each run's condition is read from its own
``config.yaml``: the run's ``perturbations`` are those of one of the conditions of
:data:`aectorch.runtime.presets.REARING`. Everything else comes from its ``summary.json``, through
`aectorch.runs.Run`: the learned code's read-outs (`aectorch.coding.readouts.code_summary`, per
dictionary), the evaluation (normal eyes, the final state), the final training window and the
read-outs of the correction (the corrected conditions' event ends: the vergence, and the code as
the perturbation left it, `aectorch.runtime.loop.Perturbations`), and the training time. A missing
file, an unfinished run or a bad argument prints one ``error:`` line and exits with status 2
(`aectorch.report.command.run_command`, as ``python -m aectorch.report`` does).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
from pathlib import Path
from typing import Mapping, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.figures import save_figure  # noqa: E402
from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.runs import Run  # noqa: E402
from aectorch.runtime.presets import REARING  # noqa: E402

__all__ = ["DOMINANCE", "LINEAGE_RESULTS", "THRESHOLDS", "code_numbers", "lineage_verdicts", "mean_disparity", "rearing_condition", "rearing_runs",
           "rearing_rows", "rearing_table", "plot_rearing", "plot_rearing_curves"]

#: An atom is dominated by one eye when its binocularity index is beyond this (Hubel and Wiesel's
#: ocular-dominance groups 1-2 and 6-7 of seven bins: |index| > 3/7).
DOMINANCE = 3 / 7
#: The orientation bins (their centres, deg: 0 horizontal stripes, 90 vertical) the orientation
#: columns report.
REARED_DEG = {"vertical": 90.0, "horizontal": 0.0}
_EVENT_FIELDS = ("kind", "start", "end", "eye", "params")


def _events(events: Sequence[Mapping]) -> list[tuple]:
    return [tuple(repr(event.get(key)) if key == "params" else event.get(key) for key in _EVENT_FIELDS)
            for event in events]


def rearing_condition(config: Mapping) -> str:
    """The rearing condition (a name of :data:`REARING`) whose events are a run config's
    ``perturbations``; a run without perturbations is ``normal``.

    Raises:
        ValueError: the perturbations are those of no condition (named in the message).

    Example:
        >>> rearing_condition({"perturbations": [{"kind": "strabismus", "start": 0, "eye": "right",
        ...                                       "params": {"deg": 10.0}, "label": None}]})
        'strabismus'
    """
    events = _events(config.get("perturbations") or [])
    for name, condition in REARING.items():
        if events == _events(condition):
            return name
    raise ValueError(f"perturbations {config.get('perturbations')!r} are those of no rearing condition "
                     f"({', '.join(REARING)})")


def rearing_runs(folder: str | os.PathLike, *more: str | os.PathLike) -> dict[str, list[Run]]:
    """The run folders of a suite (``folder`` and the folders in it that hold a ``summary.json``;
    and those of ``more`` sweep folders, e.g. conditions run later), by condition in
    :data:`REARING`'s order, each list by seed.

    Raises:
        FileNotFoundError: a folder holds no finished run.
        ValueError: two runs of the same condition and seed; a sweep job that has not finished
            (a run's files but no ``summary.json``), named.
    """
    groups: dict[str, list[Run]] = {}
    for folder in map(Path, (folder, *more)):
        if not folder.is_dir():
            raise FileNotFoundError(f"sweep folder {str(folder)!r}: no such folder")
        paths = [folder] if (folder / "summary.json").is_file() else sorted(
            p for p in folder.iterdir() if (p / "summary.json").is_file())
        if not paths:
            raise FileNotFoundError(f"{folder} holds no finished run (no */summary.json)")
        unfinished = sorted(p.name for p in folder.iterdir() if p.is_dir() and p not in paths
                            and any((p / name).exists() for name in ("checkpoint.pt", "metrics.jsonl", "config.yaml")))
        if unfinished and folder not in paths:
            raise ValueError(f"{folder} holds unfinished runs ({', '.join(unfinished)}: no summary.json), whose "
                             "conditions the table would miss: finish them (python train.py train.resume=<run>) "
                             "or move them out of the sweep folder")
        for run in map(Run, paths):
            group = groups.setdefault(rearing_condition(run.config), [])
            twin = [r for r in group if r.config.get("seed", 0) == run.config.get("seed", 0)]
            if twin:
                raise ValueError(f"{run.path} and {twin[0].path} are runs of the same condition and seed")
            group.append(run)
    return {name: sorted(groups[name], key=lambda r: r.config.get("seed", 0)) for name in REARING if name in groups}


def code_numbers(readout: Mapping) -> dict[str, float]:
    """One dictionary's read-out (`code_summary`) as the table's numbers: the mean absolute
    binocularity index, its signed mean from the histogram's bin centres (< 0: leaning to the left
    eye), the shares of the atoms dominated by the left and by the right eye
    (:data:`DOMINANCE`) and the shares preferring vertical and horizontal stripes (the orientation
    bins centred on :data:`REARED_DEG`).

    Example:
        >>> import torch
        >>> from aectorch.coding.readouts import code_summary
        >>> atoms = torch.randn(200, 8, generator=torch.Generator().manual_seed(0))
        >>> atoms[100:] = 0                      # the right halves: left-eye atoms only
        >>> numbers = code_numbers(code_summary(atoms))
        >>> numbers["mean_abs_index"], numbers["left"], numbers["right"]
        (1.0, 1.0, 0.0)
    """
    binocularity, orientation = readout["binocularity"], readout["orientation"]
    counts, edges = binocularity["counts"], binocularity["edges"]
    total = max(1, sum(counts))
    left = sum(c for c, high in zip(counts, edges[1:]) if high <= -DOMINANCE + 1e-6)
    right = sum(c for c, low in zip(counts, edges[:-1]) if low >= DOMINANCE - 1e-6)
    # The signed mean, from the bins' centres (the summary keeps the histogram, not each atom's index).
    signed = sum(c * (low + high) / 2 for c, low, high in zip(counts, edges[:-1], edges[1:])) / total
    out = {"mean_abs_index": float(binocularity["mean_abs_index"]), "mean_index": signed, "left": left / total,
           "right": right / total}
    o_counts, centres = orientation["counts"], orientation["centres_deg"]
    o_total = max(1, sum(o_counts))
    for name, deg in REARED_DEG.items():
        out[name] = sum(c for c, centre in zip(o_counts, centres) if abs(centre - deg) < 1e-6) / o_total
    return out


def _correction(summary: Mapping) -> dict | None:
    """The vergence read-out of an event's end (a correction), or None without one."""
    recovery = (summary.get("perturbation") or {}).get("recovery") or {}
    ends = [entry for label, entry in recovery.items() if label.endswith(" ends")]
    if not ends:
        return None
    vergence = ends[0]["vergence"]
    return {"iteration": ends[0]["iteration"], "before": vergence["before"], "final": vergence["final"],
            "iterations_to_recover": vergence["iterations_to_recover"]}


def _code_at_correction(summary: Mapping, cue: str) -> dict:
    """``cue``'s dictionaries' read-outs (`code_summary`) at the first event's end (a correction),
    ``{scale: readout}``; empty without one, or for a run from before these read-outs."""
    ends = [entry for label, entry in ((summary.get("perturbation") or {}).get("code") or {}).items()
            if label.endswith(" ends")]
    return {} if not ends else {k.split("/", 1)[1]: v for k, v in ends[0]["code"].items() if k.startswith(f"{cue}/")}


def mean_disparity(readout: Mapping) -> float:
    """The mean preferred disparity (pixels at the dictionary's scale) of one dictionary's atoms,
    from its read-out's histogram (`code_summary`'s ``disparity``); NaN without atoms."""
    disparity = readout["disparity"]
    total = sum(disparity["counts"])
    return sum(c * d for c, d in zip(disparity["counts"], disparity["disparities_px"])) / total if total else math.nan


#: The verdicts' thresholds: the lineage's strabismus (the issue's bar: at some scale at least
#: half the atoms dominated, at least 15 % by each eye); monocular deprivation (at some scale at
#: least half the atoms dominated by the open eye, at most 5 % by the closed one); normal rearing
#: (at every scale at most 10 % dominated); a shifted disparity preference (the mean preferred
#: disparity at least 1 px of the scale from normal rearing's); a lean (a signed mean index
#: beyond 0.05 towards the sharp eye); orientation rearing (the reared band's share at least
#: twice normal rearing's).
THRESHOLDS = {"strabismus_dominated": 0.5, "strabismus_each": 0.15, "monocular_open": 0.5, "monocular_closed": 0.05,
              "normal_dominated": 0.10, "disparity_shift_px": 1.0, "lean": 0.05, "orientation_ratio": 2.0}


def _means(rows: Sequence[dict], name: str, key: str = "code") -> dict[str, dict[str, float]]:
    """Per scale, the mean over ``name``'s runs of each :func:`code_numbers` value (``key``:
    ``code`` at the end, ``at_correction``); empty without such runs."""
    mine = [r[key] for r in rows if r["condition"] == name and r[key]]
    return {scale: {k: _mean([m[scale][k] for m in mine]) for k in mine[0][scale]} for scale in mine[0]} if mine else {}


def _judge_normal(rows: Sequence[dict]) -> tuple[str, bool]:
    code = _means(rows, "normal")
    worst = max(code, key=lambda s: code[s]["left"] + code[s]["right"])
    dominated = code[worst]["left"] + code[worst]["right"]
    return f"most dominated scale {worst}: {100 * dominated:.0f} % of atoms", dominated <= THRESHOLDS["normal_dominated"]


def _judge_monocular(rows: Sequence[dict]) -> tuple[str, bool]:
    code = _means(rows, "monocular")
    best = max(code, key=lambda s: code[s]["left"])
    c = code[best]
    return (f"{best}: {100 * c['left']:.0f} % dominated by the open (left) eye, {100 * c['right']:.0f} % by the closed",
            c["left"] >= THRESHOLDS["monocular_open"] and c["right"] <= THRESHOLDS["monocular_closed"])


def _judge_strabismus(rows: Sequence[dict]) -> tuple[str, bool]:
    code = _means(rows, "strabismus")
    best = max(code, key=lambda s: min(code[s]["left"], code[s]["right"]))
    c = code[best]
    return (f"{best}: {100 * (c['left'] + c['right']):.0f} % dominated ({100 * c['left']:.0f} % left, "
            f"{100 * c['right']:.0f} % right)", c["left"] + c["right"] >= THRESHOLDS["strabismus_dominated"]
            and min(c["left"], c["right"]) >= THRESHOLDS["strabismus_each"])


def _judge_small_strabismus(rows: Sequence[dict]) -> tuple[str, bool]:
    def disparity(name, scale):
        return _mean([mean_disparity(r["code_raw"][scale]) for r in rows if r["condition"] == name])

    shifts = {scale: disparity("strabismus_3deg", scale) - disparity("normal", scale) for scale in rows[0]["code_raw"]}
    best = max(shifts, key=lambda s: abs(shifts[s]))
    dominated = max(c["left"] + c["right"] for c in _means(rows, "strabismus_3deg").values())
    cells = ", ".join(f"{scale} {shift:+.2f}" for scale, shift in shifts.items())
    return (f"mean preferred disparity against normal rearing (px of the scale): {cells}; at most "
            f"{100 * dominated:.0f} % dominated",
            abs(shifts[best]) >= THRESHOLDS["disparity_shift_px"] and dominated < THRESHOLDS["strabismus_dominated"])


def _fine(code: Mapping[str, dict]) -> dict[str, dict]:
    """The fine and full dictionaries of ``code`` (all of them when it has neither)."""
    return {s: c for s, c in code.items() if s in ("fine", "full")} or dict(code)


def _judge_suppression(rows: Sequence[dict]) -> tuple[str, bool]:
    fine = _fine(_means(rows, "anisometropia_late", "at_correction"))
    cells = ", ".join(f"{s} {c['mean_index']:+.2f}" for s, c in fine.items())
    return (f"mean index while blurred (before the late correction): {cells}",
            min(c["mean_index"] for c in fine.values()) <= -THRESHOLDS["lean"])


def _judge_recovery(rows: Sequence[dict]) -> tuple[str, bool]:
    early = min(c["mean_index"] for c in _fine(_means(rows, "anisometropia_early")).values())
    late = min(c["mean_index"] for c in _fine(_means(rows, "anisometropia_late")).values())
    vergence = [_mean([r["vergence_eval"] for r in rows if r["condition"] == n])
                for n in ("normal", "anisometropia_early", "anisometropia_late")]
    return (f"mean index at the end, early / late: {early:+.2f} / {late:+.2f}; vergence MAE normal / early / late "
            f"{' / '.join(f'{v:.3f}' for v in vergence)} deg", early > -THRESHOLDS["lean"] and late <= -THRESHOLDS["lean"])


def _judge_orientation(rows: Sequence[dict]) -> tuple[str, bool]:
    normal, parts, agrees = _means(rows, "normal"), [], True
    for name in ("vertical", "horizontal"):
        code = _means(rows, name)
        ratio = max(code[s][name] / max(normal[s][name], 1e-9) for s in code)
        parts.append(f"{name}: up to {ratio:.1f}x normal's share")
        agrees &= ratio >= THRESHOLDS["orientation_ratio"]
    return "; ".join(parts), agrees


#: The lineage's results the suite checks: (result, source, the conditions it needs, its judge).
LINEAGE_RESULTS = (
    ("normal rearing: mostly binocular atoms", "Klimmasch et al. 2021, Fig. 4", ("normal",), _judge_normal),
    ("monocular deprivation: atoms dominated by the open eye", "Klimmasch et al. 2021, Fig. 4", ("monocular",),
     _judge_monocular),
    ("strabismus (10 deg): most atoms monocular, both eyes", "Klimmasch et al. 2021, Fig. 4", ("strabismus",),
     _judge_strabismus),
    ("strabismus (3 deg): a shifted disparity preference, not monocularity", "Klimmasch et al. 2021, Methods",
     ("strabismus_3deg", "normal"), _judge_small_strabismus),
    ("anisometropia: the blurred eye suppressed at the fine scales", "Eckmann et al. 2020; Klimmasch et al. 2021",
     ("anisometropia_late",), _judge_suppression),
    ("anisometropia: recovery if corrected early, not late", "Klimmasch et al. 2021",
     ("anisometropia_early", "anisometropia_late", "normal"), _judge_recovery),
    ("orientation rearing: preferences shift to the reared band", "Klimmasch et al. 2021",
     ("vertical", "horizontal", "normal"), _judge_orientation),
)


def lineage_verdicts(groups: Mapping[str, Sequence[Run]], cue: str = "stereo") -> list[dict]:
    """For each result of the AEC lineage the suite can check (:data:`LINEAGE_RESULTS`), whether
    the runs agree: ``{"result", "source", "numbers", "agrees"}`` (``agrees`` None and the numbers
    "not run" where a condition it needs did not run). Means over the seeds; the thresholds are
    :data:`THRESHOLDS`."""
    rows = rearing_rows(groups, cue)
    ran = {r["condition"] for r in rows}
    out = []
    for result, source, needs, judge in LINEAGE_RESULTS:
        numbers, agrees = judge(rows) if set(needs) <= ran else ("not run", None)
        out.append({"result": result, "source": source, "numbers": numbers, "agrees": agrees})
    return out


def _verdict_table(groups: Mapping[str, Sequence[Run]], cue: str) -> list[str]:
    lines = ["", "| the lineage's result | source | here (means over the seeds) | agrees |", "|---|---|---|---|"]
    for v in lineage_verdicts(groups, cue):
        mark = {True: "yes", False: "no", None: "-"}[v["agrees"]]
        lines.append(f"| {v['result']} | {v['source']} | {v['numbers']} | {mark} |")
    return lines


def rearing_rows(groups: Mapping[str, Sequence[Run]], cue: str = "stereo") -> list[dict]:
    """One row per run: its condition and seed, its training time, :func:`code_numbers` of each of
    ``cue``'s dictionaries (``"code"``, ``"initial"`` of its start and ``"at_correction"`` as the
    perturbation left it, where the run has a correction), the evaluation's and the final
    training window's vergence MAE and the correction's read-out (`_correction`)."""
    rows = []
    for name, runs in groups.items():
        for run in runs:
            summary = run.summary
            code = {k.split("/", 1)[1]: code_numbers(v) for k, v in run.code.items()
                    if k != "initial" and k.startswith(f"{cue}/")}
            initial = {k.split("/", 1)[1]: code_numbers(v) for k, v in run.code.get("initial", {}).items()
                       if k.startswith(f"{cue}/")}
            if not code:
                raise KeyError(f"{run.path / 'summary.json'} has no read-outs of the {cue!r} cue's dictionaries")
            at_correction = _code_at_correction(summary, cue)
            rows.append({"condition": name, "seed": run.config.get("seed"), "run": str(run.path),
                         "train_seconds": float(summary["train_seconds"]), "code": code, "initial": initial,
                         "code_raw": {k.split("/", 1)[1]: v for k, v in run.code.items() if k.startswith(f"{cue}/")},
                         "at_correction": {k: code_numbers(v) for k, v in at_correction.items()},
                         "at_correction_raw": at_correction,
                         "vergence_eval": (summary.get("evaluation") or {}).get("vergence_mae_deg"),
                         "vergence_window": summary["final"].get("vergence_mae_deg"),
                         "correction": _correction(summary)})
    return rows


def _mean(values: Sequence) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.fmean(values) if values else math.nan


def _cell(values: Sequence, spec: str = ".3f", percent: bool = False) -> str:
    values = [100 * v if percent else v for v in values if v is not None and math.isfinite(v)]
    if not values:
        return "-"
    text = format(statistics.fmean(values), spec)
    return text if len(values) == 1 else f"{text} ({format(min(values), spec)}-{format(max(values), spec)})"


def rearing_table(groups: Mapping[str, Sequence[Run]], cue: str = "stereo",
                  scales: Sequence[str] | None = None) -> list[str]:
    """The rearing suite's tables: per condition and ``cue`` dictionary (scale), the mean absolute
    binocularity index, its signed mean (from the bins), the shares of left- and right-dominated
    atoms (|index| > 3/7) and of atoms
    preferring vertical (90 deg) and horizontal (0 deg) stripes; then per condition the vergence
    MAE of the evaluation (normal eyes, the final state) and of the final training window, the
    correction's read-out (the short training window when the blurred eye is corrected, and at
    the end) and the training time; then, for the runs that read it, the code at the correction
    (as the perturbation left it) against the code at the end. Cells are means over the seeds
    (smallest-largest); the random start's mean index is in square brackets. Then
    :func:`lineage_verdicts`: each lineage result, the numbers that test it, and whether they agree.
    The last line is the suite's total training time (``summary.json``'s ``train_seconds`` summed over the runs).
    ``scales`` keeps only those dictionaries in the per-dictionary tables (default: all)."""
    rows = rearing_rows(groups, cue)
    known = {scale for r in rows for scale in r["code"]}
    if scales is not None and not set(scales) <= known:
        raise ValueError(f"scales: {sorted(set(scales) - known)} are not among the {cue!r} cue's "
                         f"dictionaries {sorted(known)}")
    keep = (lambda scale: True) if scales is None else (lambda scale: scale in scales)
    lines = ["| condition (runs) | dictionary | mean abs. binocularity index [start] | mean index | left-dominated % "
             "| right-dominated % | vertical % | horizontal % |", "|---|---|---|---|---|---|---|---|"]
    for name in groups:
        mine = [r for r in rows if r["condition"] == name]
        for scale in filter(keep, mine[0]["code"]):
            code = [r["code"][scale] for r in mine]
            start = _mean([r["initial"].get(scale, {}).get("mean_abs_index") for r in mine])
            lines.append(f"| {name} ({len(mine)}) | {cue}/{scale} | {_cell([c['mean_abs_index'] for c in code])} "
                         f"[{start:.3f}] | {_cell([c['mean_index'] for c in code], '+.2f')} | "
                         f"{_cell([c['left'] for c in code], '.0f', True)} | "
                         f"{_cell([c['right'] for c in code], '.0f', True)} | "
                         f"{_cell([c['vertical'] for c in code], '.0f', True)} | "
                         f"{_cell([c['horizontal'] for c in code], '.0f', True)} |")
    lines += ["", "| condition (runs) | vergence MAE, evaluation (deg) | final training window (deg) "
              "| correction: window at it -> at the end (deg) | training (s per run) |", "|---|---|---|---|---|"]
    for name in groups:
        mine = [r for r in rows if r["condition"] == name]
        fixes = [r["correction"] for r in mine if r["correction"] is not None]
        fix = "-" if not fixes else f"{_cell([f['before'] for f in fixes])} -> {_cell([f['final'] for f in fixes])}"
        lines.append(f"| {name} ({len(mine)}) | {_cell([r['vergence_eval'] for r in mine])} | "
                     f"{_cell([r['vergence_window'] for r in mine])} | {fix} | "
                     f"{_cell([r['train_seconds'] for r in mine], '.0f')} |")
    lines += _correction_code_table(rows, groups, cue, keep)
    lines += _verdict_table(groups, cue)
    total = sum(r["train_seconds"] for r in rows)
    lines += ["", f"suite: {len(rows)} runs, training {total / 60:.1f} min in all ({total:.0f} s; "
              f"summary.json's train_seconds summed)"]
    return lines


def _correction_code_table(rows: Sequence[dict], groups: Mapping, cue: str, keep=lambda scale: True) -> list[str]:
    """The code as the perturbation left it (read at the correction) against the code at the end,
    per condition with that read-out and ``cue`` dictionary; none without such a condition."""
    lines = []
    for name in groups:
        mine = [r for r in rows if r["condition"] == name and r["at_correction"]]
        for scale in filter(keep, mine[0]["at_correction"] if mine else []):
            before, after = [r["at_correction"][scale] for r in mine], [r["code"][scale] for r in mine]
            cells = [f"{_cell([c[key] for c in before], spec, percent)} -> "
                     f"{_cell([c[key] for c in after], spec, percent)}" for key, spec, percent in (("mean_abs_index", ".3f", False), ("mean_index", "+.2f", False),
                                                ("left", ".0f", True), ("right", ".0f", True))]
            lines.append(f"| {name} ({len(mine)}) | {cue}/{scale} | {' | '.join(cells)} |")
    if not lines:
        return []
    return ["", "| condition (runs) | dictionary | at the correction -> at the end: mean abs. binocularity index "
            "| mean index | left-dominated % | right-dominated % |", "|---|---|---|---|---|---|", *lines]


def plot_rearing(groups: Mapping[str, Sequence[Run]], path: str | os.PathLike, cue: str = "stereo") -> Path:
    """The rearing suite in one figure: per ``cue`` dictionary (row) and condition (column) the
    binocularity histogram (share of the atoms per bin, the mean over the seeds; bars: smallest
    to largest run; red outline: at the correction, where the runs read it), then the vergence
    MAE at the end (evaluation with normal eyes, and the final training window) per condition,
    and the short training window's vergence when the blurred eye is corrected and at the end."""
    rows = rearing_rows(groups, cue)
    names = list(groups)
    scales = list(rows[0]["code_raw"])
    fig = _figure(len(scales), len(names))
    grid = fig.add_gridspec(len(scales) + 1, len(names) * 2, height_ratios=[1] * len(scales) + [1.4])
    for i, scale in enumerate(scales):
        for j, name in enumerate(names):
            ax = fig.add_subplot(grid[i, 2 * j:2 * j + 2])
            _histogram(ax, [r for r in rows if r["condition"] == name], scale)
            if i == 0:
                ax.set_title(name, fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{cue}/{scale}\nshare of atoms", fontsize=8)
    _vergence_panel(fig.add_subplot(grid[len(scales), :len(names)]), rows, names)
    _correction_panel(fig.add_subplot(grid[len(scales), len(names):]), rows, names)
    fig.suptitle("Rearing: the binocularity index (R - L) / (R + L) of the learned code's atoms,\n"
                 "vergence at the end and after the correction")
    return save_figure(fig, path, dpi=100)


def _figure(rows: int, columns: int):
    from matplotlib.figure import Figure

    return Figure(figsize=(2.1 * columns + 1, 1.7 * rows + 3.2), layout="constrained")


def _histogram(ax, rows: Sequence[dict], scale: str) -> None:
    import numpy as np

    def shares_of(histograms):  # each histogram's share of the atoms per bin
        return np.array([np.asarray(e["counts"], float) / max(1.0, float(np.sum(e["counts"]))) for e in histograms])

    entries = [r["code_raw"][scale]["binocularity"] for r in rows]
    edges = np.asarray(entries[0]["edges"], dtype=float)
    shares = shares_of(entries)
    mean = shares.mean(0)
    ax.bar(edges[:-1], mean, width=np.diff(edges), align="edge", color="tab:blue", alpha=0.8,
           yerr=np.stack([mean - shares.min(0), shares.max(0) - mean]), error_kw={"linewidth": 0.7},
           ecolor="black")
    fixed = [r["at_correction_raw"][scale]["binocularity"] for r in rows if scale in r["at_correction_raw"]]
    if fixed:  # the code as the perturbation left it
        before = shares_of(fixed).mean(0)
        ax.stairs(before, edges, color="tab:red", linewidth=1.0, label="at the correction")
    ax.set_xlim(-1, 1)
    ax.set_ylim(0, 1.05)
    ax.tick_params(labelsize=6)
    ax.text(0.02, 0.95, f"|i| {statistics.fmean(e['mean_abs_index'] for e in entries):.2f}", fontsize=7,
            transform=ax.transAxes, va="top")


def _vergence_panel(ax, rows: Sequence[dict], names: Sequence[str]) -> None:
    for j, name in enumerate(names):
        mine = [r for r in rows if r["condition"] == name]
        for offset, key, color, label in ((-0.15, "vergence_eval", "tab:blue", "evaluation (normal eyes)"),
                                          (0.15, "vergence_window", "tab:orange", "final training window")):
            values = [r[key] for r in mine if r[key] is not None]
            ax.bar(j + offset, _mean(values), width=0.3, color=color, alpha=0.6, label=label if j == 0 else None)
            ax.plot([j + offset] * len(values), values, "k.", markersize=3)
    ax.set_xticks(range(len(names)), names, rotation=30, fontsize=7, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("vergence MAE (deg)", fontsize=8)
    ax.set_title("vergence at the end (dots: seeds)", fontsize=9)
    ax.legend(fontsize=7)


def _correction_panel(ax, rows: Sequence[dict], names: Sequence[str]) -> None:
    fixed = [name for name in names if any(r["correction"] for r in rows if r["condition"] == name)]
    for j, name in enumerate(fixed):
        mine = [r["correction"] for r in rows if r["condition"] == name and r["correction"]]
        for k, (key, color, label) in enumerate((("before", "tab:red", "at the correction"),
                                                 ("final", "tab:green", "at the end"))):
            values = [m[key] for m in mine if m[key] is not None]
            ax.bar(j + (k - 0.5) * 0.3, _mean(values), width=0.3, color=color, alpha=0.6,
                   label=label if j == 0 else None)
            ax.plot([j + (k - 0.5) * 0.3] * len(values), values, "k.", markersize=3)
    if not fixed:
        ax.text(0.5, 0.5, "no correction in these runs", ha="center", transform=ax.transAxes)
    ax.set_xticks(range(len(fixed)), fixed, fontsize=7)
    ax.set_ylabel("vergence, short training window (deg)", fontsize=8)
    ax.set_title("recovery after the correction (dots: seeds)", fontsize=9)
    if fixed:
        ax.legend(fontsize=7)


def plot_rearing_curves(groups: Mapping[str, Sequence[Run]], path: str | os.PathLike, cue: str = "stereo") -> Path:
    """The code's read-outs against training iterations (``train.readout_every``,
    `aectorch.runs.Run.code_readouts`): per ``cue`` dictionary (column) the share of the atoms
    dominated by one eye (|index| > 3/7; top) and the mean absolute binocularity index (bottom),
    one line per condition (the mean over its seeds). Whether a condition's code has converged
    by the end of the suite is read here.

    Raises:
        ValueError: no run of ``groups`` has read-outs (run the suite with ``train.readout_every``).
    """
    import numpy as np
    from matplotlib.figure import Figure

    curves: dict[str, dict[str, tuple[list, list, list]]] = {}
    for name, runs in groups.items():
        per_run = [run.code_readouts for run in runs]
        per_run = [lines for lines in per_run if lines]
        if not per_run:
            continue
        iterations = sorted(set.intersection(*({line["iteration"] for line in lines} for lines in per_run)))
        for scale in (k for k in per_run[0][0]["code"] if k.startswith(f"{cue}/")):
            dominated, index = [], []
            for it in iterations:
                numbers = [code_numbers(next(line for line in lines if line["iteration"] == it)["code"][scale])
                           for lines in per_run]
                dominated.append(np.mean([n["left"] + n["right"] for n in numbers]))
                index.append(np.mean([n["mean_abs_index"] for n in numbers]))
            curves.setdefault(scale, {})[name] = (iterations, dominated, index)
    if not curves:
        raise ValueError("no run of the suite has code read-outs (code_readouts.jsonl): run it with "
                         "train.readout_every=N")
    fig = Figure(figsize=(3.2 * len(curves) + 1, 5.4), layout="constrained")
    axes = fig.subplots(2, len(curves), squeeze=False, sharex=True)
    from matplotlib import colormaps

    palette = colormaps["tab20"]
    colour = {name: palette((2 * k) % 20 + (2 * k) // 20) for k, name in enumerate(groups)}  # one per condition
    for j, (scale, lines) in enumerate(curves.items()):
        for name, (iterations, dominated, index) in lines.items():
            style = {"label": name, "linewidth": 1.2, "color": colour[name]}
            axes[0, j].plot(iterations, 100 * np.asarray(dominated), **style)
            axes[1, j].plot(iterations, index, **style)
        axes[0, j].set_title(scale, fontsize=9)
        axes[1, j].set_xlabel("training iteration", fontsize=8)
    axes[0, 0].set_ylabel("atoms dominated by one eye (%)", fontsize=8)
    axes[1, 0].set_ylabel("mean |binocularity index|", fontsize=8)
    axes[0, -1].legend(fontsize=6)
    fig.suptitle("Rearing: the code read out during training (means over the seeds)")
    return save_figure(fig, path, dpi=100)


def _report(args) -> list[str]:
    groups = rearing_runs(*args.folder)
    lines = rearing_table(groups, args.cue, args.scales)
    if args.plot:
        lines.append(f"wrote {plot_rearing(groups, args.plot, args.cue)}")
    if args.curves:
        lines.append(f"wrote {plot_rearing_curves(groups, args.curves, args.cue)}")
    return lines


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `rearing_table`'s docstring."""
    out = study_parser("experiments/rearing/report.py", rearing_table, _report)
    out.add_argument("folder", type=Path, nargs="+",
                     help="the suite's sweep folders (python train.py -m ... hydra.sweep.dir=...)")
    out.add_argument("--cue", default="stereo", help="the cue whose dictionaries are read out (default: stereo)")
    out.add_argument("--scales", nargs="+", default=None,
                     help="only these dictionaries in the per-dictionary tables (e.g. fine full; default: all)")
    out.add_argument("--plot", type=Path, default=None, help="also draw the suite's figure into this PNG")
    out.add_argument("--curves", type=Path, default=None,
                     help="also draw the code's read-outs against iterations into this PNG (train.readout_every)")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the suite's tables (and draw its figures); 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
