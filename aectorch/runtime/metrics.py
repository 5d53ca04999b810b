"""Streaming training metrics over :class:`~aectorch.framework.IterationRecord` s.

:class:`TrainingMetrics` turns the records of `JointLearner.iteration` into the flat,
JSON-ready numbers that ``metrics.jsonl``, TensorBoard and the figures use. Its keys are a
contract with `aectorch.figures`:

- ``pursuit_mae_deg``, ``vergence_mae_deg``: the paper's eq. (9), the mean absolute error of
  the left (pursuit) and right (vergence) pan at the last iteration of each fixation, over the
  last ``window_fixations`` fixation ends (each environment's fixation counts as one);
- ``depth_mae_m``: mean ``|depth_prediction_m - distance_m|`` over the last ``window_trials``
  trials with a prediction (not NaN): the depth MLP's estimate made before the trial joined its
  training data, so an honest online error (the paper's Fig. 3b moving average);
- per cue ``c`` in ``parallax``, ``stereo``, averaged over the iterations since the previous
  summary: ``c/reward`` (mean R), ``c/entropy`` (mean policy entropy, nats), ``c/td_error``
  (mean |TD error| of the iterations that learned; NaN if none did), and per scale ``s``:
  ``c/s/error`` (mean reconstruction error) and ``c/s/atom_usage`` (the perplexity
  ``exp(H(p))`` of the atom-selection distribution ``p`` accumulated since the previous summary,
  divided by the number of atoms: 1 = every atom chosen equally often, 1/N = one atom only).

Values not yet defined (no fixation ended, no iteration since the last summary) are NaN.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from aectorch._checks import check_int
from aectorch.choices import Cue
from aectorch.coding.patches import DEFAULT_SCALES

__all__ = ["CUES", "TrainingMetrics"]

#: The learner's cues, in the order the metrics report them.
CUES = Cue.values()


def _mean(total: float, count: int) -> float:
    return total / count if count else math.nan


class TrainingMetrics:
    """Moving-window task errors and per-interval learning statistics.

    Args:
        num_envs: environments B of the records (checked).
        window_fixations: fixation ends the pursuit and vergence errors average over (>= 1).
        window_trials: predicted trials the depth error averages over (>= 1).
        scales: the learner's scales, in the order of ``CueRecord.errors``' columns (default
            ``JointLearner``'s, :data:`aectorch.coding.patches.DEFAULT_SCALES`).

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> from aectorch.sim import ActiveDepthEnv
        >>> env = ActiveDepthEnv(2, textures=torch.rand(3, 64, 64), fixation_iterations=1, seed=0)
        >>> learner = JointLearner(LearnerConfig(num_atoms=16), generator=torch.Generator().manual_seed(0))
        >>> metrics = TrainingMetrics(2)
        >>> metrics.update(learner.iteration(env))
        >>> summary = metrics.summary()
        >>> summary["pursuit_mae_deg"] >= 0, 0 < summary["stereo/fine/atom_usage"] <= 1
        (True, True)
    """

    def __init__(
        self,
        num_envs: int,
        window_fixations: int = 1000,
        window_trials: int = 1000,
        *,
        scales: Sequence[str] = DEFAULT_SCALES,
    ) -> None:
        for name, value in (("num_envs", num_envs), ("window_fixations", window_fixations),
                            ("window_trials", window_trials)):
            check_int(value, name, 1)
        self.num_envs = num_envs
        self.window_fixations = window_fixations
        self.window_trials = window_trials
        self.scales = tuple(scales)
        empty = torch.zeros(0, dtype=torch.float64)
        self.pursuit = empty.clone()  # |error| at the last fixation ends, oldest first
        self.vergence = empty.clone()
        self.depth = empty.clone()  # |prediction - distance| of the last predicted trials
        self._reset_interval()

    def _reset_interval(self) -> None:
        n = len(self.scales)
        self.iterations = 0
        self.sums = {cue: {"reward": 0.0, "entropy": 0.0, "td_error": 0.0} for cue in CUES}
        self.td_count = {cue: 0 for cue in CUES}
        self.error_sums = {cue: torch.zeros(n, dtype=torch.float64) for cue in CUES}
        self.atom_counts: dict[str, Tensor | None] = {cue: None for cue in CUES}

    @staticmethod
    def _append(window: Tensor, values: Tensor, size: int) -> Tensor:
        return torch.cat((window, values.detach().double().reshape(-1).cpu()))[-size:]

    def update(self, record) -> None:
        """Add one :class:`~aectorch.framework.IterationRecord`."""
        if record.pursuit_error_deg.shape != (self.num_envs,):
            raise ValueError(
                f"record has {tuple(record.pursuit_error_deg.shape)} environments, "
                f"the metrics expect [{self.num_envs}]"
            )
        if record.fixation_end:
            self.pursuit = self._append(self.pursuit, record.pursuit_error_deg.abs(), self.window_fixations)
            self.vergence = self._append(self.vergence, record.vergence_error_deg.abs(), self.window_fixations)
        if record.trial_end and record.depth_prediction_m is not None:
            error = (record.depth_prediction_m.double() - record.distance_m.double()).abs().cpu()
            self.depth = self._append(self.depth, error[~torch.isnan(error)], self.window_trials)
        self.iterations += 1
        for cue in CUES:
            c = getattr(record, cue)
            if c.errors.shape[-1] != len(self.scales):
                raise ValueError(f"record has {c.errors.shape[-1]} scales, the metrics expect {self.scales}")
            sums = self.sums[cue]
            sums["reward"] += float(c.reward.double().mean())
            sums["entropy"] += float(c.entropy.double().mean())
            if c.td_error is not None:
                sums["td_error"] += float(c.td_error.double().abs().mean())
                self.td_count[cue] += 1
            self.error_sums[cue] += c.errors.detach().double().mean(0).cpu()
            counts = c.atom_counts.detach().double().cpu()
            previous = self.atom_counts[cue]
            self.atom_counts[cue] = counts if previous is None else previous + counts

    @property
    def window_full(self) -> bool:
        """Whether the pursuit and vergence windows hold ``window_fixations`` fixation ends."""
        return self.pursuit.numel() >= self.window_fixations

    def summary(self, *, reset: bool = True) -> dict[str, float]:
        """The metrics as a flat dict of floats; ``reset`` starts a new averaging interval."""
        out = {
            "pursuit_mae_deg": float(self.pursuit.mean()) if self.pursuit.numel() else math.nan,
            "vergence_mae_deg": float(self.vergence.mean()) if self.vergence.numel() else math.nan,
            "depth_mae_m": float(self.depth.mean()) if self.depth.numel() else math.nan,
        }
        for cue in CUES:
            sums = self.sums[cue]
            out[f"{cue}/reward"] = _mean(sums["reward"], self.iterations)
            out[f"{cue}/entropy"] = _mean(sums["entropy"], self.iterations)
            out[f"{cue}/td_error"] = _mean(sums["td_error"], self.td_count[cue])
            counts = self.atom_counts[cue]
            for i, scale in enumerate(self.scales):
                out[f"{cue}/{scale}/error"] = _mean(float(self.error_sums[cue][i]), self.iterations)
                out[f"{cue}/{scale}/atom_usage"] = math.nan if counts is None else _usage(counts[i])
        if reset:
            self._reset_interval()
        return out

    # -- checkpoints ---------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to continue exactly (copies)."""
        return {
            "num_envs": self.num_envs,
            "window_fixations": self.window_fixations,
            "window_trials": self.window_trials,
            "scales": list(self.scales),
            "pursuit": self.pursuit.clone(),
            "vergence": self.vergence.clone(),
            "depth": self.depth.clone(),
            "iterations": self.iterations,
            "sums": {cue: dict(v) for cue, v in self.sums.items()},
            "td_count": dict(self.td_count),
            "error_sums": {cue: v.clone() for cue, v in self.error_sums.items()},
            "atom_counts": {cue: None if v is None else v.clone() for cue, v in self.atom_counts.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` (the windows and scales must match this object's)."""
        for key in ("num_envs", "window_fixations", "window_trials"):
            if state[key] != getattr(self, key):
                raise ValueError(f"state was saved with {key}={state[key]!r}, these metrics have {getattr(self, key)!r}")
        if tuple(state["scales"]) != self.scales:
            raise ValueError(f"state was saved with scales={state['scales']!r}, these metrics have {self.scales!r}")
        self.pursuit = state["pursuit"].clone()
        self.vergence = state["vergence"].clone()
        self.depth = state["depth"].clone()
        self.iterations = int(state["iterations"])
        self.sums = {cue: dict(v) for cue, v in state["sums"].items()}
        self.td_count = dict(state["td_count"])
        self.error_sums = {cue: v.clone() for cue, v in state["error_sums"].items()}
        self.atom_counts = {cue: None if v is None else v.clone() for cue, v in state["atom_counts"].items()}


def _usage(counts: Tensor) -> float:
    """Perplexity of the distribution ``counts / counts.sum()`` divided by its size (NaN if empty)."""
    total = float(counts.sum())
    if total <= 0:
        return math.nan
    p = counts / total
    p = p[p > 0]
    entropy = float(-(p * p.log()).sum())
    return math.exp(entropy) / counts.numel()
