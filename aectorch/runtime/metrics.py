"""Streaming training metrics over :class:`~aectorch.framework.IterationRecord` s.

:class:`TrainingMetrics` turns the records of `JointLearner.iteration` into the flat,
JSON-ready numbers that ``metrics.jsonl``, TensorBoard and the figures use. Its keys are a
contract with `aectorch.figures`:

- ``<movement>_mae_deg`` for each eye movement of the records (``pursuit_mae_deg``,
  ``vergence_mae_deg``): the paper's eq. (9), the mean absolute error of the movement's eye (the
  left eye's pan for pursuit, the right eye's for vergence) at the last iteration of each
  fixation, over the last ``window_fixations`` fixation ends (each environment's fixation counts
  as one);
- ``depth_mae_m``: mean ``|depth_prediction_m - distance_m|`` over the last ``window_trials``
  trials with a prediction (not NaN): the depth MLP's estimate made before the trial joined its
  training data, so an honest online error (the paper's Fig. 3b moving average);
- per learned cue ``c`` (``parallax``, ``stereo``), averaged over the iterations since the
  previous summary: ``c/reward`` (mean R), ``c/entropy`` (mean policy entropy, nats),
  ``c/td_error`` (mean |TD error| of the iterations that learned; NaN if none did), and per scale
  ``s``: ``c/s/error`` (mean reconstruction error) and ``c/s/atom_usage`` (the perplexity
  ``exp(H(p))`` of the atom-selection distribution ``p`` accumulated since the previous summary,
  divided by the number of atoms: 1 = every atom chosen equally often, 1/N = one atom only).

- with ``recent`` (a run with perturbations), the short window that shows a perturbation's
  transient: ``<movement>_recent_deg`` (the MAE of the last ``recent`` fixation ends),
  ``<movement>_recent_1px`` (the fraction of them within one pixel, `aectorch.evaluation.WITHIN_DEG`)
  and ``depth_recent_m`` (the last ``recent // 2`` predicted trials: the same iterations).

Values not yet defined (no fixation ended, no iteration since the last summary) are NaN.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_int
from aectorch.evaluation.summary import WITHIN_DEG
from aectorch.framework import default_cues
from aectorch.sim import ActiveDepthEnv

__all__ = ["PAPER_WINDOW", "RECENT_WINDOW", "TrainingMetrics"]

#: The training windows' length: the paper's eq. (9) averages the last 1000 fixation ends (and
#: the depth MAE the last 1000 trials).
PAPER_WINDOW = 1000
#: The short window of a run with perturbations: 4 fixations of 32 environments (120 iterations).
RECENT_WINDOW = 128


def _mean(total: float, count: int) -> float:
    return total / count if count else math.nan


class TrainingMetrics:
    """Moving-window task errors and per-interval learning statistics.

    Args:
        num_envs: environments B of the records (checked).
        window_fixations: fixation ends the eye movements' errors average over (>= 1).
        window_trials: predicted trials the depth error averages over (>= 1).
        cues: the learned cues' scales, ``{cue: scale names}`` in the order of ``CueRecord.errors``'
            columns (default: `aectorch.framework.default_cues`' cues and scales; for a learner:
            :meth:`for_learner`).
        movements: the eye movements of the records' ``errors_deg`` (default: those of
            `aectorch.sim.ActiveDepthEnv`'s cues, pursuit and vergence).
        recent: ``None`` (default), or the fixation ends of the short window (>= 1, at most
            ``window_fixations``; its depth window is ``recent // 2`` trials, at most
            ``window_trials``): the keys ``*_recent_*``.

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
        >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=1), textures=torch.rand(3, 64, 64),
        ...                      seed=0)
        >>> learner = JointLearner(LearnerConfig(), generator=torch.Generator().manual_seed(0))
        >>> metrics = TrainingMetrics.for_learner(learner, 2)
        >>> metrics.update(learner.iteration(env))
        >>> summary = metrics.summary()
        >>> summary["pursuit_mae_deg"] >= 0, 0 < summary["stereo/fine/atom_usage"] <= 1
        (True, True)
    """

    def __init__(
        self,
        num_envs: int,
        window_fixations: int = PAPER_WINDOW,
        window_trials: int = PAPER_WINDOW,
        *,
        cues: Mapping[str, Sequence[str]] | None = None,
        movements: Sequence[str] | None = None,
        recent: int | None = None,
    ) -> None:
        for name, value in (("num_envs", num_envs), ("window_fixations", window_fixations),
                            ("window_trials", window_trials)):
            check_int(value, name, 1)
        if recent is not None:
            check_int(recent, "recent", 1)
        self.recent = recent
        self.num_envs = num_envs
        self.window_fixations = window_fixations
        self.window_trials = window_trials
        cues = {name: cue.scales for name, cue in default_cues().items()} if cues is None else cues
        self.cues = {str(name): tuple(scales) for name, scales in cues.items()}
        if movements is None:
            movements = [movement.name for movement in ActiveDepthEnv.CUES.values()]
        # |error| at the last fixation ends per movement, oldest first
        self.errors = {str(m): torch.zeros(0, dtype=torch.float64) for m in movements}
        self.depth = torch.zeros(0, dtype=torch.float64)  # |prediction - distance| of the last predicted trials
        self._reset_interval()

    @classmethod
    def for_learner(cls, learner, num_envs: int, window_fixations: int = PAPER_WINDOW, window_trials: int = PAPER_WINDOW,
                    movements: Sequence[str] | None = None, recent: int | None = None) -> "TrainingMetrics":
        """The metrics of ``learner``'s cues and scales (a `JointLearner`)."""
        cues = {name: tuple(s.name for s in cue.encoder.scales) for name, cue in learner.cues.items()}
        return cls(num_envs, window_fixations, window_trials, cues=cues, movements=movements, recent=recent)

    def _reset_interval(self) -> None:
        self.iterations = 0
        self.sums = {cue: {"reward": 0.0, "entropy": 0.0, "td_error": 0.0} for cue in self.cues}
        self.td_count = {cue: 0 for cue in self.cues}
        self.error_sums = {cue: torch.zeros(len(scales), dtype=torch.float64) for cue, scales in self.cues.items()}
        self.atom_counts: dict[str, Tensor | None] = {cue: None for cue in self.cues}

    @staticmethod
    def _append(window: Tensor, values: Tensor, size: int) -> Tensor:
        return torch.cat((window, values.detach().double().reshape(-1).cpu()))[-size:]

    def update(self, record) -> None:
        """Add one :class:`~aectorch.framework.IterationRecord`."""
        if set(record.errors_deg) != set(self.errors):
            raise ValueError(f"record has the movements {list(record.errors_deg)}, the metrics expect {list(self.errors)}")
        for movement, error in record.errors_deg.items():
            if error.shape != (self.num_envs,):
                raise ValueError(f"record has {tuple(error.shape)} environments, the metrics expect [{self.num_envs}]")
            if record.fixation_end:
                self.errors[movement] = self._append(self.errors[movement], error.abs(), self.window_fixations)
        if record.trial_end and record.depth_prediction_m is not None:
            error = (record.depth_prediction_m.double() - record.distance_m.double()).abs().cpu()
            self.depth = self._append(self.depth, error[~torch.isnan(error)], self.window_trials)
        if set(record.cues) != set(self.cues):
            raise ValueError(f"record has the cues {list(record.cues)}, the metrics expect {list(self.cues)}")
        self.iterations += 1
        for cue, scales in self.cues.items():
            c = record.cues[cue]
            if c.errors.shape[-1] != len(scales):
                raise ValueError(f"record's {cue} has {c.errors.shape[-1]} scales, the metrics expect {scales}")
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
        """Whether every movement's window holds ``window_fixations`` fixation ends."""
        return all(w.numel() >= self.window_fixations for w in self.errors.values())

    def summary(self, *, reset: bool = True) -> dict[str, float]:
        """The metrics as a flat dict of floats; ``reset`` starts a new averaging interval."""
        out = {f"{movement}_mae_deg": float(w.mean()) if w.numel() else math.nan for movement, w in self.errors.items()}
        out["depth_mae_m"] = float(self.depth.mean()) if self.depth.numel() else math.nan
        if self.recent is not None:
            out.update(self.recent_summary())
        for cue, scales in self.cues.items():
            sums = self.sums[cue]
            out[f"{cue}/reward"] = _mean(sums["reward"], self.iterations)
            out[f"{cue}/entropy"] = _mean(sums["entropy"], self.iterations)
            out[f"{cue}/td_error"] = _mean(sums["td_error"], self.td_count[cue])
            counts = self.atom_counts[cue]
            for i, scale in enumerate(scales):
                out[f"{cue}/{scale}/error"] = _mean(float(self.error_sums[cue][i]), self.iterations)
                out[f"{cue}/{scale}/atom_usage"] = math.nan if counts is None else _usage(counts[i])
        if reset:
            self._reset_interval()
        return out

    def recent_summary(self) -> dict[str, float]:
        """The short window's keys (``recent``; see the module): the last ``recent`` fixation ends
        of each movement's window (the long window holds them), the last ``recent // 2`` trials."""
        out = {}
        for movement, w in self.errors.items():
            last = w[-self.recent:]  # type: ignore[operator]  # (called only with recent set)
            out[f"{movement}_recent_deg"] = float(last.mean()) if last.numel() else math.nan
            out[f"{movement}_recent_1px"] = float((last <= WITHIN_DEG).double().mean()) if last.numel() else math.nan
        depth = self.depth[-max(1, self.recent // 2):]  # type: ignore[operator]
        out["depth_recent_m"] = float(depth.mean()) if depth.numel() else math.nan
        return out

    def window_mae(self) -> float:
        """The sum of the movements' windowed errors: what `train.keep_best` minimises (NaN when
        no fixation ended yet)."""
        return sum(float(w.mean()) if w.numel() else math.nan for w in self.errors.values())

    # -- checkpoints ---------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to continue exactly (copies)."""
        return {
            "num_envs": self.num_envs,
            "window_fixations": self.window_fixations,
            "window_trials": self.window_trials,
            "cues": {cue: list(scales) for cue, scales in self.cues.items()},
            "errors": {movement: w.clone() for movement, w in self.errors.items()},
            "depth": self.depth.clone(),
            "iterations": self.iterations,
            "sums": {cue: dict(v) for cue, v in self.sums.items()},
            "td_count": dict(self.td_count),
            "error_sums": {cue: v.clone() for cue, v in self.error_sums.items()},
            "atom_counts": {cue: None if v is None else v.clone() for cue, v in self.atom_counts.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` (the windows and cues must match this object's)."""
        for key in ("num_envs", "window_fixations", "window_trials"):
            if state[key] != getattr(self, key):
                raise ValueError(f"state was saved with {key}={state[key]!r}, these metrics have {getattr(self, key)!r}")
        cues = {cue: tuple(scales) for cue, scales in state["cues"].items()}
        if cues != self.cues or set(state["errors"]) != set(self.errors):
            raise ValueError(f"state was saved with cues={cues!r} and movements {list(state['errors'])}, these "
                             f"metrics have {self.cues!r} and {list(self.errors)}")
        self.errors = {movement: w.clone() for movement, w in state["errors"].items()}
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
