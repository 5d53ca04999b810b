"""``JointLearner``: the paper's joint learning framework (sections 2-3), batched over B environments.

It composes the three learners and drives an :class:`~aectorch.sim.ActiveDepthEnv`:

- two :class:`~aectorch.coding.BinocularEncoder` s, one per depth cue: motion parallax (*m*:
  the dominant eye before and after the body shift) and stereo (*s*: both eyes), each with a
  dictionary per scale (the paper's coarse and fine scale, and by default a wider one);
- two :class:`~aectorch.control.NaturalActorCritic` s: pursuit of the dominant eye (fed by cue
  *m*) and vergence of the other eye (fed by cue *s*);
- the :class:`~aectorch.depth.DepthMLP`, retrained with our Levenberg-Marquardt on the final eye
  movements ``q`` of the trials seen so far.

One :meth:`JointLearner.iteration` advances every environment by one iteration:

**step k1** parallax observation -> encode -> features f_m and reward R_m = -(e^C + e^F)
-> critic/actor update for the previous pursuit transition (reward R_m is the reward of the
previous pursuit action: the coding quality its movement led to) -> pursuit action -> one
dictionary step on the observation;
**step k2** the same for the stereo observation and vergence.

Transitions that cross a fixation boundary (a new start state, or a new texture and distance)
are not learned from (``skip_fixation_boundary``; the last state of a fixation does not lead to
the first of the next). Each finished trial's ``q`` is first predicted by the current depth MLP
(so the online depth error is honest) and then joins the depth training data. With B = 1 this is
the paper's sequential algorithm; with B > 1 every learner takes the mean of the B
per-environment updates (see the learners' docstrings).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple, Optional

import torch
from torch import Tensor, nn

from aectorch.coding import BinocularEncoder

from aectorch.coding.patches import DEFAULT_SCALES, SCALE_NAMES, as_scale
from aectorch.control import ActorCriticConfig, NaturalActorCritic
from aectorch.depth import DepthMLP, fit_levenberg_marquardt
from aectorch.profiling import stage

__all__ = ["DEFAULT_ACTIONS_DEG", "DEFAULT_SCALES", "PAPER_ACTIONS_DEG", "default_control", "CueRecord", "IterationRecord", "JointLearner", "LearnerConfig"]

#: The default action set: the paper's seven increments plus +-0.5 and +-1 degrees, so that a
#: fixation's 30 iterations can reach the 5.7 degrees of pursuit that 1 m needs in six steps (the
#: paper's largest step, 0.2 degrees, needs 29 of them). A largest step of 2 degrees (the default
#: before 2026-12-02) made the greedy policy of near trials cycle between states 2 degrees apart
#: (docs/results.md, "A smaller largest step").
DEFAULT_ACTIONS_DEG = (-1.0, -0.5, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.5, 1.0)
#: The paper's action set A.
PAPER_ACTIONS_DEG = (-0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2)


def default_control() -> ActorCriticConfig:
    """The actor-critic settings :class:`JointLearner` uses by default (see docs/paper-mapping.md).

    The lineage's z-scored features (Welford) with step sizes for their norm (about sqrt(864)
    with the three default scales, sqrt(576) with the paper's two),
    a near-zero initial policy (uniform), the critic discounted by 0.3 (the lineage's 0.3-0.6;
    the improvement reward needs gamma < 1), and a fast actor: the advantage parameters w
    estimate the advantage, the actor follows them with step 10.
    """
    return ActorCriticConfig(alpha_v=0.001, alpha_theta=10.0, critic_discount=0.3,
                             normalize_features=True, actor_init=0.01, critic_init=0.0,
                             batch_reference=64, feature_norm=30.0, actor_decay=1000.0)


#: The depth MLP is first fitted once this many trials are stored (fewer cannot hold out a
#: validation set).
_MIN_DEPTH_TRIALS = 10


@dataclass
class LearnerConfig:
    """Hyperparameters of :class:`JointLearner`.

    Defaults are the paper's values where it gives them and they can reach the targets; where
    they differ (action set, reward, actor-critic settings) docs/paper-mapping.md says why, and
    ``preset=paper`` (:data:`aectorch.config.PAPER_PRESET`) restores the paper's values.

    Attributes:
        num_atoms: atoms per dictionary, N (paper: 288).
        sparsity: non-zero coefficients per patch (paper: 10).
        algorithm: ``"mp"`` (the paper's matching pursuit) or ``"omp"``.
        scales: foveal scales, names from :data:`aectorch.coding.patches.SCALE_NAMES`; default
            :data:`DEFAULT_SCALES`, ``("wide", "coarse", "fine")``: the paper's ``("coarse",
            "fine")`` and ``"wide"`` (`aectorch.coding.patches.WIDE`, not in the paper: the
            coarse crop at 3.56 deg/px). ``"full"`` (the central 40 px unreduced) is optional.
        centred_patches: mirror-centred sampling at every scale (`aectorch.coding.patches.Scale`'s
            ``centred``): each pyramid level samples between pixel pairs and the fine scale's
            patch grid sits in the middle of its crop, so the patches of mirrored images are the
            mirrored patches and the parallax cue's symmetry holds exactly. ``False`` is the classic
            reduce (``cv2.pyrDown``), whose samples drift 0.5-7.5 px left of the crop's centre:
            measured on a trained learner, the features of a mirrored pair then differ from the
            permuted features by 14-60 % (by scale), so the mirrored transitions the symmetry
            learns from are not the real ones.
        render_scales: ask the environment for each scale's crop rendered directly at the scale's
            resolution (``ActiveDepthEnv.stereo_observation(scales=...)``: mipmapped textures,
            2 x 2 lookups per pixel, within 0.5 % of the exact area average, then the rest of the
            pyramid's blur; 2,488 rendered pixels per eye image against the 128 px crop's 16,384)
            instead of rendering the crops and reducing them with the pyramid. An environment
            without ``renders_scales`` gets the crops either way.
        dictionary_lr: dictionary learning rate per iteration (the lineage: 0.01-0.5; default 0.1).
        dictionary_decay: tau (> 0; default 500), or ``None`` for a constant rate (the lineage):
            the dictionaries' rate decays as ``dictionary_lr * (tau / (tau + t)) ** dictionary_decay_power`` after t
            dictionary steps, so the code settles once the eye movements have shaped it (the
            lineage raised its rate over training; online dictionary learning decays it).
        dictionary_decay_power: p of ``dictionary_decay`` (> 0).
        pooling: ``"mean"`` over patches (the lineage; keeps the features' norm near 1, which the
            critic's step size needs) or ``"sum"`` (eq. 3 literally).
        feature_scale: the features f the actor-critics see are ``feature_scale * f``. The
            critic's step is stable only while ``alpha_v * ||f||^2 < 2``; mean-pooled features of
            a 288-atom dictionary have a norm of about 0.1, so 10 brings them near 1.
        features: what the actor-critics see: ``"pooled"`` (the pooled activities f of eq. 5,
            times ``feature_scale``) or ``"unit"`` (f / ||f||, times ``feature_scale``). The
            pooled activities grow while the dictionaries learn (better atoms take larger
            coefficients), and the critic's and the advantage parameters' steps diverge once
            ``alpha * ||f||^2 > 2``; unit features keep that bound fixed.
        actions_deg: the action set A of pan increments (paper: +-0.2, +-0.1, +-0.05, 0;
            default :data:`DEFAULT_ACTIONS_DEG` adds +-0.5 and +-1).
        control: actor-critic hyperparameters shared by pursuit and vergence (default
            :func:`default_control`; ``ActorCriticConfig()`` is the paper's form).
        skip_fixation_boundary: do not learn from the transition between two fixations.
        reward: what the actor-critics learn from (default ``"improvement"``). ``"coding"`` (the paper): R = -(e^C + e^F) of
            the observation the action led to. ``"improvement"``: R(s') - R(s), the change of the
            coding reward the action caused. With a critic discount gamma < 1 the two define the
            same discounted problem (the improvement's return is (1 - gamma) times the coding
            reward's, minus a constant of the start state), but the improvement leaves out the
            texture's reward level, the largest term of the TD error's noise. With gamma = 1 the
            improvement's return telescopes to a constant: use it only with ``critic_discount < 1``.
        symmetry: the cues whose symmetry the learner uses (a subset of ``("parallax",
            "stereo")``; default both; ``[]`` is the paper). Mirroring the world left-right
            mirrors both images of the parallax pair and negates the pursuit it needs; exchanging
            the two eyes' images of a stereo pair negates the disparity, so the vergence change it
            needs (for a fronto-parallel plane and textures that are mirror-symmetric in
            distribution). For each cue listed, its dictionaries keep their atoms in pairs related
            by that symmetry (so the features of the transformed observation are a permutation of
            the features, at no cost), and every actor-critic update also learns from the
            transformed transition: features permuted, action negated (the action set must be
            symmetric), the same reward. Leftward and rightward fixations then teach one pursuit
            policy, and under- and over-convergence one vergence policy: neither can prefer a
            direction the images do not give, and the stereo dictionaries code crossed and
            uncrossed disparities alike.
        depth_hidden: hidden units of the depth MLP (paper: 10).
        depth_every_trials: retrain the depth MLP after every this many finished trials (all B
            environments' trials count).
        depth_max_samples: keep the last this many trials as the MLP's training data.
        depth_max_epochs: Levenberg-Marquardt epoch budget per retraining.
    """

    num_atoms: int = 288
    sparsity: int = 10
    algorithm: str = "mp"
    scales: tuple[str, ...] = DEFAULT_SCALES
    centred_patches: bool = True
    render_scales: bool = True
    dictionary_lr: float = 0.1
    dictionary_decay: Optional[float] = 500.0
    dictionary_decay_power: float = 1.0
    pooling: str = "mean"
    feature_scale: float = 10.0
    actions_deg: tuple[float, ...] = DEFAULT_ACTIONS_DEG
    control: ActorCriticConfig = field(default_factory=lambda: default_control())
    skip_fixation_boundary: bool = True
    reward: str = "improvement"
    features: str = "pooled"
    symmetry: tuple[str, ...] = ("parallax", "stereo")
    depth_hidden: int = 10
    depth_every_trials: int = 256
    depth_max_samples: int = 20000
    depth_max_epochs: int = 200

    def __post_init__(self) -> None:
        if self.algorithm not in ("mp", "omp"):
            raise ValueError(f"LearnerConfig.algorithm must be 'mp' or 'omp', got {self.algorithm!r}")
        if self.features not in ("pooled", "unit"):
            raise ValueError(f"LearnerConfig.features must be 'pooled' or 'unit', got {self.features!r}")
        if self.reward not in ("coding", "improvement"):
            raise ValueError(f"LearnerConfig.reward must be 'coding' or 'improvement', got {self.reward!r}")
        if self.pooling not in ("mean", "sum"):
            raise ValueError(f"LearnerConfig.pooling must be 'mean' or 'sum', got {self.pooling!r}")
        self.scales = tuple(self.scales)
        try:
            self.actions_deg = tuple(float(a) for a in self.actions_deg)
        except (TypeError, ValueError):
            raise ValueError(f"LearnerConfig.actions_deg must be a list of numbers (degrees), got {self.actions_deg!r}") from None
        try:
            self.symmetry = tuple(self.symmetry)
        except TypeError:
            self.symmetry = (self.symmetry,)
        if any(c not in ("parallax", "stereo") for c in self.symmetry) or len(set(self.symmetry)) != len(self.symmetry):
            raise ValueError("LearnerConfig.symmetry must be a list of distinct cues from ('parallax', 'stereo'), "
                             f"got {list(self.symmetry)!r}")
        if self.symmetry and sorted(-a for a in self.actions_deg) != sorted(self.actions_deg):
            raise ValueError("LearnerConfig.actions_deg must be symmetric (-a for every a) with "
                             f"LearnerConfig.symmetry={list(self.symmetry)!r}, got {list(self.actions_deg)!r}; "
                             "use a symmetric set or symmetry=[]")
        if self.symmetry and self.num_atoms % 2:
            raise ValueError(f"LearnerConfig.num_atoms must be even with LearnerConfig.symmetry (atoms come in "
                             f"pairs), got {self.num_atoms}")
        if not self.scales or any(s not in SCALE_NAMES for s in self.scales):
            raise ValueError(f"LearnerConfig.scales must be a non-empty subset of {SCALE_NAMES}, got {self.scales!r}")
        for name in ("num_atoms", "sparsity", "depth_hidden", "depth_every_trials",
                     "depth_max_samples", "depth_max_epochs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"LearnerConfig.{name} must be an int >= 1, got {value!r}")
        if not (isinstance(self.feature_scale, (int, float)) and self.feature_scale > 0):
            raise ValueError(f"LearnerConfig.feature_scale must be a number > 0, got {self.feature_scale!r}")
        if not (isinstance(self.dictionary_lr, (int, float)) and self.dictionary_lr >= 0):
            raise ValueError(f"LearnerConfig.dictionary_lr must be a number >= 0, got {self.dictionary_lr!r}")
        if not isinstance(self.render_scales, bool):
            raise ValueError(f"LearnerConfig.render_scales must be true or false, got {self.render_scales!r}")
        if not isinstance(self.centred_patches, bool):
            raise ValueError(f"LearnerConfig.centred_patches must be true or false, got {self.centred_patches!r}")
        if self.dictionary_decay is not None and not (
                isinstance(self.dictionary_decay, (int, float)) and not isinstance(self.dictionary_decay, bool)
                and math.isfinite(self.dictionary_decay) and self.dictionary_decay > 0):
            raise ValueError(f"LearnerConfig.dictionary_decay must be null or a number > 0, got {self.dictionary_decay!r}")
        if not (isinstance(self.dictionary_decay_power, (int, float)) and not isinstance(self.dictionary_decay_power, bool)
                and math.isfinite(self.dictionary_decay_power) and self.dictionary_decay_power > 0):
            raise ValueError("LearnerConfig.dictionary_decay_power must be a number > 0, "
                             f"got {self.dictionary_decay_power!r}")
        if isinstance(self.control, dict):
            self.control = ActorCriticConfig(**self.control)


class CueRecord(NamedTuple):
    """One cue's step of an iteration, per environment ``[B]`` unless noted."""

    reward: Tensor  #: R = -(e^C + e^F) of the observation
    errors: Tensor  #: ``[B, n_scales]`` reconstruction error per scale (eq. 4)
    td_error: Tensor | None  #: TD error of the update (``None`` when nothing was learned)
    entropy: Tensor  #: entropy of the policy that chose the action, nats
    actions: Tensor  #: chosen action indices
    increments_deg: Tensor  #: chosen pan increments
    atom_counts: Tensor  #: ``[n_scales, num_atoms]`` how often each atom was chosen (all B, all patches)


class IterationRecord(NamedTuple):
    """What :meth:`JointLearner.iteration` returns."""

    parallax: CueRecord
    stereo: CueRecord
    pursuit_error_deg: Tensor  #: ``[B]`` left pan - optimal, after this iteration
    vergence_error_deg: Tensor  #: ``[B]`` right pan - optimal
    fixation_end: bool
    trial_end: bool
    q_deg: Tensor | None  #: ``[B, 4]`` at a trial's end
    distance_m: Tensor | None  #: ``[B]`` true distance at a trial's end
    depth_prediction_m: Tensor | None  #: ``[B]`` the MLP's estimate before it saw these trials
    depth_retrained: bool


class JointLearner(nn.Module):
    """The paper's agent: sparse coding, eye-movement learning and depth learning, together.

    Args:
        config: hyperparameters (:class:`LearnerConfig`).
        generator: seeds the initial dictionaries and policies and draws the actions.
        device, dtype: of every learner.
        shard: this process's part of a batch split across processes
            (`aectorch.distributed.Shard`; the environment gets the same slice): the learning
            steps reduce over every process, the depth MLP trains on every process's trials and
            actions are drawn for the whole batch, so all processes keep identical learners.

    Example:
        >>> import torch
        >>> from aectorch.sim import ActiveDepthEnv
        >>> env = ActiveDepthEnv(2, textures=torch.rand(3, 64, 64), fixation_iterations=2, seed=0)
        >>> learner = JointLearner(LearnerConfig(num_atoms=32), generator=torch.Generator().manual_seed(0))
        >>> record = learner.iteration(env)
        >>> record.parallax.reward.shape, record.pursuit_error_deg.shape
        (torch.Size([2]), torch.Size([2]))
    """

    def __init__(
        self,
        config: LearnerConfig | None = None,
        *,
        generator: torch.Generator | None = None,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        shard=None,
    ) -> None:
        super().__init__()
        self.shard = shard
        self.config = config = config or LearnerConfig()
        self.generator = generator or torch.Generator().manual_seed(0)
        scales = [dataclasses.replace(as_scale(s), centred=True) if config.centred_patches else s
                  for s in config.scales]
        kwargs = dict(num_atoms=config.num_atoms, sparsity=config.sparsity, algorithm=config.algorithm,
                      scales=scales, lr=config.dictionary_lr, pooling=config.pooling,
                      generator=self.generator, dtype=dtype, device=device)
        self.parallax = BinocularEncoder(**kwargs, symmetry="mirror" if "parallax" in config.symmetry else None)
        self.stereo = BinocularEncoder(**kwargs, symmetry="swap" if "stereo" in config.symmetry else None)
        features = self.parallax.num_features
        agent = dict(actions_deg=config.actions_deg, config=config.control,
                     generator=self.generator, dtype=dtype, device=device)
        self.pursuit = NaturalActorCritic(features, **agent)
        self.vergence = NaturalActorCritic(features, **agent)
        # The index of each action's negation: a symmetric cue's transformed transition takes it
        # (the features take the encoder's `feature_permutation`). A buffer, so `.to()` moves it.
        actions = torch.tensor(config.actions_deg, dtype=torch.float64)
        negation = (actions[None, :] == -actions[:, None]).to(torch.int64).argmax(-1)
        self.register_buffer("action_negation", negation.to(device) if config.symmetry else None, persistent=False)
        with torch.no_grad():  # start the policies and critics symmetric as well
            for encoder, agent_ in ((self.parallax, self.pursuit), (self.stereo, self.vergence)):
                fmap = encoder.feature_permutation
                if fmap is not None:
                    agent_.actor_weight.copy_((agent_.actor_weight + agent_.actor_weight[self.action_negation][:, fmap]) * 0.5)
                    agent_.critic_weight.copy_((agent_.critic_weight + agent_.critic_weight[fmap]) * 0.5)
        self.depth = DepthMLP(in_features=4, hidden=config.depth_hidden, out_features=1).to(
            device=device, dtype=dtype
        )
        # Unused until the first fit, which starts from Nguyen-Widrow weights drawn from a seed of
        # ``generator``; zero them rather than leave torch's global random state in them, so that
        # a seed fixes the whole learner state (and checkpoints) even with other RNG use around.
        with torch.no_grad():
            for parameter in self.depth.parameters():
                parameter.zero_()
        # Learning state that is not a parameter: previous transitions and the depth data.
        self._previous: dict[str, tuple[Tensor, Tensor] | None] = {"m": None, "s": None}
        self.register_buffer("depth_inputs", torch.zeros(0, 4, dtype=dtype, device=device))
        self.register_buffer("depth_targets", torch.zeros(0, dtype=dtype, device=device))
        self.register_buffer("depth_trained", torch.zeros((), dtype=torch.bool, device=device))
        self.trials_seen = 0
        self._trials_at_last_fit = 0
        self.dictionary_steps = {"m": 0, "s": 0}  # learning steps each cue's dictionaries took

    def dictionary_rate(self, steps: int) -> float:
        """The dictionaries' learning rate after ``steps`` steps (``dictionary_decay``)."""
        c = self.config
        if c.dictionary_decay is None:
            return c.dictionary_lr
        return c.dictionary_lr * (c.dictionary_decay / (c.dictionary_decay + steps)) ** c.dictionary_decay_power

    # -- one cue -------------------------------------------------------------------------------
    def _cue(self, key: str, encoder: BinocularEncoder, agent: NaturalActorCritic, pair: Tensor,
             *, learn: bool, greedy: bool) -> CueRecord:
        with stage("encode"), torch.no_grad():
            if isinstance(pair, dict):  # images at each scale's resolution
                out = encoder({k: p[:, 0] for k, p in pair.items()}, {k: p[:, 1] for k, p in pair.items()}, check=False)
            else:
                out = encoder(pair[:, 0], pair[:, 1], check=False)
        with stage("rl"):
            features, reward = out.features, out.reward
            if self.config.features == "unit":
                features = features / torch.linalg.vector_norm(features, dim=-1, keepdim=True).clamp_min(1e-12)
            features = features * self.config.feature_scale
            td_error = None
            previous = self._previous[key]
            shard = self.shard
            reduce = None if shard is None else shard.sum
            if learn and previous is not None:
                learned = reward - previous[2] if self.config.reward == "improvement" else reward
                f_prev, a_prev, f_next = previous[0], previous[1], features
                fmap = encoder.feature_permutation
                if fmap is not None:  # also learn from the transformed transition
                    f_prev = torch.cat((f_prev, f_prev[:, fmap]))
                    a_prev = torch.cat((a_prev, self.action_negation[a_prev]))
                    f_next = torch.cat((f_next, f_next[:, fmap]))
                    learned = torch.cat((learned, learned))
                update = agent.update(f_prev, a_prev, learned, f_next, reduce=reduce)
                td_error = update.td_error[: features.shape[0]]
            if shard is None or greedy:
                action = agent.act(features, greedy=greedy, generator=self.generator)
            else:  # the numbers one process with the whole batch would draw; this rank's rows
                u = torch.rand(shard.total, 1, generator=self.generator, dtype=features.dtype, device=features.device)
                action = agent.act(features, uniform=shard.draw(u)[:, 0])
        if learn and self.config.dictionary_lr > 0:
            with stage("dictionary"):
                encoder.learn_(out, self.dictionary_rate(self.dictionary_steps[key]), reduce=reduce)
                self.dictionary_steps[key] += 1
        # Without learning there is no transition to complete on the next step.
        self._previous[key] = (features, action.actions, reward) if learn else None
        with stage("metrics"):
            counts = torch.stack([
                torch.bincount(c.code.indices.reshape(-1), minlength=encoder.dictionaries[s.name].num_atoms)
                for s, c in zip(encoder.scales, out.codes)
            ])
        return CueRecord(reward, out.errors, td_error, action.entropy, action.actions,
                         action.increments_deg, counts)

    def _render_scales(self, env):
        """The scales to ask ``env`` for (``render_scales``), or None for whole crops."""
        if not self.config.render_scales or not getattr(env, "renders_scales", False):
            return None
        return self.parallax.scales

    # -- the schedule ----------------------------------------------------------------------------
    def iteration(self, env, *, learn: bool = True, greedy: bool = False) -> IterationRecord:
        """Advance every environment of ``env`` by one iteration (steps k1 and k2).

        Args:
            env: an :class:`~aectorch.sim.ActiveDepthEnv` on this learner's device and dtype.
            learn: update dictionaries, policies, critics and the depth MLP; ``False`` freezes
                everything (evaluation) and leaves no pending transition, so a later learning
                step does not learn from a transition it did not see.
            greedy: take the most probable action instead of sampling.
        """
        scales = self._render_scales(env)
        with stage("render"):
            pair = env.parallax_observation() if scales is None else env.parallax_observation(scales=scales)
        parallax = self._cue("m", self.parallax, self.pursuit, pair, learn=learn, greedy=greedy)
        with stage("env"):
            env.apply_pursuit(parallax.increments_deg)
        with stage("render"):
            pair = env.stereo_observation() if scales is None else env.stereo_observation(scales=scales)
        stereo = self._cue("s", self.stereo, self.vergence, pair, learn=learn, greedy=greedy)
        with stage("env"):
            info = env.apply_vergence(stereo.increments_deg)
        if info.fixation_end and self.config.skip_fixation_boundary:
            self._previous = {"m": None, "s": None}
        prediction, retrained = None, False
        if info.trial_end:
            with stage("depth"):
                prediction = self.predict_depth(info.q_deg)
                if learn:
                    retrained = self._add_trials(info.q_deg, info.distance_m)
        return IterationRecord(
            parallax=parallax,
            stereo=stereo,
            pursuit_error_deg=info.pursuit_error_deg,
            vergence_error_deg=info.vergence_error_deg,
            fixation_end=info.fixation_end,
            trial_end=info.trial_end,
            q_deg=info.q_deg,
            distance_m=info.distance_m,
            depth_prediction_m=prediction,
            depth_retrained=retrained,
        )

    def forget_transitions(self) -> None:
        """Start the next iteration without a previous transition (e.g. after ``env.reset``)."""
        self._previous = {"m": None, "s": None}

    # -- depth -------------------------------------------------------------------------------------
    def predict_depth(self, q_deg: Tensor) -> Tensor:
        """The MLP's distance estimate ``[B]`` (metres) from ``q`` ``[B, 4]``; NaN before any training."""
        with torch.no_grad():
            estimate = self.depth(q_deg.to(self.depth_inputs.dtype)).reshape(-1)
        return torch.where(self.depth_trained, estimate, torch.full_like(estimate, math.nan))

    def _add_trials(self, q_deg: Tensor, distance_m: Tensor) -> bool:
        if self.shard is not None:  # every process's trials, in the whole batch's order
            q_deg, distance_m = self.shard.gather(q_deg), self.shard.gather(distance_m)
        keep = self.config.depth_max_samples
        self.depth_inputs = torch.cat((self.depth_inputs, q_deg.to(self.depth_inputs)))[-keep:]
        self.depth_targets = torch.cat((self.depth_targets, distance_m.to(self.depth_targets)))[-keep:]
        self.trials_seen += q_deg.shape[0]
        if (self.trials_seen - self._trials_at_last_fit < self.config.depth_every_trials
                or self.depth_inputs.shape[0] < _MIN_DEPTH_TRIALS):
            return False
        self.fit_depth()
        return True

    def fit_depth(self, *, seed: int | None = None):
        """Retrain the depth MLP on the stored trials with Levenberg-Marquardt (from its current weights)."""
        if self.depth_inputs.shape[0] < _MIN_DEPTH_TRIALS:
            raise ValueError(
                f"fit_depth needs at least {_MIN_DEPTH_TRIALS} finished trials, has {self.depth_inputs.shape[0]}"
            )
        result = self._fit_depth_mlp(self.depth_inputs, self.depth_targets, seed)
        self._trials_at_last_fit = self.trials_seen
        return result

    def _fit_depth_mlp(self, q_deg: Tensor, distance_m: Tensor, seed: int | None):
        """Levenberg-Marquardt on these trials; Nguyen-Widrow weights before the first fit."""
        if seed is None:
            seed = int(torch.randint(0, 2**31 - 1, (1,), generator=self.generator))
        like = self.depth_inputs
        result = fit_levenberg_marquardt(
            self.depth, q_deg.to(like), distance_m.to(like), max_epochs=self.config.depth_max_epochs,
            seed=seed, init=None if bool(self.depth_trained) else "nguyen-widrow",
        )
        self.depth_trained.fill_(True)
        return result

    def calibrate_depth(self, q_deg: Tensor, distance_m: Tensor, *, seed: int | None = None):
        """Refit the depth MLP on the given trials only, from its current weights.

        Training fits the MLP on trials made with *sampled* actions, whose final eye angles
        scatter more than those of the greedy policy that is evaluated; refitted on greedy
        trials of the training textures (:func:`aectorch.evaluate.run_trials`), the MLP maps the
        evaluated policy's own ``q`` to distance (``train.depth_calibration_trials``). The
        stored training trials (``depth_inputs``, ``depth_targets``) are not changed.

        Args:
            q_deg: the trials' final eye angles, ``[N, 4]`` (N >= 10).
            distance_m: their true distances, ``[N]``.
            seed: seeds the fit's validation split (default: drawn from the learner's generator).

        Returns:
            The Levenberg-Marquardt fit's result.
        """
        if not isinstance(q_deg, Tensor) or q_deg.dim() != 2 or q_deg.shape[1] != 4:
            raise ValueError(f"q_deg must be a tensor of shape [N, 4], got {getattr(q_deg, 'shape', type(q_deg))}")
        if not isinstance(distance_m, Tensor) or distance_m.shape != q_deg.shape[:1]:
            raise ValueError(f"distance_m must be a tensor of shape [{q_deg.shape[0]}], "
                             f"got {getattr(distance_m, 'shape', type(distance_m))}")
        if q_deg.shape[0] < _MIN_DEPTH_TRIALS:
            raise ValueError(f"calibrate_depth needs at least {_MIN_DEPTH_TRIALS} trials, got {q_deg.shape[0]}")
        if not (torch.isfinite(q_deg).all() and torch.isfinite(distance_m).all()):
            raise ValueError("q_deg and distance_m must be finite")
        return self._fit_depth_mlp(q_deg, distance_m, seed)

    # -- checkpoints -------------------------------------------------------------------------------
    def get_extra_state(self) -> dict:
        return {
            "trials_seen": self.trials_seen,
            "trials_at_last_fit": self._trials_at_last_fit,
            "previous": self._previous,
            "generator": self.generator.get_state(),
            "dictionary_steps": dict(self.dictionary_steps),
        }

    def set_extra_state(self, state: dict) -> None:
        self.trials_seen = int(state["trials_seen"])
        self._trials_at_last_fit = int(state["trials_at_last_fit"])
        self._previous = state["previous"]
        self.generator.set_state(state["generator"])
        # Checkpoints from before the count existed: their learners had a constant rate.
        self.dictionary_steps = dict(state.get("dictionary_steps", {"m": 0, "s": 0}))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The depth buffers grow during training: take the checkpoint's size.
        for name in ("depth_inputs", "depth_targets"):
            key = prefix + name
            if key in state_dict:
                setattr(self, name, torch.empty_like(state_dict[key]))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
