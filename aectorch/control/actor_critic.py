"""`NaturalActorCritic`: the eye-movement learner of the paper (sec. 2.3).

A linear softmax policy over a discrete set of pan increments (eqs. 7-8, with a
temperature T) and a linear critic, learned with the natural-gradient actor-critic
with advantage parameters of Bhatnagar, Sutton, Ghavamzadeh and Lee (2009),
"Natural actor-critic algorithms", Automatica 45(11), algorithm 3. Per transition
``(s, a, r, s')`` with critic features ``f = f(s)``, ``f' = f(s')``::

    J      <- (1 - xi) J + xi r                                 average reward
    delta  =  r - J + gamma v.f' - v.f                          TD error (new J, old v)
    v      <- v + alpha_v delta f                               critic
    w      <- w + alpha_w (delta psi - psi (psi.w))             advantage parameters
    theta  <- Gamma((1 - alpha_theta lambda) theta + alpha_theta w)   actor (new w)

with the compatible features of the softmax policy ``pi = softmax(theta f / T)``,
``psi = grad_theta log pi(a|s) = (e_a - pi) f^T / T``. ``psi psi^T w`` is computed
as ``psi (psi.w)``: no F x F matrix is formed. The order of the lines is the
paper's: J is updated first and the TD error uses the new J and the old critic;
the actor step uses the new w.

The paper-faithful form (:meth:`ActorCriticConfig.paper_form`) has ``gamma = 1``,
``lambda = 0``, ``alpha_w = alpha_v`` (the paper has one fast step size alpha_t for v and w) and
Gamma a Euclidean projection onto a compact convex set, here the ball
``||theta||_F <= theta_bound`` (or the box ``|theta_ij| <= theta_bound``). The
variants of the MATLAB AEC lineage are options of `ActorCriticConfig`: a
discounted ``V(s')`` (``critic_discount``), weight decay instead of the projection
(``weight_decay`` with ``projection="none"``), a separate ``alpha_w``, online
z-scoring of the features (``normalize_features``), and, per call of
`NaturalActorCritic.update`, no update on the first step of a fixation (the
``first_step`` mask). The defaults are the values `aectorch.framework.JointLearner` trains
with (docs/paper-mapping.md says why each differs from the paper-faithful form).

Batched rule (B environments, one shared learner): every environment computes its
sequential step from the same shared state (its own ``J_b = (1 - xi) J + xi r_b``
enters its own TD error ``delta_b``); J, v and w move by the mean of the B
per-environment increments, and the actor then takes its step with that mean w.
The actor step is affine in w, so before Gamma this is also the mean of the B
per-environment actor steps; Gamma is applied once, to the mean. With B = 1 this
is the sequential algorithm. Environments masked by ``first_step`` are left out
of the means (mean over the environments that update; nothing moves when none does).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, NamedTuple, Optional, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from aectorch._checks import check_bool, check_finite, check_int, is_int, is_real
from aectorch.control.features import merge_moments, scale_to_norm, standardize
from aectorch.control.agent import (
    DEFAULT_ACTIONS_DEG, ActOutput, LearnOutput, Reduce, Transitions, draw_uniform, entropy, sample_actions,
)

__all__ = ["ActOutput", "ActorCriticConfig", "NaturalActorCritic", "UpdateOutput"]

_PROJECTIONS = ("ball", "box", "none")


@dataclass
class ActorCriticConfig:
    """Hyperparameters of `NaturalActorCritic`; the defaults are those the joint learner trains with.

    The 2017 paper gives no step sizes. The defaults (docs/paper-mapping.md) are the lineage's
    z-scored features (Welford) scaled to norm ``feature_norm`` = 30 with a critic step
    ``alpha_v`` = 0.001 for that norm, a near-zero initial policy (``actor_init`` 0.01), the
    critic discounted by 0.3 (the lineage's 0.3-0.6; the improvement reward needs gamma < 1), a
    fast actor (the advantage parameters w estimate the advantage, the actor follows them with
    step 10, decaying over ``actor_decay`` = 1000 full steps) and steps meant for the mean of
    ``batch_reference`` = 64 transitions.

    :meth:`paper_form` is algorithm 3 as the paper states it with the constant step sizes of the
    older discrete natural-actor-critic AEC models (``aec-lineage.md``): alpha_v = alpha_w = 0.4,
    xi = 0.01, and alpha_theta = 0.04 = alpha_v / 10, which puts the actor on the slower time
    scale that Bhatnagar et al.'s convergence proof needs (decaying step sizes with
    ``sum alpha = inf``, ``sum alpha^2 < inf``, ``alpha_theta / alpha_v -> 0`` and
    ``xi = c alpha_v``; constant step sizes, as every AEC model used, only track that ideal). On
    the angle-error toy of the tests, alpha_theta = 0.4 ends farther than 0.05 degrees from zero
    for 3 to 6 of 10 seeds after 1000 to 2000 steps; 0.04 ends within it for all 10.

    The step sizes act on the features as given: with ``alpha_v ||f||^2 >= 2`` the
    critic diverges, so scale the features to a norm of about 1 (the pooled
    activities of eq. 3 are far larger) or the step sizes down. They apply per
    update call, to the mean of the B per-environment increments.

    The natural gradient of a softmax policy does not vanish as the policy becomes
    deterministic, so theta grows without bound unless Gamma (or weight decay)
    stops it; Bhatnagar et al. need a compact set and leave its shape and size
    open. On the ball, theta settles in the direction of w: a Boltzmann policy over
    the compatible advantages, which keeps the greedy action. The box clamps every
    weight alone, so two actions can tie at the bound (seen on a contextual bandit).
    Weight decay ``lambda`` is the soft form of the ball (theta tends to ``w / lambda``).

    Attributes:
        alpha_v: critic step size alpha (> 0).
        alpha_w: step size of the advantage parameters w (> 0); ``None`` uses
            ``alpha_v`` as in the paper. A separate value is a lineage variant
            (e.g. 0.025 with alpha_v 0.75).
        alpha_theta: actor step size beta (> 0).
        xi: average-reward rate, in (0, 1].
        temperature: softmax temperature T of the policy while learning (> 0);
            the compatible features carry the same 1/T. The lineage: 1.
        critic_discount: gamma multiplying ``V(s')`` in the TD error, in [0, 1] (default 0.3);
            1 is the paper (average reward, undiscounted); the lineage used 0.3-0.6.
        projection: Gamma, the projection of the actor step: ``"ball"`` (default,
            ``theta <- theta min(1, theta_bound / ||theta||_F)``), ``"box"``
            (``clamp(theta, -theta_bound, theta_bound)``) or ``"none"``.
        theta_bound: radius of the ball or half-width of the box (> 0). It bounds
            every logit by ``theta_bound ||f|| / T`` (ball); 100 is loose for features
            of norm about 1.
        weight_decay: lambda of the actor step ``(1 - alpha_theta lambda) theta``
            (>= 0, with ``alpha_theta * lambda <= 1``); the lineage used 0.01-0.04
            with no projection (``projection="none"``). 0 is the paper.
        normalize_features: z-score every feature online (default on), ``(f - mean) /
            sqrt(var + normalize_eps)``, for both the actor and the critic (a lineage
            variant). The running mean and sample variance (Welford's algorithm,
            batches merged with Chan's formula) are buffers; `update` adds the
            features of s of the environments that update *after* learning from
            them, so `act` and `update` of one step use the same statistics. Before
            two samples the variance is taken as 1 (before one, the mean as 0).
        normalize_eps: added to the variance of the z-scoring (> 0). A feature that has
            barely varied yet is divided by about its square root: raise it for
            features that are constant for a while.
        normalize_window: ``None`` (default: every sample counts alike, the plain running
            z-score), or the number of samples (>= 2) the z-scoring's statistics remember: once
            that many are in, the count stays there and older samples are down-weighted
            geometrically (each update merges the batch into statistics of at most this weight).
            The dictionaries keep learning, so the features' distribution drifts; with every
            sample weighted alike the statistics follow it ever more slowly.
        normalize_samples: ``None`` (default: the statistics take in every sample, for ever), or
            the number of samples (>= 2) after which the z-scoring's statistics stop changing.
            The features' distribution follows the policy and the dictionaries, so statistics that
            keep moving change what a fixed actor does (measured: with the actor and the
            dictionaries frozen, the pursuit window still drifted from 0.12 to 0.18 deg as the
            statistics moved); frozen, the z-scoring is a fixed map the actor can settle on.
        feature_norm: ``None``, or a norm (default 30) every feature vector the actor and critic see
            is scaled to, after the z-scoring if that is on (> 0). The critic's step is stable
            only while ``alpha_v ||f||^2 < 2``; z-scored features of unusual states (an eye far
            off its target) can be several times longer than the typical ones, and a fixed norm
            keeps every step inside the bound (the normalised-LMS form of the TD step).
        batch_reference: ``None`` (every update takes its full step on the mean of its
            transitions), or the number of transitions (>= 1; default 64) the step sizes are meant for: an
            update from ``n < batch_reference`` transitions moves J, v, w and theta by
            ``n / batch_reference`` of its step, as the per-transition steps of a batch of
            ``batch_reference`` would, so a small batch (B = 1, the sequential algorithm) takes
            no larger steps per transition than the batch the steps were chosen with; larger
            batches take the full step on their (less noisy) mean.
        actor_decay: ``None`` (a constant actor step, as every AEC model ran), or tau
            (> 0; default 1000): the actor's step decays as ``alpha_theta * (tau / (tau + t)) ** actor_decay_power``,
            where t counts the updates so far in units of full steps (an update scaled by
            ``batch_reference`` counts as that fraction of one). The critic and w keep their
            constant steps, so the actor becomes ever slower than the critic
            (``alpha_theta / alpha_v -> 0``, as Bhatnagar et al.'s convergence needs).
        actor_decay_power: p of ``actor_decay`` (> 0). 1 is the harmonic decay of stochastic
            approximation (``sum alpha_theta = inf``: the actor never stops); p > 1 makes the
            actor's whole path finite, ``alpha_theta * tau / (p - 1)``, so the policy converges to
            a fixed point instead of drifting on.
        actor_floor: ``None`` (default), or a fraction in (0, 1]: the decaying actor step falls
            no lower than ``actor_floor * alpha_theta`` (a perturbation experiment's choice of
            plasticity, ``plasticity=floor``).
        actor_init: initial actor weights are uniform in ``[-actor_init, actor_init]``
            (>= 0; default 0.01; lineage 0.4; the paper: "initially random").
        critic_init: initial critic weights are uniform in ``[-critic_init,
            critic_init]`` (>= 0; default 0; lineage 0.05). The advantage parameters start at 0.
    """

    alpha_v: float = 0.001
    alpha_w: Optional[float] = None
    alpha_theta: float = 10.0
    xi: float = 0.01
    temperature: float = 1.0
    critic_discount: float = 0.3
    projection: str = "ball"
    theta_bound: float = 100.0
    weight_decay: float = 0.0
    normalize_features: bool = True
    normalize_eps: float = 1e-8
    normalize_window: Optional[int] = None
    normalize_samples: Optional[int] = None
    feature_norm: Optional[float] = 30.0
    batch_reference: Optional[int] = 64
    actor_decay: Optional[float] = 1000.0
    actor_decay_power: float = 1.0
    actor_floor: Optional[float] = None
    actor_init: float = 0.01
    critic_init: float = 0.0

    @classmethod
    def paper_form(cls, **overrides) -> "ActorCriticConfig":
        """Algorithm 3 as the paper states it, with the older AEC models' constant step sizes
        (see the class docstring): undiscounted, raw features, constant steps; ``overrides``
        replace fields."""
        form = dict(alpha_v=0.4, alpha_theta=0.04, critic_discount=1.0, normalize_features=False,
                    feature_norm=None, batch_reference=None, actor_decay=None, actor_init=0.4, critic_init=0.05)
        return cls(**{**form, **overrides})

    def __post_init__(self) -> None:
        owner = type(self).__name__

        def require(name: str, ok, expected: str) -> None:
            value = getattr(self, name)
            if not (is_real(value) and ok(value)):
                raise ValueError(f"{owner}.{name} must be {expected}, got {value!r}")

        positive = (lambda x: x > 0), "a finite float > 0"
        non_negative = (lambda x: x >= 0), "a finite float >= 0"
        for name in ("alpha_v", "alpha_theta", "temperature", "theta_bound", "normalize_eps", "actor_decay_power"):
            require(name, *positive)
        for name in ("weight_decay", "actor_init", "critic_init"):
            require(name, *non_negative)
        if self.alpha_w is not None:
            require("alpha_w", positive[0], "None or a finite float > 0")
        if self.feature_norm is not None:
            require("feature_norm", positive[0], "None or a finite float > 0")
        if self.actor_decay is not None:
            require("actor_decay", positive[0], "None or a finite float > 0")
        if self.actor_floor is not None:
            require("actor_floor", lambda x: 0 < x <= 1, "None or a fraction in (0, 1]")
        if self.normalize_window is not None and not (is_int(self.normalize_window) and self.normalize_window >= 2):
            raise ValueError(f"{owner}.normalize_window must be None or an int >= 2, got {self.normalize_window!r}")
        if self.batch_reference is not None and not (is_int(self.batch_reference) and self.batch_reference >= 1):
            raise ValueError(f"{owner}.batch_reference must be None or an int >= 1, got {self.batch_reference!r}")
        if self.normalize_samples is not None and not (
            is_int(self.normalize_samples) and self.normalize_samples >= 2
        ):
            raise ValueError(f"{owner}.normalize_samples must be None or an int >= 2, got {self.normalize_samples!r}")
        if self.projection not in _PROJECTIONS:
            raise ValueError(
                f"{owner}.projection must be one of {', '.join(map(repr, _PROJECTIONS))}, "
                f"got {self.projection!r}"
            )
        require("xi", lambda x: 0 < x <= 1, "a float in (0, 1]")
        require("critic_discount", lambda x: 0 <= x <= 1, "a float in [0, 1]")
        check_bool(self.normalize_features, f"{owner}.normalize_features")
        if self.alpha_theta * self.weight_decay > 1:
            raise ValueError(
                f"{owner}.alpha_theta * weight_decay must be <= 1 (the decay factor "
                f"1 - alpha_theta * weight_decay would flip the sign of theta), got "
                f"{self.alpha_theta} * {self.weight_decay}"
            )

    @property
    def step_w(self) -> float:
        """The step size of w actually used (``alpha_w``, or ``alpha_v`` when that is ``None``)."""
        return self.alpha_v if self.alpha_w is None else self.alpha_w


class UpdateOutput(NamedTuple):
    """What `NaturalActorCritic.update` returns (all computed before the weights move).

    Attributes:
        td_error: delta per environment, `[B]` (also for environments that did not update).
        average_reward: J after the update, `[]`.
        value: ``v.f(s)``, `[B]`.
        next_value: ``v.f(s')`` (undiscounted), `[B]`.
        advantage: the compatible advantage estimate ``psi.w``, `[B]`.
        entropy: entropy in nats of the learning policy ``pi(.|s)``, `[B]`.
        updated: which environments contributed to the update, `[B]` bool.
    """

    td_error: torch.Tensor
    average_reward: torch.Tensor
    value: torch.Tensor
    next_value: torch.Tensor
    advantage: torch.Tensor
    entropy: torch.Tensor
    updated: torch.Tensor


class NaturalActorCritic(nn.Module):
    """Linear softmax actor and linear critic learned by Bhatnagar et al.'s algorithm 3.

    The learner is shared by B environments; see the module docstring for the
    rule, its variants and the batched form. Weights are updated in place by the
    rule under ``torch.no_grad`` (they are `nn.Parameter` with
    ``requires_grad=False``); everything that defines the learner, J and the
    z-scoring statistics included, is in the `state_dict`.

    Args:
        num_features: length F of the feature vector f(s) (the paper: 2 x 288).
        actions_deg: the action set A of pan increments in degrees (default
            `DEFAULT_ACTIONS_DEG`; the paper's seven: `PAPER_ACTIONS_DEG`).
        config: hyperparameters (default: `ActorCriticConfig()`; the paper-faithful form:
            `ActorCriticConfig.paper_form()`).
        generator: optional `torch.Generator` for the initial actor and critic weights.
        dtype, device: of the weights (default: torch's defaults). Inputs are cast to
            this dtype and must be on this device.
        unscaled_features: the last this many features (a cue's proprioception) are left out
            of the scaling to ``feature_norm`` (default 0: all scaled).
        **options: fields of `ActorCriticConfig` that override `config`, e.g.
            ``alpha_v=0.1``.

    Attributes:
        actor_weight: theta, `[A, F]` (row a is w_a of eq. 8).
        critic_weight: v, `[F]`.
        advantage_weight: w, `[A, F]`.
        average_reward: J, `[]`.
        feature_count, feature_mean, feature_m2: Welford state of the z-scoring.

    Shape:
        act: features `[B, F]` -> `ActOutput` of `[B]` tensors.
        update: features, next_features `[B, F]`; actions `[B]` int; rewards `[B]`;
        first_step `[B]` bool -> `UpdateOutput`.

    Example:
        >>> import torch
        >>> from aectorch.control import NaturalActorCritic
        >>> g = torch.Generator().manual_seed(0)
        >>> agent = NaturalActorCritic(576, generator=g, alpha_v=0.05)
        >>> f = torch.rand(4, 576, generator=g) / 24
        >>> out = agent.act(f, generator=g)
        >>> out.actions.shape, out.increments_deg.dtype
        (torch.Size([4]), torch.float32)
        >>> f_next = torch.rand(4, 576, generator=g) / 24
        >>> step = agent.update(f, out.actions, -torch.rand(4, generator=g), f_next)
        >>> step.td_error.shape, step.average_reward.shape
        (torch.Size([4]), torch.Size([]))
        >>> agent.act(f, greedy=True).actions.shape
        torch.Size([4])
    """

    def __init__(
        self,
        num_features: int,
        actions_deg: Sequence[float] = DEFAULT_ACTIONS_DEG,
        config: ActorCriticConfig | None = None,
        *,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
        unscaled_features: int = 0,
        **options,
    ) -> None:
        super().__init__()
        check_int(num_features, "num_features")
        self.unscaled_features = check_int(unscaled_features, "unscaled_features", 0)
        if unscaled_features > num_features:
            raise ValueError(f"unscaled_features must be <= num_features = {num_features}, got {unscaled_features}")
        actions = tuple(actions_deg) if not isinstance(actions_deg, torch.Tensor) else tuple(
            actions_deg.tolist()
        )
        if len(actions) < 1 or not all(is_real(a) for a in actions):
            raise ValueError(
                f"actions_deg must be a non-empty sequence of finite floats, got {actions_deg!r}"
            )
        if config is None:
            config = ActorCriticConfig()
        elif not isinstance(config, ActorCriticConfig):
            raise TypeError(f"config must be an ActorCriticConfig or None, got {type(config).__name__}")
        fields = {f.name for f in dataclasses.fields(ActorCriticConfig)}
        unknown = sorted(set(options) - fields)
        if unknown:
            raise TypeError(
                f"unexpected keyword argument(s) {unknown}; options must be fields of "
                f"ActorCriticConfig: {sorted(fields)}"
            )
        self.config = dataclasses.replace(config, **options) if options else config
        self.num_features = num_features
        self.num_actions = len(actions)
        cfg = self.config

        def uniform(shape: tuple[int, ...], bound: float) -> torch.Tensor:
            # Drawn on the CPU so that a CPU generator gives the same weights on any device.
            u = torch.rand(shape, generator=generator, dtype=dtype, device="cpu")
            return ((2 * u - 1) * bound).to(device)

        theta = uniform((self.num_actions, num_features), cfg.actor_init)
        theta = _project(theta, cfg.projection, cfg.theta_bound)  # start inside the set of Gamma
        critic = uniform((num_features,), cfg.critic_init)
        self.actor_weight = nn.Parameter(theta, requires_grad=False)
        self.critic_weight = nn.Parameter(critic, requires_grad=False)
        self.advantage_weight = nn.Parameter(torch.zeros_like(theta), requires_grad=False)
        self.register_buffer("actions_deg", torch.tensor(actions, dtype=theta.dtype, device=theta.device))
        self.register_buffer("average_reward", theta.new_zeros(()))
        self.register_buffer("feature_count", torch.zeros((), dtype=torch.int64, device=theta.device))
        self.register_buffer("feature_mean", theta.new_zeros(num_features))
        self.register_buffer("feature_m2", theta.new_zeros(num_features))
        # Updates so far, in units of full steps (the actor's decay; `actor_decay`).
        self.register_buffer("step_count", torch.zeros((), dtype=torch.float64, device=theta.device))

    def extra_repr(self) -> str:
        return f"num_features={self.num_features}, num_actions={self.num_actions}, config={self.config}"

    # ------------------------------------------------------------------ checks
    def _features(self, features: torch.Tensor, name: str, check: bool) -> torch.Tensor:
        if not isinstance(features, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(features).__name__}")
        if features.ndim != 2 or features.shape[1] != self.num_features:
            raise ValueError(
                f"{name} must have shape [B, {self.num_features}], got {tuple(features.shape)}"
            )
        if not features.is_floating_point():
            raise TypeError(f"{name} must be a floating-point tensor, got {features.dtype}")
        self._same_device(features, name)
        if check:
            check_finite(features, name)
        return features.to(self.actor_weight.dtype)

    def _same_device(self, tensor: torch.Tensor, name: str) -> None:
        if tensor.device != self.actor_weight.device:
            raise ValueError(
                f"{name} must be on the module's device {self.actor_weight.device}, got {tensor.device}"
            )

    def _per_env(self, tensor: torch.Tensor, name: str, batch: int) -> None:
        if not isinstance(tensor, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
        if tuple(tensor.shape) != (batch,):
            raise ValueError(
                f"{name} must have shape [{batch}] (one per environment), got {tuple(tensor.shape)}"
            )
        self._same_device(tensor, name)

    # ------------------------------------------------------------------ policy
    def normalize(self, features: torch.Tensor) -> torch.Tensor:
        """The features as the actor and critic see them: z-scored and scaled to ``feature_norm``
        when enabled, else unchanged.

        Shape:
            features `[B, F]` -> `[B, F]` (no checks, no statistics update).
        """
        cfg = self.config
        x = features
        if cfg.normalize_features:
            x = standardize(features, self.feature_count, self.feature_mean, self.feature_m2, cfg.normalize_eps)
        if cfg.feature_norm is not None:
            x = scale_to_norm(x, cfg.feature_norm, self.unscaled_features)
        return x

    def _log_policy(self, x: torch.Tensor, temperature: float) -> torch.Tensor:
        return torch.log_softmax(x @ self.actor_weight.t() / temperature, dim=-1)

    def forward(self, features: torch.Tensor, *, temperature: float | None = None) -> torch.Tensor:
        """The policy pi(.|s) of eqs. (7)-(8), `[B, F]` -> action probabilities `[B, A]`."""
        x = self.normalize(self._features(features, "features", check=False))
        return self._log_policy(x, self._temperature(temperature)).exp()

    def log_policy(self, features: torch.Tensor) -> torch.Tensor:
        """log pi(.|s) at the learning temperature (what `act` samples from), `[B, F]` -> `[B, A]`."""
        x = self.normalize(self._features(features, "features", check=False))
        return self._log_policy(x, self.config.temperature)

    @torch.no_grad()
    def value(self, features: torch.Tensor) -> torch.Tensor:
        """The critic's value ``v.f(s)``, `[B, F]` -> `[B]`."""
        return self.normalize(self._features(features, "features", check=False)) @ self.critic_weight

    def _temperature(self, temperature: float | None) -> float:
        if temperature is None:
            return self.config.temperature
        if not (is_real(temperature) and temperature > 0):
            raise ValueError(f"temperature must be a finite float > 0 or None, got {temperature!r}")
        return float(temperature)

    @torch.no_grad()
    def act(
        self,
        features: torch.Tensor,
        greedy: bool = False,
        generator: torch.Generator | None = None,
        *,
        temperature: float | None = None,
        uniform: torch.Tensor | None = None,
        check: bool = True,
    ) -> ActOutput:
        """Choose one action per environment.

        Sampling draws one uniform number per environment (``torch.rand`` with
        `generator`) and inverts the policy's cumulative distribution, so a seeded
        generator reproduces the actions. Changes no state.

        Args:
            features: f(s), `[B, F]`.
            greedy: take the most probable action (the first on ties) instead of sampling.
            generator: `torch.Generator` on the features' device for sampling
                (default: torch's global generator).
            temperature: softmax temperature for this call (default: the learning
                temperature of the config; the lineage tested greedy or at T = 0.1).
            uniform: the uniform numbers in [0, 1) to sample with, `[B]`, instead of
                drawing them from `generator` (torch.compile cannot trace a
                `torch.Generator` argument; draw them outside the compiled call).
            check: check that the features are finite (a host sync; skipped under
                torch.compile). Shapes are always checked.

        Returns:
            `ActOutput` of `[B]` tensors.
        """
        t = self._temperature(temperature)
        x = self.normalize(self._features(features, "features", check))
        logp = self._log_policy(x, t)
        if greedy:
            actions = logp.argmax(dim=-1)
        else:
            if uniform is None:
                u = draw_uniform(x.shape[0], generator, x)
            else:
                self._per_env(uniform, "uniform", x.shape[0])
                u = uniform.to(x.dtype)
            actions = sample_actions(logp, u)
        log_prob = logp.gather(-1, actions[:, None]).squeeze(-1)
        return ActOutput(actions, self.actions_deg[actions], log_prob, entropy(logp))

    # ------------------------------------------------------------------ learning
    # long: the batched update of algorithm 3, step by step in the module docstring's order (TD
    # error, critic, advantage weights, actor, feature statistics); split, it would no longer read
    # as the equations it implements.
    @torch.no_grad()
    def update(
        self,
        features: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
        next_features: torch.Tensor,
        first_step: torch.Tensor | None = None,
        *,
        check: bool = True,
        reduce: Callable[[torch.Tensor], torch.Tensor] | None = None,
    ) -> UpdateOutput:
        """One step of algorithm 3 from the transitions ``(s, a, r, s')`` of B environments.

        Args:
            features: f(s), `[B, F]`.
            actions: indices of the actions taken in s, `[B]` integer.
            rewards: r received on the transition, `[B]`.
            next_features: f(s'), `[B, F]`.
            first_step: `[B]` bool, True where the transition is the first step of a
                fixation and must not be learned from (a lineage variant); those
                environments change nothing. ``None`` (the paper): all update.
            check: check that inputs are finite and actions in range (a host sync;
                skipped under torch.compile). Shapes are always checked.
            reduce: for a batch split across processes (`aectorch.runtime.distributed`): sums a tensor
                over all of them (an all-reduce). Every mean over environments then runs over
                the whole batch, so each process takes the same step as one process with all the
                environments would. ``None``: this batch is the whole batch.

        Returns:
            `UpdateOutput`; see the module docstring for the rule and its batched form.
        """
        cfg = self.config
        f = self._features(features, "features", check)
        f_next = self._features(next_features, "next_features", check)
        batch = f.shape[0]
        if f_next.shape[0] != batch:
            raise ValueError(
                f"next_features must have the batch size of features ({batch}), got {f_next.shape[0]}"
            )
        self._per_env(actions, "actions", batch)
        if actions.is_floating_point() or actions.is_complex() or actions.dtype == torch.bool:
            raise TypeError(f"actions must be an integer tensor, got {actions.dtype}")
        self._per_env(rewards, "rewards", batch)
        if not rewards.is_floating_point():
            raise TypeError(f"rewards must be a floating-point tensor, got {rewards.dtype}")
        if first_step is not None:
            self._per_env(first_step, "first_step", batch)
            if first_step.dtype != torch.bool:
                raise TypeError(f"first_step must be a bool tensor, got {first_step.dtype}")
        if check and not torch.compiler.is_compiling():
            check_finite(rewards, "rewards")
            if not bool(((actions >= 0) & (actions < self.num_actions)).all()):
                raise ValueError(
                    f"actions must be indices in [0, {self.num_actions}), got values in "
                    f"[{int(actions.min())}, {int(actions.max())}]"
                )
        r = rewards.to(f.dtype)
        actions = actions.long()

        # Mean over the environments that update: weights 1/n on them, 0 elsewhere.
        total = (lambda t: t) if reduce is None else reduce
        if first_step is None and reduce is None:
            updated = torch.ones(batch, dtype=torch.bool, device=f.device)
            weight = f.new_full((batch,), 1.0 / batch)
            any_update = f.new_ones(())
            count = f.new_full((), float(batch))
        else:
            updated = torch.ones(batch, dtype=torch.bool, device=f.device) if first_step is None else ~first_step
            count = total(updated.sum())
            weight = updated.to(f.dtype) / count.clamp_min(1).to(f.dtype)
            any_update = (count > 0).to(f.dtype)
        if cfg.batch_reference is not None:  # a small batch takes the per-transition steps
            scale = (count.to(f.dtype) / cfg.batch_reference).clamp_max(1)
            weight = weight * scale
            any_update = any_update * scale

        theta, v, w = self.actor_weight, self.critic_weight, self.advantage_weight
        j = self.average_reward
        t = cfg.temperature
        x, x_next = self.normalize(f), self.normalize(f_next)

        j_env = j + cfg.xi * (r - j)  # each environment's own J_{t+1}
        value, next_value = x @ v, x_next @ v
        delta = r - j_env + cfg.critic_discount * next_value - value

        logp = self._log_policy(x, t)
        # psi_b = g_b f_b^T / T with g_b = e_a - pi; psi_b.w = g_b.(w f_b) / T.
        g = F.one_hot(actions, self.num_actions).to(x.dtype) - logp.exp()
        advantage = (g * (x @ w.t())).sum(-1) / t
        coeff = weight * (delta - advantage)

        # Every new value is computed before any is written: one read phase, one write phase.
        # (torch 2.13's inductor misordered a read of w after its in-place update otherwise.)
        j_new = j + total((weight * (j_env - j)).sum())
        v_new = v + cfg.alpha_v * total((weight * delta) @ x)
        w_new = w + (cfg.step_w / t) * total((coeff[:, None] * g).t() @ x)
        step = cfg.alpha_theta * any_update
        steps_new = self.step_count + any_update.to(self.step_count.dtype)
        if cfg.actor_decay is not None:
            decay = (cfg.actor_decay / (cfg.actor_decay + self.step_count)) ** cfg.actor_decay_power
            if cfg.actor_floor is not None:
                decay = decay.clamp_min(cfg.actor_floor)
            step = step * decay.to(step.dtype)
        theta_new = theta * (1 - step * cfg.weight_decay) + step * w_new
        theta_new = _project(theta_new, cfg.projection, cfg.theta_bound)
        if cfg.normalize_features:
            stats = merge_moments(self.feature_count, self.feature_mean, self.feature_m2, f, updated, total,
                                  cfg.normalize_window)
        j.view(1).copy_(j_new.view(1))  # a 0-dim float64 buffer's copy_ is lost under torch.compile
        v.copy_(v_new)
        w.copy_(w_new)
        theta.copy_(theta_new)
        self.step_count.view(1).copy_(steps_new.view(1))
        if cfg.normalize_features:
            if cfg.normalize_samples is not None:  # full statistics stay as they are
                full = self.feature_count >= cfg.normalize_samples
                old = (self.feature_count, self.feature_mean, self.feature_m2)
                stats = tuple(torch.where(full, o, n) for o, n in zip(old, stats))
            for buffer, new in zip((self.feature_count, self.feature_mean, self.feature_m2), stats):
                buffer.view(-1).copy_(new.view(-1))
        return UpdateOutput(delta, j_new, value, next_value, advantage, entropy(logp), updated)

    def learn(self, transitions: Transitions, *, reduce: Reduce | None = None) -> LearnOutput:
        """The `Agent` protocol's step: one :meth:`update` from the batch (algorithm 3 learns from
        every transition as it comes; ``last`` changes nothing)."""
        t = transitions
        out = self.update(t.features, t.actions, t.rewards, t.next_features, check=False, reduce=reduce)
        return LearnOutput(out.td_error, True)

    @torch.no_grad()
    def raise_rate(self, fraction: float) -> float:
        """Make the actor plastic again: a decayed actor step (``actor_decay``) is raised to
        ``fraction`` (in (0, 1]) of ``alpha_theta`` by winding its step count back, from where it
        decays again (a larger step stays). Returns the actor step's factor now."""
        cfg = self.config
        if not (is_real(fraction) and 0 < fraction <= 1):
            raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
        if cfg.actor_decay is None:
            return 1.0
        count = cfg.actor_decay * (fraction ** (-1.0 / cfg.actor_decay_power) - 1.0)
        self.step_count.clamp_(max=count)
        factor = (cfg.actor_decay / (cfg.actor_decay + float(self.step_count))) ** cfg.actor_decay_power
        return factor if cfg.actor_floor is None else max(factor, cfg.actor_floor)

    @torch.no_grad()
    def symmetrize_(self, feature_permutation: torch.Tensor, action_negation: torch.Tensor) -> None:
        """Start the policy and the critic invariant under a symmetry: theta and v become the means of
        themselves and their transforms (features permuted by ``feature_permutation``, actions by
        ``action_negation``), so transformed states get the negated actions' probabilities."""
        theta, v = self.actor_weight, self.critic_weight
        theta.copy_((theta + theta[action_negation][:, feature_permutation]) * 0.5)
        v.copy_((v + v[feature_permutation]) * 0.5)



def _project(theta: torch.Tensor, projection: str, bound: float) -> torch.Tensor:
    """Gamma: the Euclidean projection onto the ball or the box of size `bound` (or none)."""
    if projection == "ball":
        # A uniform rescaling: the order of the logits, so the greedy action, survives it.
        norm = torch.linalg.vector_norm(theta)
        return theta * (bound / norm.clamp_min(torch.finfo(theta.dtype).tiny)).clamp_max(1)
    if projection == "box":
        return theta.clamp(-bound, bound)
    return theta
