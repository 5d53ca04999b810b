"""``DepthLearner``: the depth MLP, the trials it learns from, when it refits, and its calibration.

Each finished trial's final eye angles ``q`` (``[4]``: both eyes' pan and tilt, degrees) are
first predicted by the current MLP (so the online depth error is honest) and then join a replay
buffer of the last ``max_samples`` trials; after every ``every_trials`` new trials the MLP is
refitted on the buffer with our Levenberg-Marquardt (`fit_levenberg_marquardt`), from its current
weights (Nguyen-Widrow weights before the first fit).
"""

from __future__ import annotations

import math
from typing import Callable

import torch
from torch import Tensor, nn

from aectorch._checks import check_int
from aectorch.depth.levenberg_marquardt import LevenbergMarquardtResult, fit_levenberg_marquardt
from aectorch.depth.mlp import DepthMLP

__all__ = ["DepthLearner", "MIN_DEPTH_TRIALS"]

#: The depth MLP is first fitted once this many trials are stored (fewer cannot hold out a
#: validation set).
MIN_DEPTH_TRIALS = 10


class DepthLearner(nn.Module):
    """The depth MLP with its replay buffer of trials and its fit cadence.

    Args:
        hidden: hidden units of the MLP (paper: 10).
        every_trials: refit after every this many new trials.
        max_samples: keep the last this many trials.
        max_epochs: Levenberg-Marquardt's epoch budget per fit.
        generator: draws a fit's seed (its validation split) when none is given.
        device, dtype: of the MLP and the buffer.

    Example:
        >>> import torch
        >>> depth = DepthLearner(every_trials=20, generator=torch.Generator().manual_seed(0))
        >>> q = torch.randn(20, 4)
        >>> depth.predict(q).isnan().all().item(), depth.add_trials(q, 1 + q[:, 0].abs())
        (True, True)
    """

    inputs: Tensor  # buffers
    targets: Tensor
    trained: Tensor

    def __init__(self, hidden: int = 10, *, every_trials: int = 256, max_samples: int = 20000,
                 max_epochs: int = 200, generator: torch.Generator | None = None,
                 device: torch.device | str | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        self.every_trials = check_int(every_trials, "every_trials")
        self.max_samples = check_int(max_samples, "max_samples")
        self.max_epochs = check_int(max_epochs, "max_epochs")
        self.generator = generator or torch.Generator().manual_seed(0)
        self.mlp = DepthMLP(in_features=4, hidden=check_int(hidden, "hidden"), out_features=1).to(
            device=device, dtype=dtype)
        # Unused until the first fit, which starts from Nguyen-Widrow weights drawn from a seed of
        # ``generator``; zero them rather than leave torch's global random state in them, so that
        # a seed fixes the whole learner state (and checkpoints) even with other RNG use around.
        with torch.no_grad():
            for parameter in self.mlp.parameters():
                parameter.zero_()
        self.register_buffer("inputs", torch.zeros(0, 4, dtype=dtype, device=device))
        self.register_buffer("targets", torch.zeros(0, dtype=dtype, device=device))
        self.register_buffer("trained", torch.zeros((), dtype=torch.bool, device=device))
        self.trials_seen = 0
        self.trials_at_last_fit = 0

    def predict(self, q_deg: Tensor) -> Tensor:
        """The distance estimate ``[B]`` (metres) from ``q`` ``[B, 4]``; NaN before any fit."""
        with torch.no_grad():
            estimate = self.mlp(q_deg.to(self.inputs.dtype)).reshape(-1)
        return torch.where(self.trained, estimate, torch.full_like(estimate, math.nan))

    def add_trials(self, q_deg: Tensor, distance_m: Tensor,
                   gather: Callable[[Tensor], Tensor] = lambda t: t) -> bool:
        """Store finished trials (``gather``: every process's, in the whole batch's order) and
        refit when ``every_trials`` new ones have come in; returns whether it refitted."""
        q_deg, distance_m = gather(q_deg), gather(distance_m)
        keep = self.max_samples
        self.inputs = torch.cat((self.inputs, q_deg.to(self.inputs)))[-keep:]
        self.targets = torch.cat((self.targets, distance_m.to(self.targets)))[-keep:]
        self.trials_seen += q_deg.shape[0]
        if (self.trials_seen - self.trials_at_last_fit < self.every_trials
                or self.inputs.shape[0] < MIN_DEPTH_TRIALS):
            return False
        self.fit()
        return True

    def fit(self, *, seed: int | None = None) -> LevenbergMarquardtResult:
        """Refit the MLP on the stored trials with Levenberg-Marquardt (from its current weights)."""
        if self.inputs.shape[0] < MIN_DEPTH_TRIALS:
            raise ValueError(f"fit_depth needs at least {MIN_DEPTH_TRIALS} finished trials, has {self.inputs.shape[0]}")
        result = self._fit(self.inputs, self.targets, seed)
        self.trials_at_last_fit = self.trials_seen
        return result

    def calibrate(self, q_deg: Tensor, distance_m: Tensor, *, seed: int | None = None) -> LevenbergMarquardtResult:
        """Refit the MLP on the given trials only, from its current weights; the stored trials are
        not changed (see `aectorch.framework.JointLearner.calibrate_depth`)."""
        if not isinstance(q_deg, Tensor) or q_deg.dim() != 2 or q_deg.shape[1] != 4:
            raise ValueError(f"q_deg must be a tensor of shape [N, 4], got {getattr(q_deg, 'shape', type(q_deg))}")
        if not isinstance(distance_m, Tensor) or distance_m.shape != q_deg.shape[:1]:
            raise ValueError(f"distance_m must be a tensor of shape [{q_deg.shape[0]}], "
                             f"got {getattr(distance_m, 'shape', type(distance_m))}")
        if q_deg.shape[0] < MIN_DEPTH_TRIALS:
            raise ValueError(f"calibrate_depth needs at least {MIN_DEPTH_TRIALS} trials, got {q_deg.shape[0]}")
        if not (torch.isfinite(q_deg).all() and torch.isfinite(distance_m).all()):
            raise ValueError("q_deg and distance_m must be finite")
        return self._fit(q_deg, distance_m, seed)

    def _fit(self, q_deg: Tensor, distance_m: Tensor, seed: int | None) -> LevenbergMarquardtResult:
        if seed is None:
            seed = int(torch.randint(0, 2**31 - 1, (1,), generator=self.generator))
        like = self.inputs
        result = fit_levenberg_marquardt(
            self.mlp, q_deg.to(like), distance_m.to(like), max_epochs=self.max_epochs,
            seed=seed, init=None if bool(self.trained) else "nguyen-widrow",
        )
        self.trained.fill_(True)
        return result

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The buffer grows during training: take the checkpoint's size.
        for name in ("inputs", "targets"):
            key = prefix + name
            if key in state_dict:
                setattr(self, name, getattr(self, name).new_empty(state_dict[key].shape))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
