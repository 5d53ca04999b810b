"""`PPO`: proximal policy optimisation (Schulman et al. 2017) as an eye-movement agent.

A softmax policy and a value function over the cue's features (linear by default, as the natural
actor-critic's, or with one tanh hidden layer), trained with TorchRL's clipped surrogate loss
(`torchrl.objectives.ClipPPOLoss`) on TorchRL's generalised advantage estimates
(`torchrl.objectives.value.functional.generalized_advantage_estimate`). The agent collects the
transitions of ``fixations`` fixations of all B environments (a rollout of ``[B, T]``
transitions), then, at the fixation's end, computes the advantages of the rollout with the
value function of the moment (each fixation is one episode, cut by its time limit: its last
state's value is bootstrapped, nothing flows across fixations) and takes ``epochs`` passes of
``minibatches`` shuffled minibatches of Adam steps on the loss. The policy the rollout was
collected with is constant over the rollout (no update, and frozen feature statistics), so its
log-probabilities are recomputed exactly before the first step.

The features are z-scored with running statistics (as `NaturalActorCritic` does), which take in
each rollout's features after its update. Several processes that share a batch (``reduce``)
average their gradients, so they keep one policy.

TorchRL is an optional dependency (``pip install aectorch[rl]``): it is imported when a `PPO` is
built.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Optional, Sequence

import torch
from torch import Tensor, nn

from aectorch._checks import check_bool, check_int, check_real
from aectorch.control.agent import (DEFAULT_ACTIONS_DEG, ActOutput, LearnOutput, Reduce, Transitions, draw_uniform,
                                    entropy, sample_actions)
from aectorch.control.features import merge_moments, standardize

__all__ = ["PPO", "PPOConfig"]


@dataclass
class PPOConfig:
    """Hyperparameters of `PPO`.

    Attributes:
        lr: Adam's learning rate (> 0).
        epochs: passes over each rollout (>= 1).
        minibatches: minibatches per pass (>= 1; each holds ``B * T / minibatches`` transitions).
        clip: epsilon of the clipped surrogate objective (> 0).
        discount: gamma of the returns, in [0, 1] (the natural actor-critic's ``critic_discount``
            plays the same role; the improvement reward needs gamma < 1).
        gae_lambda: lambda of the generalised advantage estimates, in [0, 1].
        entropy_coef: weight of the entropy bonus (>= 0).
        value_coef: weight of the value loss (squared error; >= 0).
        max_grad_norm: gradients are clipped to this norm (> 0) before each step.
        normalize_advantage: standardise the advantages within each minibatch.
        fixations: fixations per rollout (>= 1): the agent learns after every this many.
        hidden: 0 (default): a linear policy and value function, as the natural actor-critic's;
            N > 0: each an MLP with one tanh hidden layer of N units.
        feature_norm: ``None``, or the norm (> 0) every z-scored feature vector is scaled to
            (default 3). With the cues' 864 z-scored features unscaled (norm about 29), one Adam
            step (each weight moves by about ``lr``) changes a logit by up to ``lr * sum |x_i|``,
            about 2 at ``lr = 0.003``: the vergence policy of ``learner.cues.stereo.agent=ppo``
            learned to 0.33 deg by iteration 1700 and then broke down to 2.0 deg by 2400
            (seed 0); with the norm scaled to 3 it ended at 0.147 deg, with 1 at 0.187 deg
            (CHANGELOG.md, the entry on PPO's z-scored features scaled to norm 3).
        normalize_eps: added to the variance of the z-scoring (> 0).
        actor_init: the policy's output weights start uniform in ``[-actor_init, actor_init]``
            (>= 0; biases at 0), a near-uniform policy.
        lr_decay: ``None`` (default: a constant learning rate), or tau (> 0): the u-th update
            (0-based) steps at ``lr * tau / (tau + u)``, as the natural actor-critic's
            ``actor_decay`` decays its actor, so the final policy is no snapshot of a constant-step
            walk (a run of 2400 iterations makes 80 updates).
        weight_decay: decoupled weight decay (AdamW's) of the policy's weights (>= 0; default 0:
            none; biases and the value function are never decayed). Each update multiplies the
            weights by ``1 - lr * weight_decay`` per Adam step, so a policy that the rewards stop
            pushing drifts back toward the uniform one instead of sharpening onto the training
            textures, as the lineage's AEC models keep their actors' weights small (Eckmann et al.
            2020: 0.04; Klimmasch et al. 2021).
        logit_penalty: weight (>= 0; default 0: none) of the mean squared centred logit
            (each state's logits less their mean) of the minibatch's states, added to the loss.
            Unlike the weight decay it pulls only where the policy is evaluated, and unlike the
            entropy bonus its gradient does not vanish where the policy has saturated (the
            entropy's gradient in a logit is ``-p (log p + H)``, about 0 once one action takes
            all the mass), so a state whose policy went deterministic becomes explorable again.
    """

    lr: float = 0.003
    epochs: int = 4
    minibatches: int = 4
    clip: float = 0.2
    discount: float = 0.3
    gae_lambda: float = 0.95
    entropy_coef: float = 0.01
    value_coef: float = 0.5
    max_grad_norm: float = 0.5
    normalize_advantage: bool = True
    fixations: int = 1
    hidden: int = 0
    feature_norm: Optional[float] = 3.0
    normalize_eps: float = 1e-8
    actor_init: float = 0.01
    lr_decay: Optional[float] = None
    weight_decay: float = 0.0
    logit_penalty: float = 0.0

    def __post_init__(self) -> None:
        owner = type(self).__name__
        for name in ("lr", "clip", "max_grad_norm", "normalize_eps"):
            check_real(getattr(self, name), f"{owner}.{name}", above=0)
        for name in ("entropy_coef", "value_coef", "actor_init", "weight_decay", "logit_penalty"):
            check_real(getattr(self, name), f"{owner}.{name}", minimum=0)
        for name in ("discount", "gae_lambda"):
            value = check_real(getattr(self, name), f"{owner}.{name}", minimum=0)
            if value > 1:
                raise ValueError(f"{owner}.{name} must be in [0, 1], got {value!r}")
        for name in ("epochs", "minibatches", "fixations"):
            check_int(getattr(self, name), f"{owner}.{name}", 1)
        check_int(self.hidden, f"{owner}.hidden", 0)
        check_bool(self.normalize_advantage, f"{owner}.normalize_advantage")
        for name in ("feature_norm", "lr_decay"):
            if getattr(self, name) is not None:
                check_real(getattr(self, name), f"{owner}.{name}", above=0)


def _torchrl():
    try:
        from tensordict import TensorDict
        from torchrl.modules import ProbabilisticActor
        from torchrl.objectives import ClipPPOLoss
        from torchrl.objectives.value.functional import generalized_advantage_estimate

        from aectorch.control._keyed import Keyed
    except ImportError as err:
        raise ImportError("the PPO agent needs TorchRL: pip install 'aectorch[rl]' (torchrl and tensordict)") from err
    return TensorDict, Keyed, ProbabilisticActor, ClipPPOLoss, generalized_advantage_estimate


def _network(inputs: int, outputs: int, hidden: int, init: float, generator, dtype, device) -> nn.Module:
    """A linear map, or an MLP with one tanh hidden layer; weights drawn from ``generator`` on the
    CPU (the same weights on any device), the output layer's uniform in +-``init``, biases 0."""
    def uniform(shape, bound):
        return ((2 * torch.rand(shape, generator=generator, dtype=dtype) - 1) * bound).to(device)

    out = nn.Linear(hidden or inputs, outputs, device=device, dtype=dtype)
    with torch.no_grad():
        out.weight.copy_(uniform(out.weight.shape, init))
        out.bias.zero_()
    if not hidden:
        return out
    layer = nn.Linear(inputs, hidden, device=device, dtype=dtype)
    with torch.no_grad():
        layer.weight.copy_(uniform(layer.weight.shape, 1.0 / math.sqrt(inputs)))
        layer.bias.zero_()
    return nn.Sequential(layer, nn.Tanh(), out)


class PPO(nn.Module):
    """Proximal policy optimisation over the discrete pan increments (see the module docstring).

    Args:
        num_features: length F of the feature vectors.
        actions_deg: the action set of pan increments in degrees (default `DEFAULT_ACTIONS_DEG`).
        config: hyperparameters (default `PPOConfig()`).
        generator: draws the initial weights and shuffles the minibatches (the cue's generator:
            its state is the learner's).
        dtype, device: of the networks.
        unscaled_features: the last this many features (a cue's proprioception) are z-scored but
            left out of the scaling to ``feature_norm`` (default 0: all scaled).
        **options: fields of `PPOConfig` that override ``config``.

    Attributes:
        policy: features -> action logits `[B, A]`.
        value: features -> state value `[B, 1]`.
        feature_count, feature_mean, feature_m2: the z-scoring's running moments.

    Example:
        >>> import torch
        >>> g = torch.Generator().manual_seed(0)
        >>> agent = PPO(8, (-0.1, 0.0, 0.1), generator=g, epochs=1)
        >>> f = torch.rand(4, 8, generator=g)
        >>> act = agent.act(f, uniform=torch.rand(4, generator=g))
        >>> out = agent.learn(Transitions(f, act.actions, torch.zeros(4), f, last=True))
        >>> out.td_error.shape, out.updated
        (torch.Size([4]), True)
    """

    #: The entries of the extra state that belong to each environment (batch first): a checkpoint
    #: of several processes joins them (`aectorch.framework.batch_state`).
    BATCH_STATE = ("rollout",)

    def __init__(self, num_features: int, actions_deg: Sequence[float] = DEFAULT_ACTIONS_DEG,
                 config: PPOConfig | None = None, *, generator: torch.Generator | None = None,
                 dtype: torch.dtype | None = None, device: torch.device | str | None = None,
                 unscaled_features: int = 0, **options) -> None:
        super().__init__()
        check_int(num_features, "num_features")
        self.unscaled_features = check_int(unscaled_features, "unscaled_features", 0)
        if unscaled_features > num_features:
            raise ValueError(f"unscaled_features must be <= num_features = {num_features}, got {unscaled_features}")
        config = PPOConfig() if config is None else config
        if not isinstance(config, PPOConfig):
            raise TypeError(f"config must be a PPOConfig or None, got {type(config).__name__}")
        self.config = cfg = dataclasses.replace(config, **options) if options else config
        actions = tuple(float(a) for a in actions_deg)
        if not actions:
            raise ValueError(f"actions_deg must be a non-empty sequence of numbers, got {actions_deg!r}")
        self.num_features, self.num_actions = num_features, len(actions)
        self.generator = generator or torch.Generator().manual_seed(0)
        dtype = dtype or torch.get_default_dtype()
        self.policy = _network(num_features, self.num_actions, cfg.hidden, cfg.actor_init, self.generator, dtype, device)
        self.value = _network(num_features, 1, cfg.hidden, 0.0, self.generator, dtype, device)
        like = self.value[-1].bias if cfg.hidden else self.value.bias
        self.register_buffer("actions_deg", torch.tensor(actions, dtype=dtype, device=like.device))
        self.register_buffer("feature_count", torch.zeros((), dtype=torch.int64, device=like.device))
        self.register_buffer("feature_mean", like.new_zeros(num_features))
        self.register_buffer("feature_m2", like.new_zeros(num_features))
        TensorDict, Keyed, ProbabilisticActor, ClipPPOLoss, gae = _torchrl()
        self._tensordict, self._gae = TensorDict, gae
        # The loss's categorical distributions skip torch's argument checks (the logits are the
        # policy's, the actions its own indices): the same numbers, fewer operations per step.
        actor = ProbabilisticActor(Keyed(self.policy, "observation", "logits"), in_keys=["logits"],
                                   distribution_class=torch.distributions.Categorical,
                                   distribution_kwargs={"validate_args": False}, return_log_prob=True)
        # The loss holds the networks through TorchRL's wrappers: not registered as a submodule, so
        # the state dict names them once (policy.*, value.*).
        self.__dict__["_loss"] = ClipPPOLoss(
            actor, Keyed(self.value, "observation", "state_value"), clip_epsilon=cfg.clip,
            entropy_coeff=cfg.entropy_coef, critic_coeff=cfg.value_coef, loss_critic_type="l2",
            normalize_advantage=cfg.normalize_advantage,
            # The same update without functional parameter copies or the explained-variance log,
            # which nothing reads.
            functional=False, log_explained_variance=False)
        parameters = list(self.policy.parameters()) + list(self.value.parameters())
        if cfg.weight_decay:  # AdamW's decoupled decay of the policy's weight matrices alone
            decayed = {id(p) for p in self.policy.parameters() if p.ndim > 1}
            self.__dict__["optimizer"] = torch.optim.AdamW(
                [{"params": [p for p in parameters if id(p) not in decayed], "weight_decay": 0.0},
                 {"params": [p for p in parameters if id(p) in decayed], "weight_decay": cfg.weight_decay}], lr=cfg.lr)
        else:
            self.__dict__["optimizer"] = torch.optim.Adam(parameters, lr=cfg.lr)
        self._rollout: list[Transitions] = []
        self.fixations_seen = 0
        # The update's large tensors' memory, kept from one update to the next (see _update).
        self._workspace: dict[str, Tensor] = {}

    def __getstate__(self) -> dict:
        """Copies and pickles leave the kept memory behind (nothing it holds is state)."""
        state = super().__getstate__() if hasattr(super(), "__getstate__") else self.__dict__
        return {**state, "_workspace": {}}

    def extra_repr(self) -> str:
        return f"num_features={self.num_features}, num_actions={self.num_actions}, config={self.config}"

    # -- the policy --------------------------------------------------------------------------------
    def normalize(self, features: Tensor) -> Tensor:
        """The features as the networks see them: z-scored (and scaled to ``feature_norm``)."""
        return self._standardize(features)

    def _standardize(self, features: Tensor, out: Tensor | None = None) -> Tensor:
        """`normalize`, written to ``out`` (which may be ``features``) when given."""
        return standardize(features.to(self.feature_mean.dtype), self.feature_count, self.feature_mean,
                           self.feature_m2, self.config.normalize_eps, self.config.feature_norm, out=out,
                           unscaled=self.unscaled_features)

    def _buffer(self, name: str, shape: tuple[int, ...], like: Tensor, dtype: torch.dtype | None = None) -> Tensor:
        """A contiguous tensor of ``shape`` (contents undefined) in memory kept under ``name``: the
        first elements of a flat buffer that grows when needed."""
        dtype = dtype or like.dtype
        numel = math.prod(shape)
        kept = self._workspace.get(name)
        if kept is None or kept.numel() < numel or kept.dtype != dtype or kept.device != like.device:
            kept = self._workspace[name] = torch.empty(numel, dtype=dtype, device=like.device)
        return kept[:numel].view(shape)

    def log_policy(self, features: Tensor) -> Tensor:
        """log pi(.|s), `[B, F]` -> `[B, A]`."""
        return torch.log_softmax(self.policy(self.normalize(features)), dim=-1)

    @torch.no_grad()
    def act(self, features: Tensor, greedy: bool = False, generator: torch.Generator | None = None, *,
            uniform: Tensor | None = None) -> ActOutput:
        """One action per environment (see `Agent.act`); changes no state."""
        if features.ndim != 2 or features.shape[1] != self.num_features:
            raise ValueError(f"features must have shape [B, {self.num_features}], got {tuple(features.shape)}")
        logp = self.log_policy(features)
        if greedy:
            actions = logp.argmax(dim=-1)
        else:
            if uniform is None:
                uniform = draw_uniform(features.shape[0], generator, logp)
            actions = sample_actions(logp, uniform.to(logp.dtype))
        return ActOutput(actions, self.actions_deg[actions], logp.gather(-1, actions[:, None]).squeeze(-1),
                         entropy(logp))

    # -- learning ----------------------------------------------------------------------------------
    def learn(self, transitions: Transitions, *, reduce: Reduce | None = None) -> LearnOutput:
        """Store the transitions; at the end of every ``fixations``-th fixation (``last``), learn
        from the rollout (see the module docstring). Returns the TD errors under the current value
        function."""
        t = transitions
        with torch.no_grad():
            value = self.value(self.normalize(t.features))[:, 0]
            next_value = self.value(self.normalize(t.next_features))[:, 0]
            td_error = t.rewards.to(value) + self.config.discount * next_value - value
        self._rollout.append(Transitions(*(u.detach() for u in t[:4]), last=bool(t.last)))
        if not t.last:
            return LearnOutput(td_error, False)
        self.fixations_seen += 1
        if self.fixations_seen % self.config.fixations:
            return LearnOutput(td_error, False)
        self._update(reduce)
        return LearnOutput(td_error, True)

    @torch.no_grad()
    def advantages(self, features: Tensor, next_features: Tensor, rewards: Tensor, last: Tensor) -> tuple[Tensor, Tensor]:
        """TorchRL's generalised advantage estimates and value targets of a rollout, `[B, T, 1]` each.

        Args:
            features, next_features: f(s) and f(s') of the rollout's transitions, `[B, T, F]`.
            rewards: `[B, T]`.
            last: `[T]` bool, True where a fixation ends (its next state's value is bootstrapped and
                no advantage flows back across it).
        """
        return self._advantages(self.normalize(features), self.normalize(next_features), rewards, last)

    @torch.no_grad()
    def _advantages(self, x: Tensor, next_x: Tensor, rewards: Tensor, last: Tensor) -> tuple[Tensor, Tensor]:
        """`advantages` of the z-scored features ``x``, ``next_x``."""
        value = self.value(x)
        next_value = self.value(next_x)
        done = last.to(torch.bool)[None, :, None].expand_as(value).clone()
        return self._gae(self.config.discount, self.config.gae_lambda, value, next_value,
                         rewards.to(value)[..., None], done, torch.zeros_like(done))

    def _update(self, reduce: Reduce | None) -> None:
        cfg, rollout = self.config, self._rollout
        # The rollout's large tensors, [B, T, F], live in memory kept from one update to the next
        # (fresh memory of that size is paid for in page faults at every update).
        first = rollout[0].features
        shape = (first.shape[0], len(rollout), first.shape[1])
        features = torch.stack([t.features for t in rollout], 1, out=self._buffer("features", shape, first))
        rewards = torch.stack([t.rewards for t in rollout], 1).to(features)
        actions = torch.stack([t.actions for t in rollout], 1)
        last = torch.tensor([t.last for t in rollout], device=features.device)
        # Each z-scored once (the statistics change at the update's end), in place where possible.
        dtype = self.feature_mean.dtype
        x = self._standardize(features, self._buffer("x", shape, first, dtype))
        next_x = self._buffer("next_x", shape, first, dtype)
        if first.dtype == dtype:
            next_x = self._standardize(torch.stack([t.next_features for t in rollout], 1, out=next_x), next_x)
        else:
            next_x = self._standardize(torch.stack([t.next_features for t in rollout], 1), next_x)
        advantage, target = self._advantages(x, next_x, rewards, last)
        with torch.no_grad():
            old = torch.log_softmax(self.policy(x), -1).gather(-1, actions[..., None])[..., 0]
        columns = {"observation": x.flatten(0, 1), "action": actions.flatten(), "action_log_prob": old.flatten(),
                   "advantage": advantage.flatten(0, 1), "value_target": target.flatten(0, 1)}
        rows = actions.numel()
        if cfg.lr_decay is not None:  # this is update fixations_seen / fixations - 1 (0-based)
            done = self.fixations_seen // cfg.fixations - 1
            for group in self.optimizer.param_groups:
                group["lr"] = cfg.lr * cfg.lr_decay / (cfg.lr_decay + done)
        parameters = [p for group in self.optimizer.param_groups for p in group["params"]]
        minibatches = min(cfg.minibatches, rows)  # a rollout smaller than that: one each
        size = rows // minibatches
        # Each epoch's shuffled rows, copied once into kept memory (next_x's: no longer needed);
        # its minibatches, consecutive slices, hold the same rows in the same order as
        # `batch[order[start:start + size]]` of the rollout's TensorDict.
        shuffled_x = next_x.flatten(0, 1)
        for _ in range(cfg.epochs):
            order = torch.randperm(rows, generator=self.generator).to(features.device)
            shuffled = self._tensordict({k: torch.index_select(v, 0, order, out=shuffled_x) if k == "observation"
                                         else v.index_select(0, order) for k, v in columns.items()},
                                        batch_size=[rows])
            for start in range(0, size * minibatches, size):
                losses = self._loss(shuffled[start:start + size])
                loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                if cfg.logit_penalty:
                    logits = self.policy(shuffled_x[start:start + size])
                    loss = loss + cfg.logit_penalty * (logits - logits.mean(-1, keepdim=True)).square().mean()
                self.optimizer.zero_grad(set_to_none=False)
                loss.backward()
                if reduce is not None:  # one policy over all processes: the mean gradient
                    world = reduce(torch.ones((), dtype=loss.dtype, device=loss.device))
                    for p in parameters:
                        p.grad.copy_(reduce(p.grad) / world)
                nn.utils.clip_grad_norm_(parameters, cfg.max_grad_norm)
                self.optimizer.step()
        stats = merge_moments(self.feature_count, self.feature_mean, self.feature_m2, features.flatten(0, 1), None,
                              reduce or (lambda t: t), workspace=next_x.flatten(0, 1) if first.dtype == dtype else None)
        for buffer, new in zip((self.feature_count, self.feature_mean, self.feature_m2), stats):
            buffer.copy_(new)
        self._rollout = []

    @torch.no_grad()
    def symmetrize_(self, feature_permutation: Tensor, action_negation: Tensor) -> None:
        """Start a linear policy and value function invariant under the cue's symmetry (means of
        themselves and their transforms); with a hidden layer the symmetry is learned from the
        transformed transitions alone."""
        if self.config.hidden:
            return
        w, b, v = self.policy.weight, self.policy.bias, self.value.weight
        w.copy_((w + w[action_negation][:, feature_permutation]) * 0.5)
        b.copy_((b + b[action_negation]) * 0.5)
        v.copy_((v + v[:, feature_permutation]) * 0.5)

    # -- checkpoints -------------------------------------------------------------------------------
    def get_extra_state(self) -> dict:
        """The optimizer's state, the rollout collected so far and the fixation count."""
        return {"optimizer": self.optimizer.state_dict(), "fixations_seen": self.fixations_seen,
                "rollout": [{"features": t.features, "actions": t.actions, "rewards": t.rewards,
                             "next_features": t.next_features, "last": t.last} for t in self._rollout]}

    def set_extra_state(self, state: dict) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        self.fixations_seen = int(state["fixations_seen"])
        device = self.feature_mean.device
        self._rollout = [Transitions(*(t[k].to(device) for k in ("features", "actions", "rewards", "next_features")),
                                     last=bool(t["last"])) for t in state["rollout"]]
