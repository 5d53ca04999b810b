"""Eye control: the `Agent` protocol and its agents, the natural actor-critic (Bhatnagar et al. 2009,
algorithm 3) and PPO, that choose pan increments from a cue's features."""

from aectorch.control.actor_critic import ActorCriticConfig, NaturalActorCritic, UpdateOutput
from aectorch.control.agent import (
    DEFAULT_ACTIONS_DEG, PAPER_ACTIONS_DEG, ActOutput, Agent, LearnOutput, Transitions, draw_uniform, sample_actions,
)
from aectorch.control.factory import AGENTS, agent_config, make_agent
from aectorch.control.ppo import PPO, PPOConfig
from aectorch.control.rewards import RewardScale, learned_reward

__all__ = ["AGENTS", "DEFAULT_ACTIONS_DEG", "PAPER_ACTIONS_DEG", "PPO", "ActOutput", "ActorCriticConfig", "Agent",
           "LearnOutput", "NaturalActorCritic", "PPOConfig", "RewardScale", "Transitions", "UpdateOutput",
           "agent_config", "draw_uniform", "learned_reward", "make_agent", "sample_actions"]
