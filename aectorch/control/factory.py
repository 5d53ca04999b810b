"""``make_agent``: an `Agent` by name, with its config."""

from __future__ import annotations

from typing import Sequence

import torch

from aectorch._checks import check_choice
from aectorch.choices import AgentName
from aectorch.control.actor_critic import ActorCriticConfig, NaturalActorCritic
from aectorch.control.ppo import PPO, PPOConfig

__all__ = ["AGENTS", "agent_config", "make_agent"]

#: The agents :func:`make_agent` builds: name -> (class, config class).
AGENTS = {AgentName.nac: (NaturalActorCritic, ActorCriticConfig), AgentName.ppo: (PPO, PPOConfig)}


def agent_config(name: str):
    """The config class of the agent called ``name``."""
    return AGENTS[check_choice(name, "agent", AgentName)][1]


def make_agent(name: str, num_features: int, actions_deg: Sequence[float], config=None, *,
               generator: torch.Generator | None = None, dtype: torch.dtype | None = None,
               device: torch.device | str | None = None, unscaled_features: int = 0):
    """Build the agent called ``name`` (``"nac"``: `NaturalActorCritic`, ``"ppo"``: `PPO`) for
    ``num_features`` features and the action set ``actions_deg``, with its config
    (`ActorCriticConfig`, `PPOConfig`; ``None``: the defaults); the last ``unscaled_features``
    of them are left out of the scaling to its ``feature_norm``.

    Example:
        >>> agent = make_agent("ppo", 6, (-0.1, 0.0, 0.1), generator=torch.Generator().manual_seed(0))
        >>> agent.act(torch.zeros(2, 6), greedy=True).actions.shape
        torch.Size([2])
    """
    cls, _ = AGENTS[check_choice(name, "agent", AgentName)]
    return cls(num_features, actions_deg, config, generator=generator, dtype=dtype, device=device,
               unscaled_features=unscaled_features)
