"""The `Agent` protocol: what a cue's learner needs of the algorithm that chooses its eye movements.

An agent maps the features of B environments' observations to one discrete action each (an index
into its ``actions_deg``) and learns from batches of transitions ``(s, a, r, s')``. Two agents
implement it: `NaturalActorCritic` (Bhatnagar et al. 2009, algorithm 3; online, one update per
batch) and `PPO` (clipped surrogate, generalised advantage estimates; it collects the
transitions of a fixation and then trains for epochs of minibatches).
`aectorch.control.make_agent` builds one by name (``"nac"``, ``"ppo"``).

A batch (:class:`Transitions`) is one transition per environment, all from the same iteration of
a fixation; ``last`` says that their next states end the fixation (the episode is cut there: a
time limit, not a terminal state). Sampling is by inverse CDF from one uniform number per
environment (:func:`sample_actions`), so that a caller who draws those numbers (for the whole
batch of several processes, say) fixes the actions.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Protocol, runtime_checkable

import torch
from torch import Tensor

__all__ = ["DEFAULT_ACTIONS_DEG", "PAPER_ACTIONS_DEG", "ActOutput", "Agent", "LearnOutput", "Reduce", "Transitions", "draw_uniform", "entropy", "sample_actions"]

#: The paper's action set A of pan increments in degrees (sec. 2.3).
PAPER_ACTIONS_DEG = (-0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2)
#: The default action set: the paper's seven increments plus +-0.5 and +-1 degrees, so that a
#: fixation's 30 iterations can reach the 5.7 degrees of pursuit that 1 m needs in six steps (the
#: paper's largest step, 0.2 degrees, needs 29 of them). A largest step of 2 degrees made the
#: greedy policy of near trials cycle between states 2 degrees apart (CHANGELOG.md).
DEFAULT_ACTIONS_DEG = (-1.0, -0.5, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.5, 1.0)

#: Sums a tensor over the processes that share a batch (an all-reduce), or ``None`` for one process.
Reduce = Callable[[Tensor], Tensor]

class ActOutput(NamedTuple):
    """What `Agent.act` returns.

    Attributes:
        actions: chosen action indices into ``actions_deg``, `[B]` int64.
        increments_deg: the chosen pan increments in degrees, `[B]`.
        log_prob: ``log pi(a|s)`` of the chosen actions under the policy that chose
            them (at the temperature used), `[B]`.
        entropy: entropy of that policy in nats, `[B]`.
    """

    actions: Tensor
    increments_deg: Tensor
    log_prob: Tensor
    entropy: Tensor


class Transitions(NamedTuple):
    """One transition ``(s, a, r, s')`` per environment, `[B, ...]`.

    Attributes:
        features: f(s), `[B, F]`.
        actions: the action indices taken in s, `[B]` int.
        rewards: r received on the transition, `[B]`.
        next_features: f(s'), `[B, F]`.
        last: s' is the last state of the fixation (the episode ends there by its time limit;
            its value still counts).
    """

    features: Tensor
    actions: Tensor
    rewards: Tensor
    next_features: Tensor
    last: bool = False


class LearnOutput(NamedTuple):
    """What `Agent.learn` returns.

    Attributes:
        td_error: ``r + gamma V(s') - V(s)`` (NAC: minus the average reward too) of each
            transition under the critic before this call's update, `[B]`.
        updated: whether the agent's weights changed in this call (PPO learns at fixation ends).
    """

    td_error: Tensor
    updated: bool


@runtime_checkable
class Agent(Protocol):
    """What `aectorch.framework.CueLearner` calls on the agent of a cue (an `nn.Module`).

    Attributes:
        num_features: F, the length of the feature vectors.
        num_actions: A, the number of actions.
        actions_deg: the action set, `[A]` degrees (a buffer).
    """

    num_features: int
    num_actions: int
    actions_deg: Tensor

    def act(self, features: Tensor, greedy: bool = False, generator: torch.Generator | None = None, *,
            uniform: Tensor | None = None) -> ActOutput:
        """One action per environment: the most probable (``greedy``), or sampled with ``uniform``
        (`[B]` in [0, 1); drawn from ``generator`` when not given). Changes no state."""
        ...

    def log_policy(self, features: Tensor) -> Tensor:
        """log pi(.|s) of the policy that `act` samples from, `[B, F]` -> `[B, A]`."""
        ...

    def learn(self, transitions: Transitions, *, reduce: Reduce | None = None) -> LearnOutput:
        """Learn from one transition per environment; ``reduce`` sums over processes."""
        ...

    def symmetrize_(self, feature_permutation: Tensor, action_negation: Tensor) -> None:
        """Make the policy (and critic) invariant under the cue's symmetry: the transformed
        features ``f[..., feature_permutation]`` with the negated actions ``action_negation[a]``
        must get the same probabilities (the learner then feeds both transitions)."""
        ...

    def state_dict(self, *args, **kwargs) -> dict: ...

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False): ...


def draw_uniform(shape, generator: torch.Generator | None, like: Tensor) -> Tensor:
    """Numbers uniform in [0, 1) of ``like``'s dtype and device, drawn by ``generator`` on the
    generator's own device: a CPU generator (the learner's, whose state checkpoints hold) drives a
    CUDA run too, with the numbers it draws on CPU.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> u = draw_uniform((2, 3), g, torch.zeros(1, dtype=torch.float64))
        >>> u.shape, u.dtype, bool(((0 <= u) & (u < 1)).all())
        (torch.Size([2, 3]), torch.float64, True)
    """
    device = like.device if generator is None else generator.device
    return torch.rand(shape, generator=generator, dtype=like.dtype, device=device).to(like.device)


def sample_actions(logp: Tensor, uniform: Tensor) -> Tensor:
    """Inverse-CDF sampling: for each row of log-probabilities ``logp`` `[B, A]` the first action
    whose cumulative probability exceeds ``uniform`` (`[B]` in [0, 1)).

    Example:
        >>> logp = torch.tensor([[0.25, 0.5, 0.25]]).log().expand(3, 3)
        >>> sample_actions(logp, torch.tensor([0.1, 0.5, 0.9])).tolist()
        [0, 1, 2]
    """
    cdf = logp.exp().cumsum(dim=-1)
    # Scaling u by the total keeps a rounding shortfall of the cdf from selecting past the last
    # likely action.
    return (cdf <= uniform[:, None] * cdf[:, -1:]).sum(dim=-1).clamp_max(logp.shape[-1] - 1)


def entropy(logp: Tensor) -> Tensor:
    """The entropy in nats of each row of log-probabilities ``logp`` `[..., A]`."""
    return -(logp.exp() * logp).sum(-1)
