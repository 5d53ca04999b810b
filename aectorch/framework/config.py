"""``LearnerConfig``: the hyperparameters of `JointLearner`, with one `CueConfig` per depth cue.

This is where the learner's defaults live, once: each cue's coder (`EncoderConfig`), its agent
(`ActorCriticConfig` or `PPOConfig`), its actions, scales and symmetry, and the depth MLP's
settings. ``preset=paper`` (`aectorch.runtime.presets.PAPER_PRESET`) lists what the paper states
differently.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from aectorch._checks import check_bool, check_choice, check_int, check_real
from aectorch.choices import AgentName, Efficiency, Features, Proprioception, Readout, Reward, Symmetry
from aectorch.coding.encoder import EncoderConfig
from aectorch.coding.patches import DEFAULT_SCALES, SCALE_NAMES
from aectorch.control import DEFAULT_ACTIONS_DEG, PAPER_ACTIONS_DEG, ActorCriticConfig, PPOConfig

__all__ = ["DEFAULT_ACTIONS_DEG", "DEFAULT_SCALES", "PAPER_ACTIONS_DEG", "CueConfig", "LearnerConfig", "default_cues"]


@dataclass
class CueConfig:
    """One depth cue's learner (`CueLearner`): its coder, its agent and what the agent learns from.

    Attributes:
        agent: the algorithm of the cue's eye movement: ``"ppo"`` (`PPO`, with ``ppo``; the
            default) or ``"nac"`` (the paper's natural actor-critic, `NaturalActorCritic`, with
            ``nac``). PPO fixates photographs it never saw more precisely (docs/results.md).
        actions_deg: the action set A of pan increments (paper: +-0.2, +-0.1, +-0.05, 0;
            default `DEFAULT_ACTIONS_DEG` adds +-0.5 and +-1).
        scales: foveal scales, names from :data:`aectorch.coding.patches.SCALE_NAMES`; default
            :data:`DEFAULT_SCALES`, ``("wide", "coarse", "fine", "full")``: the paper's
            ``("coarse", "fine")``, ``"wide"`` (`aectorch.coding.patches.WIDE`, not in the paper:
            the coarse crop at 3.56 deg/px) and ``"full"`` (not in the paper: the central 40 px
            unreduced, 0.22 deg/px; without it the stereo code cannot tell 0.1 deg from 0).
        symmetry: ``null`` (the paper), or the symmetry of the cue's image pairs that its
            dictionaries and agent use: ``"mirror"`` (mirroring the world left-right mirrors both
            images of the parallax pair and negates the pursuit it needs) or ``"swap"``
            (exchanging the two eyes' images of a stereo pair negates the disparity, so the
            vergence change it needs, for a fronto-parallel plane and textures that are
            mirror-symmetric in distribution). The dictionaries keep their atoms in pairs related
            by the symmetry (the features of the transformed observation are a permutation of the
            features, at no cost), the agent starts invariant, and every update also learns from
            the transformed transition: features permuted, action negated (the action set must be
            symmetric), the same reward. Leftward and rightward fixations then teach one pursuit
            policy, and under- and over-convergence one vergence policy.
        encoder: the sparse coder and its dictionary learning (`EncoderConfig`).
        nac: the natural actor-critic's hyperparameters (`ActorCriticConfig`), with ``agent=nac``.
        ppo: PPO's hyperparameters (`PPOConfig`), with ``agent=ppo``.
        features: what the agent sees: ``"pooled"`` (the pooled activities f of eq. 5, times
            ``feature_scale``), ``"unit"`` (f / ||f||, times ``feature_scale``) or ``"none"``
            (none of the code: the agent senses its ``proprioception`` alone, while the code
            still makes its reward). The pooled
            activities grow while the dictionaries learn (better atoms take larger coefficients),
            and the critic's steps diverge once ``alpha * ||f||^2 > 2``; unit features keep that
            bound fixed.
        feature_scale: the features the agent sees are ``feature_scale * f`` (> 0). Mean-pooled
            features of a 288-atom dictionary have a norm of about 0.1, so 10 brings them near 1.
        reward: what the agent learns from (default ``"improvement"``). ``"coding"`` (the paper):
            R = -(e^C + e^F) of the observation the action led to. ``"improvement"``: R(s') - R(s),
            the change of the coding reward the action caused. With a discount gamma < 1 the two
            define the same discounted problem (the improvement's return is (1 - gamma) times the
            coding reward's, minus a constant of the start state), but the improvement leaves out
            the texture's reward level, the largest term of the TD error's noise. With gamma = 1
            the improvement's return telescopes to a constant: use it only with a discount < 1.
            ``"scaled"``: the improvement over a running root mean square of the improvements.
            One function computes the three, here and in the standard environments
            (`aectorch.control.rewards.learned_reward`).
        efficiency: what the coding reward R measures: ``"reconstruction"`` (default, the paper:
            R = -(e^C + e^F)) or ``"information"``: the information the code keeps of its input,
            R = sum over scales of the mean over patches of 1/2 log(E (1 - e)), E the patch's
            contrast energy before normalisation (`aectorch.coding.focus.focus_reward`, derived
            from Eckmann et al. 2020's I(R;C)). A blurred image is easier to reconstruct, so the
            reconstruction reward prefers blur; the information reward prefers focus (the
            accommodation cue's, docs/results.md). ``reward`` then forms the learned reward from it.
        motor_cost: a metabolic cost of the eye movement (>= 0, default 0): the agent learns from
            the reward minus ``motor_cost * |increment|`` (degrees) of the action that led to it,
            as the lineage's AEC models charge the muscles' activity, so that standing still pays
            where the code cannot tell a small offset from none.
        readout: the increment the greedy (frozen, evaluated) policy takes: ``"mean"`` (the
            policy's mean increment, sum_a pi(a|s) a, the default: where the policy hesitates
            between stepping either way, it steps little) or ``"argmax"`` (the most probable
            action's, the paper's greedy policy). Training samples actions either way.
        proprioception: what the agent senses of its own eyes besides the code (default none):
            names of `aectorch.choices.Proprioception`, ``vergence`` (the commanded vergence
            angle, degrees), ``pan`` (the left eye's commanded pan, degrees), ``focus`` (the left
            eye's focus, dioptres; needs accommodating eyes), ``shift`` (the body's sideways shift
            since the fixation's start, metres), read when the cue observes
            (`ActiveDepthEnv.proprioception`) and appended to its features, which the agent
            z-scores with the rest (but leaves out of the scaling to its ``feature_norm``, which
            would shrink each to a few per cent of a z-score among hundreds). The vergence angle encodes the distance once vergence is right,
            so with the focus it tells an accommodation cue which way the object's focus lies,
            which the blur alone cannot (experiments/accommodation/README.md). A cue's symmetry
            leaves the vergence angle and the focus unchanged; ``pan`` and ``shift`` change sign
            under it, so they need ``symmetry=null``.
        reward_scales: the scales whose coding efficiency the agent learns from (default, empty:
            all of ``scales``); the code of every scale is still learned and seen. The wide and
            coarse scales' errors barely change within a pixel of the optimum, but leaving them
            out of both cues' rewards (``[fine, full]``) made vergence worse (3 seeds, choosing
            photographs: 0.152 against 0.100 deg; CHANGELOG.md).
        learn_until: ``None`` (default: the cue learns for the whole run), or the training
            iteration (>= 0, counted from the run's start) from which the cue learns nothing
            more: its dictionaries, its agent and the agent's feature statistics stay as they
            are, while its eye movement goes on acting and the other cues go on learning. A
            closing plasticity, as the lineage's models decay their actors' rates to 0, but for
            the whole cue: a policy that stops learning alone does not keep its precision when
            the code and the statistics under it go on changing
            (experiments/long_training/README.md).
        reopen_drop: ``None`` (default: a closed cue stays closed), or a fraction (> 0): a cue
            closed by ``learn_until`` learns again when the mean of its coding reward over the
            last ``reopen_window`` iterations falls below its level since it closed (the mean
            over the first ``reopen_window`` closed iterations) by more than this fraction of
            that level (`aectorch.framework.plasticity`). A plasticity that settles while the
            plant stays as it is and reopens when it changes.
        reopen_window: iterations (>= 1) each level is a mean over.
        reopen_for: iterations (>= 1) a reopened cue learns before it closes again and takes its
            level anew.
    """

    agent: AgentName = AgentName.ppo
    actions_deg: tuple[float, ...] = DEFAULT_ACTIONS_DEG
    scales: tuple[str, ...] = DEFAULT_SCALES
    symmetry: Optional[Symmetry] = None
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    nac: ActorCriticConfig = field(default_factory=ActorCriticConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    features: Features = Features.pooled
    feature_scale: float = 10.0
    reward: Reward = Reward.improvement
    efficiency: Efficiency = Efficiency.reconstruction
    motor_cost: float = 0.0
    readout: Readout = Readout.mean
    proprioception: tuple[str, ...] = ()
    reward_scales: tuple[str, ...] = ()
    learn_until: Optional[int] = None
    reopen_drop: Optional[float] = None
    reopen_window: int = 200
    reopen_for: int = 2400

    def __post_init__(self) -> None:
        # Messages name the field as "cue.<field>"; `aectorch.runtime.config.to_experiment_config`
        # names the cue in them ("learner.cues.stereo.<field>").
        owner = "cue"
        self.agent = check_choice(self.agent, f"{owner}.agent", AgentName)
        self.features = check_choice(self.features, f"{owner}.features", Features)
        self.reward = check_choice(self.reward, f"{owner}.reward", Reward)
        self.efficiency = check_choice(self.efficiency, f"{owner}.efficiency", Efficiency)
        self.readout = check_choice(self.readout, f"{owner}.readout", Readout)
        if self.symmetry is not None:
            self.symmetry = check_choice(self.symmetry, f"{owner}.symmetry", Symmetry)
        try:
            self.actions_deg = tuple(float(a) for a in self.actions_deg)
        except (TypeError, ValueError):
            raise ValueError(f"{owner}.actions_deg must be a list of numbers (degrees), got {self.actions_deg!r}") from None
        if not self.actions_deg:
            raise ValueError(f"{owner}.actions_deg must not be empty")
        self.scales = tuple(self.scales)
        if not self.scales or any(s not in SCALE_NAMES for s in self.scales):
            raise ValueError(f"{owner}.scales must be a non-empty subset of {SCALE_NAMES}, got {list(self.scales)!r}")
        if len(set(self.scales)) != len(self.scales):
            raise ValueError(f"{owner}.scales must be distinct, got {list(self.scales)!r}")
        self.reward_scales = tuple(self.reward_scales)
        if any(s not in self.scales for s in self.reward_scales) or len(set(self.reward_scales)) != len(self.reward_scales):
            raise ValueError(f"{owner}.reward_scales must be distinct names of {owner}.scales {list(self.scales)} "
                             f"(empty: all of them), got {list(self.reward_scales)!r}")
        check_real(self.feature_scale, f"{owner}.feature_scale", above=0)
        check_real(self.motor_cost, f"{owner}.motor_cost", minimum=0)
        if self.learn_until is not None:
            check_int(self.learn_until, f"{owner}.learn_until", 0)
        if self.reopen_drop is not None:
            check_real(self.reopen_drop, f"{owner}.reopen_drop", above=0)
            if self.learn_until is None:
                raise ValueError(f"{owner}.reopen_drop reopens a cue closed by {owner}.learn_until, which is null; "
                                 f"give {owner}.learn_until=N or {owner}.reopen_drop=null")
        check_int(self.reopen_window, f"{owner}.reopen_window", 1)
        check_int(self.reopen_for, f"{owner}.reopen_for", 1)
        self._check_proprioception(owner)
        for name, cls in (("encoder", EncoderConfig), ("nac", ActorCriticConfig), ("ppo", PPOConfig)):
            if isinstance(getattr(self, name), dict):
                setattr(self, name, cls(**getattr(self, name)))
        if self.symmetry is not None:
            if sorted(-a for a in self.actions_deg) != sorted(self.actions_deg):
                raise ValueError(f"{owner}.actions_deg must be symmetric (-a for every a) with "
                                 f"{owner}.symmetry={self.symmetry}, got {list(self.actions_deg)!r}; use a "
                                 f"symmetric set or {owner}.symmetry=null")
            if self.encoder.num_atoms % 2:
                raise ValueError(f"{owner}.encoder.num_atoms must be even with {owner}.symmetry (atoms come in "
                                 f"pairs), got {self.encoder.num_atoms}")

    def _check_proprioception(self, owner: str) -> None:
        names = self.proprioception
        if isinstance(names, str) or not hasattr(names, "__iter__"):
            raise ValueError(f"{owner}.proprioception must be a list of {list(Proprioception.values())}, got {names!r}")
        self.proprioception = tuple(str(check_choice(n, f"{owner}.proprioception", Proprioception)) for n in names)
        if len(set(self.proprioception)) != len(self.proprioception):
            raise ValueError(f"{owner}.proprioception must be distinct, got {list(self.proprioception)!r}")
        if self.features == Features.none and not self.proprioception:
            raise ValueError(f"{owner}.features=none leaves the agent nothing to see: give it {owner}.proprioception "
                             f"(a list of {list(Proprioception.values())}) or features pooled or unit")
        odd = [str(n) for n in (Proprioception.pan, Proprioception.shift) if n in self.proprioception]
        if self.symmetry is not None and odd:
            raise ValueError(f"{owner}.proprioception {odd[0]!r} changes sign under {owner}.symmetry={self.symmetry}; "
                             f"use {owner}.symmetry=null or leave {odd[0]!r} out")

    @property
    def agent_config(self):
        """The config of the chosen agent (``nac`` or ``ppo``)."""
        return self.nac if self.agent == AgentName.nac else self.ppo


def default_cues(**fields) -> dict[str, CueConfig]:
    """The paper's two cues, in its order (steps k1, k2): motion parallax, with its mirror symmetry,
    and stereo, with its eye-swap symmetry; ``fields`` of `CueConfig` replace the defaults in both.

    Example:
        >>> cues = default_cues(encoder=EncoderConfig(num_atoms=32), agent="ppo")
        >>> {name: (cue.symmetry, cue.encoder.num_atoms, cue.agent) for name, cue in cues.items()}
        {'parallax': ('mirror', 32, 'ppo'), 'stereo': ('swap', 32, 'ppo')}
    """
    return {"parallax": CueConfig(**{"symmetry": Symmetry.mirror, **fields}),
            "stereo": CueConfig(**{"symmetry": Symmetry.swap, **fields})}


@dataclass
class LearnerConfig:
    """Hyperparameters of :class:`JointLearner`.

    Defaults are the paper's values where it gives them and they can reach the targets; where
    they differ (action set, reward, actor-critic settings, symmetries) docs/paper-mapping.md says
    why, and ``preset=paper`` (:data:`aectorch.runtime.presets.PAPER_PRESET`) restores the
    paper's values.

    Attributes:
        cues: one `CueConfig` per depth cue, by the cue's name in the environment
            (`aectorch.sim.ActiveDepthEnv.CUES`: ``parallax`` drives pursuit, ``stereo``
            vergence); default :func:`default_cues`.
        active_cues: the cues the learner learns (a subset of ``cues``; ``null``, the default: all
            of them). The environment holds the movement of every other cue at its optimum:
            ``[stereo]`` is the lineage's vergence-only model, ``[parallax]`` a pursuit-only one.
        render_scales: ask the environment for each scale's crop rendered directly at the scale's
            resolution (``ActiveDepthEnv.observe(cue, scales=...)``: mipmapped textures, 2 x 2
            lookups per pixel, within 0.5 % of the exact area average, then the rest of the
            pyramid's blur; 4,252 rendered pixels per eye image for the default four scales against
            the 128 px crop's 16,384)
            instead of rendering the crops and reducing them with the pyramid.
        skip_fixation_boundary: do not learn from the transition between two fixations.
        depth_hidden: hidden units of the depth MLP (paper: 10).
        depth_every_trials: retrain the depth MLP after every this many finished trials (all B
            environments' trials count).
        depth_max_samples: keep the last this many trials as the MLP's training data.
        depth_max_epochs: Levenberg-Marquardt epoch budget per retraining.
    """

    cues: dict[str, CueConfig] = field(default_factory=default_cues)
    active_cues: Optional[list[str]] = None
    render_scales: bool = True
    skip_fixation_boundary: bool = True
    depth_hidden: int = 10
    depth_every_trials: int = 256
    depth_max_samples: int = 20000
    depth_max_epochs: int = 200

    def __post_init__(self) -> None:
        owner = "learner"
        if not isinstance(self.cues, dict) or not self.cues:
            raise ValueError(f"{owner}.cues must map cue names to cue configs, got {self.cues!r}")
        self.cues = {str(name): cue if isinstance(cue, CueConfig) else CueConfig(**cue)
                     for name, cue in self.cues.items()}
        if self.active_cues is not None:
            active = [str(c) for c in (self.active_cues if isinstance(self.active_cues, (list, tuple))
                                       else [self.active_cues])]
            if not active or len(set(active)) != len(active) or any(c not in self.cues for c in active):
                raise ValueError(f"{owner}.active_cues must be a non-empty list of distinct cues from "
                                 f"{list(self.cues)}, got {active!r}")
            self.active_cues = active
        for name in ("depth_hidden", "depth_every_trials", "depth_max_samples", "depth_max_epochs"):
            check_int(getattr(self, name), f"{owner}.{name}", 1)
        check_bool(self.render_scales, f"{owner}.render_scales")
        check_bool(self.skip_fixation_boundary, f"{owner}.skip_fixation_boundary")

    @property
    def learned_cues(self) -> list[str]:
        """The names of the cues the learner learns, in the order of ``cues``."""
        return [c for c in self.cues if self.active_cues is None or c in self.active_cues]
