"""Depth from eye movements: `DepthMLP`, its Levenberg-Marquardt trainer and `DepthLearner` (the
replay buffer of trials and the fit cadence) (the paper's sec. 2.4)."""

from aectorch.depth.levenberg_marquardt import STOP_REASONS, LevenbergMarquardtResult, fit_levenberg_marquardt
from aectorch.depth.mlp import ACTIVATIONS, DepthMLP, mapminmax, mapminmax_reverse, nguyen_widrow_
from aectorch.depth.learner import MIN_DEPTH_TRIALS, DepthLearner

__all__ = [
    "ACTIVATIONS",
    "DepthLearner",
    "DepthMLP",
    "MIN_DEPTH_TRIALS",
    "LevenbergMarquardtResult",
    "STOP_REASONS",
    "fit_levenberg_marquardt",
    "mapminmax",
    "mapminmax_reverse",
    "nguyen_widrow_",
]
