"""Depth from eye movements: `DepthMLP` and its Levenberg-Marquardt trainer (the paper's sec. 2.4)."""

from aectorch.depth.levenberg_marquardt import STOP_REASONS, LevenbergMarquardtResult, fit_levenberg_marquardt
from aectorch.depth.mlp import ACTIVATIONS, DepthMLP, mapminmax, mapminmax_reverse, nguyen_widrow_

__all__ = [
    "ACTIVATIONS",
    "DepthMLP",
    "LevenbergMarquardtResult",
    "STOP_REASONS",
    "fit_levenberg_marquardt",
    "mapminmax",
    "mapminmax_reverse",
    "nguyen_widrow_",
]
