"""What an agent learns from the coding reward: the reward, its improvement, or the improvement scaled.

Active efficient coding rewards the eyes with how well the code reconstructs what they see, R =
-(e^C + e^F) (eq. 4). An agent can learn from it in three forms (`aectorch.choices.Reward`), and
the joint learner (`learner.cues.<cue>.reward`) and the standard environments
(`aectorch.envs`, ``reward=``) both take theirs from `learned_reward`:

- ``coding``: R(s'), the reward of the observation the action led to (the paper).
- ``improvement``: R(s') - R(s), the change the action caused. With a discount gamma < 1 it
  defines the same discounted problem as ``coding`` (its return is (1 - gamma) times the coding
  reward's, minus a constant of the start state) without the texture's reward level, the largest
  term of the noise.
- ``scaled``: the improvement divided by a running root mean square of the improvements seen,
  ``(R(s') - R(s)) / sqrt(E[(R(s') - R(s))^2] + eps)``, so that the reward has a magnitude near 1
  whatever the textures, the scales or the dictionaries' stage of learning (the lineage's scaled
  change of the error: Wilmot et al. 2021 multiply it by 600). `RewardScale` holds the running
  mean; it weighs at most its ``window`` last improvements.

The improvement needs the previous observation's reward: the first observation of a fixation (of
an episode) is coded before any action, and the first action's improvement is measured from it.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor, nn

from aectorch._checks import check_int, check_real
from aectorch.choices import Reward

__all__ = ["RewardScale", "learned_reward"]


def _identity(t: Tensor) -> Tensor:
    return t


class RewardScale(nn.Module):
    """The running mean of the squared improvements, for the ``scaled`` reward.

    Args:
        window: the running mean weighs at most this many of the last improvements (>= 1).
        eps: added to the mean square before its root (> 0).

    Example:
        >>> scale = RewardScale(window=100)
        >>> _ = scale.update_(torch.tensor([3.0, -4.0]))
        >>> round(scale.rms().item(), 4)
        3.5355
    """

    def __init__(self, window: int = 100_000, eps: float = 1e-12) -> None:
        super().__init__()
        self.window = check_int(window, "window", 1)
        self.eps = check_real(eps, "eps", above=0)
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("mean_square", torch.zeros((), dtype=torch.float64))

    def update_(self, improvement: Tensor, reduce: Callable[[Tensor], Tensor] | None = None) -> "RewardScale":
        """Merge the improvements ``[B]`` in (``reduce`` sums over the processes that share the
        batch; ``None``: one process)."""
        reduce = reduce or _identity
        squares = improvement.detach().to(self.mean_square.dtype).square()
        nb = reduce(torch.tensor(float(squares.numel()), dtype=squares.dtype, device=squares.device))
        total = reduce(squares.sum())
        n = torch.minimum(self.count, (self.window - nb).clamp_min(0))
        self.mean_square.copy_((n * self.mean_square + total) / (n + nb).clamp_min(1))
        self.count.copy_(n + nb)
        return self

    def rms(self) -> Tensor:
        """sqrt(mean square + eps), a scalar tensor."""
        return torch.sqrt(self.mean_square + self.eps)


def learned_reward(form: Reward | str, reward: Tensor, previous: Tensor | None = None,
                   scale: RewardScale | None = None, reduce: Callable[[Tensor], Tensor] | None = None) -> Tensor:
    """The reward an agent learns from, in the ``form`` of `aectorch.choices.Reward`.

    Args:
        form: ``coding``, ``improvement`` or ``scaled``.
        reward: R(s'), the coding reward of the observation the action led to.
        previous: R(s), the coding reward of the observation the action was taken in (the
            improvement forms).
        scale: the running scale (``scaled``); it is updated with these improvements first.
        reduce: sums over the processes that share the batch (``scaled``; ``None``: one process).

    Shape:
        reward, previous `[B]` -> `[B]`.

    Example:
        >>> r, r_prev = torch.tensor([-1.0, -2.0]), torch.tensor([-1.5, -1.0])
        >>> learned_reward("improvement", r, r_prev).tolist()
        [0.5, -1.0]
    """
    form = Reward(form)
    if form == Reward.coding:
        return reward
    if previous is None:
        raise ValueError(f"reward={form.value} needs the previous observation's coding reward (previous=None)")
    improvement = reward - previous
    if form == Reward.improvement:
        return improvement
    if scale is None:
        raise ValueError("reward=scaled needs a RewardScale (scale=None)")
    scale.update_(improvement, reduce)
    return improvement / scale.rms().to(improvement.dtype)
