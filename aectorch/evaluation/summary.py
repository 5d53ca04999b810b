"""Summaries of trial errors: MAE, RMSE, median, 4 x IQR, and the fractions on target and failed."""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from aectorch.evaluation.views import VIEW_PREFIX

__all__ = ["BEYOND_DEG", "LAST_ITERATIONS", "LAST_SUFFIX", "WITHIN_DEG", "fractions", "movements", "per_trial_rows",
           "summarise"]

#: An eye within this many degrees of its optimum counts as on target: one pixel (0.2226 deg/px).
WITHIN_DEG = 0.22
#: An eye farther than this from its optimum counts as failed.
BEYOND_DEG = 2.0
#: Each fixation's last this many iterations' errors are averaged as well as its final state's
#: (``<movement>_last5_deg``): a fixation that ends in a limit cycle of one small action is a coin
#: toss between two states at its last iteration, and the mean is where it holds.
LAST_ITERATIONS = 5
#: The key suffix of those means in `aectorch.evaluation.run_trials`' output.
LAST_SUFFIX = f"_last{LAST_ITERATIONS}_deg"


def fractions(errors_deg: dict[str, Tensor]) -> dict:
    """The fractions of fixation ends on target (``|error| <= WITHIN_DEG``) and failed
    (``|error| > BEYOND_DEG``), for each eye movement and for all of them together (``"both"``:
    every movement on target, or any failed).

    Args:
        errors_deg: each movement's signed errors of the same fixation ends, any equal shape.

    Example:
        >>> fractions({"pursuit": torch.tensor([0.1, 0.3, 3.0]), "vergence": torch.tensor([0.0, 0.1, 0.1])})["both"]
        {'within': 0.3333333333333333, 'beyond': 0.3333333333333333}
    """
    errors = {m: e.detach().double().reshape(-1).cpu().abs() for m, e in errors_deg.items()}
    if not errors or next(iter(errors.values())).numel() == 0:
        return {key: {"within": math.nan, "beyond": math.nan} for key in (*errors_deg, "both")}
    out = {m: {"within": float((e <= WITHIN_DEG).double().mean()), "beyond": float((e > BEYOND_DEG).double().mean())}
           for m, e in errors.items()}
    within = torch.stack([e <= WITHIN_DEG for e in errors.values()]).all(0)
    beyond = torch.stack([e > BEYOND_DEG for e in errors.values()]).any(0)
    out["both"] = {"within": float(within.double().mean()), "beyond": float(beyond.double().mean())}
    return out


def movements(trials: dict[str, Tensor]) -> list[str]:
    """The eye movements of :func:`run_trials`' output (its ``<movement>_deg`` keys), in order."""
    return [key[: -len("_deg")] for key in trials
            if key.endswith("_deg") and key != "q_deg" and not key.endswith(LAST_SUFFIX)]


def per_trial_rows(trials: dict[str, Tensor], names: Sequence[str]) -> list[dict]:
    """One JSON row per trial of :func:`run_trials`' output: its texture's name, distance and each
    movement's signed error of its final state (the end of its second, rightward fixation,
    ``<movement>_error_deg``), plus both fixation ends' errors as ``[leftward, rightward]``
    (``<movement>_errors_deg``); and the same for the mean of each fixation's last 5 iterations
    (``<movement>_error_last5_deg``, ``<movement>_errors_last5_deg``) where the trials have it;
    and the texture statistics of the view at the trial's start (``view_contrast``,
    ``view_energy_<scale>``; `aectorch.evaluation.views`) where the trials have them."""
    rows = []
    moves = movements(trials)
    for i in range(trials["distance_m"].numel()):
        depth = float(trials["depth_error_m"][i])
        row = {"texture": names[int(trials["texture_index"][i])], "distance_m": round(float(trials["distance_m"][i]), 6)}
        ends = {m: trials[f"{m}_deg"][i].tolist() for m in moves}
        row.update({f"{m}_error_deg": e[-1] for m, e in ends.items()})
        lasts = {m: trials[m + LAST_SUFFIX][i].tolist() for m in moves if m + LAST_SUFFIX in trials}
        row.update({f"{m}_error{LAST_SUFFIX}": e[-1] for m, e in lasts.items()})
        row["depth_error_m"] = depth if math.isfinite(depth) else None
        row.update({f"{m}_errors_deg": e for m, e in ends.items()})
        row.update({f"{m}_errors{LAST_SUFFIX}": e for m, e in lasts.items()})
        row.update({key: float(value[i]) for key, value in trials.items() if key.startswith(VIEW_PREFIX)})
        rows.append(row)
    return rows


def summarise(errors: Tensor) -> dict:
    """Mean absolute error, median absolute error, RMSE, median, 4 x IQR and count of ``errors``."""
    e = errors.detach().double().reshape(-1).cpu()
    e = e[torch.isfinite(e)]
    if e.numel() == 0:
        return {"mae": math.nan, "median_abs": math.nan, "rmse": math.nan, "median": math.nan,
                "iqr4": math.nan, "n": 0}
    q1, q3 = torch.quantile(e, torch.tensor([0.25, 0.75], dtype=torch.float64)).tolist()
    return {
        "mae": float(e.abs().mean()),
        "median_abs": float(e.abs().median()),
        "rmse": float(e.square().mean().sqrt()),
        "median": float(e.median()),
        "iqr4": 4.0 * (q3 - q1),
        "n": int(e.numel()),
    }


