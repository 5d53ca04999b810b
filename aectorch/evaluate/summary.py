"""Summaries of trial errors: MAE, RMSE, median, 4 x IQR, and the fractions on target and failed."""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

__all__ = ["BEYOND_DEG", "WITHIN_DEG", "fractions", "per_trial_rows", "summarise"]

#: An eye within this many degrees of its optimum counts as on target: one pixel (0.2226 deg/px).
WITHIN_DEG = 0.22
#: An eye farther than this from its optimum counts as failed.
BEYOND_DEG = 2.0


def fractions(pursuit_deg: Tensor, vergence_deg: Tensor) -> dict:
    """The fractions of fixation ends on target (``|error| <= WITHIN_DEG``) and failed
    (``|error| > BEYOND_DEG``), for pursuit, vergence and both together.

    Args:
        pursuit_deg, vergence_deg: signed errors of the same fixation ends, any equal shape.

    Example:
        >>> fractions(torch.tensor([0.1, 0.3, 3.0]), torch.tensor([0.0, 0.1, 0.1]))["both"]
        {'within': 0.3333333333333333, 'beyond': 0.3333333333333333}
    """
    p, v = pursuit_deg.detach().double().reshape(-1).cpu().abs(), vergence_deg.detach().double().reshape(-1).cpu().abs()
    if p.numel() == 0:
        return {key: {"within": math.nan, "beyond": math.nan} for key in ("pursuit", "vergence", "both")}
    return {
        "pursuit": {"within": float((p <= WITHIN_DEG).double().mean()), "beyond": float((p > BEYOND_DEG).double().mean())},
        "vergence": {"within": float((v <= WITHIN_DEG).double().mean()), "beyond": float((v > BEYOND_DEG).double().mean())},
        "both": {"within": float(((p <= WITHIN_DEG) & (v <= WITHIN_DEG)).double().mean()),
                 "beyond": float(((p > BEYOND_DEG) | (v > BEYOND_DEG)).double().mean())},
    }


def per_trial_rows(trials: dict[str, Tensor], names: Sequence[str]) -> list[dict]:
    """One JSON row per trial of :func:`run_trials`' output: its texture's name, distance and the
    signed errors of its final state (the end of its second, rightward fixation), plus both
    fixation ends' pursuit and vergence errors as ``[leftward, rightward]``."""
    rows = []
    for i in range(trials["distance_m"].numel()):
        p, v = trials["pursuit_deg"][i].tolist(), trials["vergence_deg"][i].tolist()
        depth = float(trials["depth_error_m"][i])
        rows.append({
            "texture": names[int(trials["texture_index"][i])],
            "distance_m": round(float(trials["distance_m"][i]), 6),
            "pursuit_error_deg": p[-1],
            "vergence_error_deg": v[-1],
            "depth_error_m": depth if math.isfinite(depth) else None,
            "pursuit_errors_deg": p,
            "vergence_errors_deg": v,
        })
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


