"""``CueLearner``: one depth cue's learner: its encoder, its agent, the pending transition and the
cue's symmetry, built from the cue's `CueConfig`.

`JointLearner` holds one per cue (motion parallax drives pursuit, stereo drives vergence, by
default). One :meth:`CueLearner.step` encodes the cue's observation (features and reward),
completes the previous transition with that reward (the agent learns from it, and with the cue's
symmetry from the transformed transition too), chooses the next action and takes one dictionary
step.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from aectorch.choices import Efficiency, Features, Readout, Reward
from aectorch.coding import BinocularEncoder
from aectorch.coding.focus import focus_reward, input_energy
from aectorch.control import Agent, RewardScale, Transitions, draw_uniform, learned_reward, make_agent
from aectorch.framework.config import CueConfig
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
        config: the cue's `CueConfig` (its features, reward, symmetry, agent).
        encoder: the cue's `BinocularEncoder` (:meth:`build_encoder`).
        agent: the `Agent` of the eye movement the cue drives (:meth:`build_agent`).
        generator: draws the actions.
        shard: this process's part of the batch (`Shard.single` for one process).

    Attributes:
        previous: the pending transition ``(features, action, reward)`` of the last step, which
            the next step's reward completes (``None`` after :meth:`forget`); per environment,
            so it is named in ``BATCH_STATE`` (`aectorch.framework.batch_state`).
    """

    BATCH_STATE = ("previous",)

    def __init__(self, config: CueConfig, encoder: BinocularEncoder, agent: Agent, *,
                 generator: torch.Generator, shard: Shard) -> None:
        super().__init__()
        self.config, self.encoder, self.agent = config, encoder, agent
        self.generator, self.shard = generator, shard
        # The index of each action's negation: a symmetric cue's transformed transition takes it
        # (the features take `feature_permutation`). Buffers, so `.to()` moves them.
        symmetric = encoder.feature_permutation is not None
        negation = permutation = None
        if symmetric:
            actions = torch.tensor(config.actions_deg, dtype=torch.float64)
            negation = (actions[None, :] == -actions[:, None]).to(torch.int64).argmax(-1)
            negation = negation.to(agent.actions_deg.device)
            # The code's features permuted; the proprioception the symmetry leaves unchanged after them.
            code = encoder.feature_permutation
            if config.features == Features.none:  # the agent sees no code
                code = code[:0]
            permutation = torch.cat((code, torch.arange(code.numel(), code.numel() + len(config.proprioception),
                                                        dtype=code.dtype, device=code.device)))
        self.register_buffer("action_negation", negation, persistent=False)
        self.register_buffer("feature_permutation", permutation, persistent=False)
        if symmetric:  # start the policy and the critic symmetric as well
            agent.symmetrize_(permutation, negation)
        # The running scale of the ``scaled`` reward (its buffers are in the checkpoint); none otherwise.
        self.reward_scale = RewardScale() if config.reward == Reward.scaled else None
        self.previous: tuple[Tensor, Tensor, Tensor] | None = None  # (features, action, reward)

    @staticmethod
    def build_encoder(config: CueConfig, *, generator: torch.Generator, dtype=None, device=None) -> BinocularEncoder:
        """The `BinocularEncoder` of ``config`` (its encoder settings, scales and symmetry)."""
        symmetry = None if config.symmetry is None else str(config.symmetry)
        return BinocularEncoder(config.encoder, config.scales, symmetry=symmetry, generator=generator,
                                dtype=dtype, device=device)

    @staticmethod
    def build_agent(config: CueConfig, num_features: int, *, generator: torch.Generator, dtype=None,
                    device=None) -> Agent:
        """The agent of ``config`` (``config.agent`` with its settings) for the code's
        ``num_features`` features and the cue's proprioception after them: z-scored with the
        code's, but left out of the scaling to the agent's ``feature_norm``, which would weigh
        a few senses among hundreds of code features by a few per cent each."""
        k = len(config.proprioception)
        if config.features == Features.none:  # the agent senses its proprioception alone
            num_features = 0
        return make_agent(config.agent, num_features + k, config.actions_deg, config.agent_config,
                          generator=generator, dtype=dtype, device=device, unscaled_features=k)

    def step(self, observation: dict[str, Tensor], *, learn: bool, greedy: bool, last: bool = False,
             proprioception: Tensor | None = None) -> CueRecord:
        """Encode ``observation`` (the environment's ``{scale: [B, 2, side, side]}``, or its whole
        window), learn from the pending transition (``last``: this observation ends the fixation),
        act, and take a dictionary step. ``proprioception``: ``[B, k]``, the cue's
        ``config.proprioception`` sensed with the observation (`ActiveDepthEnv.proprioception`)."""
        with stage("encode"), torch.no_grad():
            out = self.encoder.encode(observation)
            if self.config.efficiency == Efficiency.information:
                out = out._replace(reward=self._information(observation, out))
            elif self.config.reward_scales:
                out = out._replace(reward=-out.errors[:, self._reward_index()].sum(-1))
        with stage("rl"):
            features = self.features(out.features, proprioception)
            td_error = self._learn(features, out.reward, last) if learn and self.previous is not None else None
            action = self._act(features, greedy)
        if learn and self.encoder.config.lr > 0:
            with stage("dictionary"):
                self.encoder.learn_(out, reduce=self.shard.reduce)
        # Without learning there is no transition to complete on the next step.
        self.previous = (features, action.actions, out.reward) if learn else None
        with stage("metrics"):
            counts = torch.stack([
                torch.bincount(c.code.indices.reshape(-1), minlength=self.encoder.dictionaries[s.name].num_atoms)
                for s, c in zip(self.encoder.scales, out.codes)
            ])
        return CueRecord(out.reward, out.errors, td_error, action.entropy, action.actions,
                         action.increments_deg, counts)

    def _information(self, observation: dict[str, Tensor], out) -> Tensor:
        """R = sum_scales mean_patches 1/2 log(E (1 - e)) (`aectorch.coding.focus`), ``[B]``."""
        missing = [s.name for s in self.encoder.scales if s.name not in observation]
        if missing:
            raise ValueError(f"efficiency=information needs each scale's own images (learner.render_scales=true); "
                             f"the observation lacks {missing}")
        chosen = self._reward_index()
        energy = [input_energy(observation[self.encoder.scales[i].name], self.encoder.scales[i]) for i in chosen]
        return focus_reward(energy, [out.codes[i].error for i in chosen])

    def _reward_index(self) -> list[int]:
        """The positions among the encoder's scales of those the reward sums (``config.reward_scales``;
        all where it is empty)."""
        names = [s.name for s in self.encoder.scales]
        return [names.index(n) for n in self.config.reward_scales] if self.config.reward_scales else list(range(len(names)))

    def features(self, pooled: Tensor, proprioception: Tensor | None = None) -> Tensor:
        """What the agent sees ``[B, F + k]``: the code's pooled activities ``[B, F]`` as
        ``config.features`` says (none of them with ``none``: ``F = 0``), times
        ``config.feature_scale``, then the ``k`` columns of
        ``proprioception`` ``[B, k]`` (``config.proprioception``; the agent z-scores them all)."""
        if self.config.features == Features.unit:
            pooled = pooled / torch.linalg.vector_norm(pooled, dim=-1, keepdim=True).clamp_min(1e-12)
        pooled = pooled[:, :0] if self.config.features == Features.none else pooled * self.config.feature_scale
        k = len(self.config.proprioception)
        if k == 0 and proprioception is None:
            return pooled
        if proprioception is None or proprioception.shape != (pooled.shape[0], k):
            got = None if proprioception is None else tuple(proprioception.shape)
            raise ValueError(f"proprioception must be [B, {k}] = [{pooled.shape[0]}, {k}] (the cue's "
                             f"{list(self.config.proprioception)}), got {got}")
        return torch.cat((pooled, proprioception.to(pooled.dtype)), -1)

    def _learn(self, features: Tensor, reward: Tensor, last: bool) -> Tensor:
        """The agent learns the pending transition, whose reward is this observation's; with the
        cue's symmetry the transformed transition too. Returns the TD errors ``[B]``."""
        f_prev, a_prev, r_prev = self.previous
        learned = learned_reward(self.config.reward, reward, r_prev, self.reward_scale, self.shard.reduce)
        if self.config.motor_cost:
            learned = learned - self.config.motor_cost * self.agent.actions_deg[a_prev].abs().to(learned.dtype)
        f_next = features
        fmap = self.feature_permutation
        if fmap is not None:  # also learn from the transformed transition
            f_prev = torch.cat((f_prev, f_prev[:, fmap]))
            a_prev = torch.cat((a_prev, self.action_negation[a_prev]))
            f_next = torch.cat((f_next, f_next[:, fmap]))
            learned = torch.cat((learned, learned))
        out = self.agent.learn(Transitions(f_prev, a_prev, learned, f_next, last=last), reduce=self.shard.reduce)
        return out.td_error[: features.shape[0]]

    def _act(self, features: Tensor, greedy: bool):
        if greedy:
            out = self.agent.act(features, greedy=True, generator=self.generator)
            if self.config.readout == Readout.mean:
                with torch.no_grad():
                    probabilities = self.agent.log_policy(features).exp()
                    mean = probabilities @ self.agent.actions_deg.to(probabilities.dtype)
                out = out._replace(increments_deg=mean)
            return out
        # The numbers one process with the whole batch would draw; this process's rows.
        u = draw_uniform((self.shard.whole_batch(features.shape[0]), 1), self.generator, features)
        return self.agent.act(features, uniform=self.shard.draw(u)[:, 0])

    def forget(self) -> None:
        """No pending transition: the next step does not learn from the one before it."""
        self.previous = None

    def get_extra_state(self) -> dict:
        return {"previous": self.previous}

    def set_extra_state(self, state: dict) -> None:
        previous = state["previous"]
        self.previous = None if previous is None else tuple(previous)
