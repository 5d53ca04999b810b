"""``CueLearner``: one depth cue's learner: its encoder, its actor-critic, the pending transition
and the cue's symmetry.

`JointLearner` uses it twice: motion parallax drives pursuit, stereo drives vergence. One
:meth:`CueLearner.step` encodes the cue's observation (features and reward), completes the
previous transition with that reward (a critic/actor update, and with the cue's symmetry the
transformed transition too), chooses the next action and takes one dictionary step.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from aectorch.choices import Features, Reward
from aectorch.coding import BinocularEncoder
from aectorch.control import NaturalActorCritic
from aectorch.framework.config import LearnerConfig
from aectorch.framework.shard import Shard
from aectorch.profiling import stage

__all__ = ["CueLearner", "CueRecord"]


class CueRecord(NamedTuple):
    """One cue's step of an iteration, per environment ``[B]`` unless noted."""

    reward: Tensor  #: R = -(e^C + e^F) of the observation
    errors: Tensor  #: ``[B, n_scales]`` reconstruction error per scale (eq. 4)
    td_error: Tensor | None  #: TD error of the update (``None`` when nothing was learned)
    entropy: Tensor  #: entropy of the policy that chose the action, nats
    actions: Tensor  #: chosen action indices
    increments_deg: Tensor  #: chosen pan increments
    atom_counts: Tensor  #: ``[n_scales, num_atoms]`` how often each atom was chosen (all B, all patches)


class CueLearner(nn.Module):
    """Sparse coding and eye-movement learning of one cue.

    Args:
        encoder: the cue's `BinocularEncoder` (its ``symmetry``, if any, is the cue's).
        agent: the `NaturalActorCritic` of the eye movement the cue drives.
        config: the learner's hyperparameters (features, reward, dictionary rate).
        generator: draws the actions.
        shard: this process's part of the batch (`Shard.single` for one process).
    """

    def __init__(self, encoder: BinocularEncoder, agent: NaturalActorCritic, config: LearnerConfig, *,
                 generator: torch.Generator, shard: Shard) -> None:
        super().__init__()
        self.encoder, self.agent, self.config = encoder, agent, config
        self.generator, self.shard = generator, shard
        # The index of each action's negation: a symmetric cue's transformed transition takes it
        # (the features take the encoder's `feature_permutation`). A buffer, so `.to()` moves it.
        actions = torch.tensor(config.actions_deg, dtype=torch.float64)
        negation = (actions[None, :] == -actions[:, None]).to(torch.int64).argmax(-1)
        symmetric = encoder.feature_permutation is not None
        self.register_buffer("action_negation", negation.to(agent.actor_weight.device) if symmetric else None,
                             persistent=False)
        if symmetric:
            with torch.no_grad():  # start the policy and the critic symmetric as well
                fmap = encoder.feature_permutation
                agent.actor_weight.copy_((agent.actor_weight + agent.actor_weight[self.action_negation][:, fmap]) * 0.5)
                agent.critic_weight.copy_((agent.critic_weight + agent.critic_weight[fmap]) * 0.5)
        self.previous: tuple[Tensor, Tensor, Tensor] | None = None  # (features, action, reward)
        self.dictionary_steps = 0  # learning steps the dictionaries took

    def dictionary_rate(self, steps: int) -> float:
        """The dictionaries' learning rate after ``steps`` steps (``dictionary_decay``)."""
        c = self.config
        if c.dictionary_decay is None:
            return c.dictionary_lr
        return c.dictionary_lr * (c.dictionary_decay / (c.dictionary_decay + steps)) ** c.dictionary_decay_power

    def step(self, pair: Tensor | dict[str, Tensor], *, learn: bool, greedy: bool) -> CueRecord:
        """Encode ``pair`` (``[B, 2, H, W]``, or ``{scale: [B, 2, side, side]}`` rendered at each
        scale's resolution), learn from the pending transition, act, and take a dictionary step."""
        with stage("encode"), torch.no_grad():
            if isinstance(pair, dict):  # images at each scale's resolution
                out = self.encoder({k: p[:, 0] for k, p in pair.items()}, {k: p[:, 1] for k, p in pair.items()},
                                   check=False)
            else:
                out = self.encoder(pair[:, 0], pair[:, 1], check=False)
        with stage("rl"):
            features = self._features(out.features)
            td_error = self._learn(features, out.reward) if learn and self.previous is not None else None
            action = self._act(features, greedy)
        if learn and self.config.dictionary_lr > 0:
            with stage("dictionary"):
                self.encoder.learn_(out, self.dictionary_rate(self.dictionary_steps), reduce=self.shard.reduce)
                self.dictionary_steps += 1
        # Without learning there is no transition to complete on the next step.
        self.previous = (features, action.actions, out.reward) if learn else None
        with stage("metrics"):
            counts = torch.stack([
                torch.bincount(c.code.indices.reshape(-1), minlength=self.encoder.dictionaries[s.name].num_atoms)
                for s, c in zip(self.encoder.scales, out.codes)
            ])
        return CueRecord(out.reward, out.errors, td_error, action.entropy, action.actions,
                         action.increments_deg, counts)

    def _features(self, pooled: Tensor) -> Tensor:
        if self.config.features == Features.unit:
            pooled = pooled / torch.linalg.vector_norm(pooled, dim=-1, keepdim=True).clamp_min(1e-12)
        return pooled * self.config.feature_scale

    def _learn(self, features: Tensor, reward: Tensor) -> Tensor:
        """The critic/actor update of the pending transition, whose reward is this observation's;
        with the cue's symmetry the transformed transition is learned too. Returns the TD error."""
        f_prev, a_prev, r_prev = self.previous
        learned = reward - r_prev if self.config.reward == Reward.improvement else reward
        f_next = features
        fmap = self.encoder.feature_permutation
        if fmap is not None:  # also learn from the transformed transition
            f_prev = torch.cat((f_prev, f_prev[:, fmap]))
            a_prev = torch.cat((a_prev, self.action_negation[a_prev]))
            f_next = torch.cat((f_next, f_next[:, fmap]))
            learned = torch.cat((learned, learned))
        update = self.agent.update(f_prev, a_prev, learned, f_next, reduce=self.shard.reduce)
        return update.td_error[: features.shape[0]]

    def _act(self, features: Tensor, greedy: bool):
        if greedy:
            return self.agent.act(features, greedy=True, generator=self.generator)
        # The numbers one process with the whole batch would draw; this process's rows.
        u = torch.rand(self.shard.whole_batch(features.shape[0]), 1, generator=self.generator, dtype=features.dtype, device=features.device)
        return self.agent.act(features, uniform=self.shard.draw(u)[:, 0])

    def forget(self) -> None:
        """No pending transition: the next step does not learn from the one before it."""
        self.previous = None
