"""The offset diagnostic of trained learners side by side (``python -m aectorch.report offsets``)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from torch import Tensor

from aectorch.evaluation import offset_summary, offset_sweep
from aectorch.figures import COLORS, save_figure
from aectorch.runs import read_json
from aectorch.sim import ActiveDepthEnv, TextureBank

__all__ = ["OFFSET_ROWS", "offset_measurement", "offsets_table", "plot_offsets", "read_measurement"]

#: The rows of `offsets_table`: `aectorch.evaluation.offset_summary`'s keys and what they say.
OFFSET_ROWS = {
    "reward_peak_abs_deg": "the reward's peak: mean distance from the optimum (deg)",
    "reward_peak_within_px": "reward peaks within 1 px",
    "reward_drop_at_0.1_deg": "the reward's mean drop 0.1 deg off the optimum",
    "expected_map_zero_crossing_deg": "zero crossing of the policy's mean increment (deg)",
    "greedy_zero_at_optimum": "greedy (argmax) increment 0 at the optimum",
    "limit_cycle_abs_deg": "where the argmax map settles (mean abs offset of its limit cycle, deg)",
    "mean_readout_limit_cycle_abs_deg": "where the mean read-out settles (deg)",
    "away_far_below": "the mean read-out steps away from the optimum, over 1 deg below it",
    "away_far_above": "the mean read-out steps away from the optimum, over 1 deg above it",
    "capture_below_deg": "capture range below the optimum: the mean read-out steps back from every offset up to (deg)",
    "capture_above_deg": "capture range above the optimum (deg)",
}
_FRACTIONS = ("reward_peak_within_px", "greedy_zero_at_optimum", "away_far_below", "away_far_above")
#: Rows left out when no learner has them (a sweep within +-1 deg reaches no offset beyond 1 deg).
_FAR_ROWS = ("away_far_below", "away_far_above", "capture_below_deg", "capture_above_deg")


def offset_measurement(checkpoint: str | Path, textures: str | Path | None,
                       distances_m: Sequence[float] = (1.0, 1.5, 2.0, 2.5, 3.0), *, step_deg: float = 0.02,
                       span_deg: float = 1.0, progress: bool = False, plot: Path | None = None) -> dict:
    """A checkpoint's offset diagnostic: `aectorch.evaluation.offset_sweep` of each cue it learns
    that steps an eye's pan (`ActiveDepthEnv.CUES`: parallax and stereo; the slip cue's velocity and
    the accommodation cue's focus are not swept) on ``textures`` (a folder of images; None: the 40
    test textures) at ``distances_m``, the eye -``span_deg`` to +``span_deg`` off the optimum in
    steps of about ``step_deg``, summarised by `offset_summary`; ``plot`` draws the sweeps
    (`plot_offsets`).
    Returns ``{"checkpoint", "textures", "cues": {cue: summary}}``, the JSON ``--json`` writes."""
    from aectorch.runtime import load_learner

    if not 0 < span_deg <= 45:
        raise ValueError(f"--span must be in (0, 45] degrees, got {span_deg}")
    if not 0 < step_deg <= span_deg:
        raise ValueError(f"--step must be in (0, span] = (0, {span_deg}] degrees, got {step_deg}")
    _, learner = load_learner(checkpoint)
    bank = TextureBank.default("test") if textures is None else TextureBank.from_folder(textures)
    count = round(span_deg / step_deg)
    offsets_deg = [round(-span_deg + span_deg * i / count, 6) for i in range(2 * count + 1)]
    sweeps = {cue: offset_sweep(learner, bank, cue=cue, offsets_deg=offsets_deg, distances_m=distances_m,
                                progress=progress) for cue in learner.cues if cue in ActiveDepthEnv.CUES}
    if plot is not None:
        plot_offsets(sweeps, plot)
    return {"checkpoint": str(checkpoint), "textures": str(textures) if textures is not None else "test textures",
            "cues": {cue: offset_summary(sweep) for cue, sweep in sweeps.items()}}


def _cell(value: float, key: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.1%}" if key in _FRACTIONS else f"{value:.3f}" if key != "reward_drop_at_0.1_deg" else f"{value:.4f}"


def offsets_table(measurements: Mapping[str, dict]) -> list[str]:
    """Where trained learners lose their precision: the offset diagnostic, a column per learner.

    Each learner is ``label=PATH``: a checkpoint, whose diagnostic is computed
    (`offset_measurement`: each cue's coding reward and greedy increment with its eye -1 to +1 deg,
    or ``--span``, off the optimum in 0.02 deg steps, the body at the end of its shift, the other
    movement at its optimum), or a JSON that ``--json`` wrote, read as stored. A row per number of
    `aectorch.evaluation.offset_summary` (those beyond 1 deg where some learner's sweep reaches
    there); a cell holds the cues' values, ``parallax / stereo``.
    """
    if not measurements:
        raise ValueError("offsets needs at least one label=checkpoint or label=measurement.json")
    cues = list(next(iter(measurements.values()))["cues"])
    for label, measurement in measurements.items():
        if list(measurement["cues"]) != cues:
            raise ValueError(f"the learners must learn the same cues, {label!r} has {list(measurement['cues'])}, "
                             f"the first {cues}")
    lines = [f"| cues: {' / '.join(cues)} | " + " | ".join(measurements) + " |", "|---|" + "---|" * len(measurements)]
    for key, text in OFFSET_ROWS.items():
        cells = [" / ".join(_cell(m["cues"][cue].get(key), key) for cue in cues) for m in measurements.values()]
        if key not in _FAR_ROWS or any(cell.strip(" /-") for cell in cells):
            lines.append(f"| {text} | " + " | ".join(cells) + " |")
    trials = {m["cues"][cues[0]]["trials"] for m in measurements.values()}
    sources = sorted({m["textures"] for m in measurements.values()})
    lines.append(f"({', '.join(map(str, sorted(trials)))} conditions of {', '.join(sources)})")
    return lines


def read_measurement(path: str | Path) -> dict:
    """An offset measurement that ``--json`` wrote."""
    data = read_json(path)
    if "cues" not in data:
        raise ValueError(f"{path} is not an offset measurement (no 'cues'; python -m aectorch.report offsets --json)")
    data.setdefault("textures", "?")
    return data


def plot_offsets(sweeps: Mapping[str, Mapping[str, Tensor]], path: str | os.PathLike) -> Path:
    """The offset diagnostic (:func:`aectorch.evaluation.offset_sweep`) of each cue: (top) the coding
    reward against the eye's offset from its optimum, relative to the reward at the optimum
    (median and quartiles over the trials); (bottom) the greedy increment (median and quartiles)
    and the policy's mean increment (mean), with the line that would reach the optimum in one step.

    Args:
        sweeps: ``{cue: sweep}``, each an `offset_sweep` result.
        path: the image file to write.

    Returns:
        The path written.
    """
    if not isinstance(sweeps, Mapping) or not sweeps:
        raise ValueError("sweeps must map cue names to offset_sweep results")
    from matplotlib.figure import Figure  # Agg renders it on savefig; pyplot is never used

    fig = Figure(figsize=(4.2 * len(sweeps), 6.0))
    axes = fig.subplots(2, len(sweeps), squeeze=False, sharex=True)
    for column, (cue, sweep) in enumerate(sweeps.items()):
        x = sweep["offsets_deg"].double().numpy()
        zero = int(np.abs(x).argmin())
        reward = sweep["reward"].double().numpy()
        relative = reward - reward[:, zero : zero + 1]
        q = np.percentile(relative, [25, 50, 75], axis=0)
        top, bottom = axes[0, column], axes[1, column]
        top.fill_between(x, q[0], q[2], color=COLORS[0], alpha=0.25, label="quartiles")
        top.plot(x, q[1], color=COLORS[0], label="median")
        top.axvline(0, color="k", lw=0.6)
        top.set_title(f"{cue}: reward - reward at the optimum", fontsize=9)
        top.legend(fontsize=7)
        greedy = np.percentile(sweep["increment_deg"].double().numpy(), [25, 50, 75], axis=0)
        bottom.fill_between(x, greedy[0], greedy[2], color=COLORS[1], alpha=0.25, label="greedy quartiles")
        bottom.plot(x, greedy[1], color=COLORS[1], label="greedy median")
        bottom.plot(x, sweep["expected_increment_deg"].double().numpy().mean(0), color=COLORS[2],
                    label="policy's mean increment")
        bottom.plot(x, -x, color="k", lw=0.6, ls="--", label="to the optimum")
        bottom.axhline(0, color="k", lw=0.6)
        bottom.set_xlabel("offset from the optimum (deg)")
        bottom.set_title(f"{cue}: increment taken there (deg)", fontsize=9)
        bottom.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)
