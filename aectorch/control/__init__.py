"""Eye control: the natural actor-critic (Bhatnagar et al. 2009, algorithm 3) that chooses pan increments."""

from aectorch.control.actor_critic import (
    PAPER_ACTIONS_DEG,
    ActorCriticConfig,
    ActOutput,
    NaturalActorCritic,
    UpdateOutput,
)

__all__ = ["PAPER_ACTIONS_DEG", "ActOutput", "ActorCriticConfig", "NaturalActorCritic", "UpdateOutput"]
