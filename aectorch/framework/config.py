"""``LearnerConfig``: the hyperparameters of `JointLearner`, and the action sets."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from aectorch._checks import check_bool, check_choice, check_int, check_real, is_real
from aectorch.choices import Algorithm, Cue, Features, Pooling, Reward
from aectorch.coding.patches import DEFAULT_SCALES, SCALE_NAMES
from aectorch.control import PAPER_ACTIONS_DEG, ActorCriticConfig

__all__ = ["DEFAULT_ACTIONS_DEG", "DEFAULT_SCALES", "PAPER_ACTIONS_DEG", "LearnerConfig", "default_control"]

#: The default action set: the paper's seven increments plus +-0.5 and +-1 degrees, so that a
#: fixation's 30 iterations can reach the 5.7 degrees of pursuit that 1 m needs in six steps (the
#: paper's largest step, 0.2 degrees, needs 29 of them). A largest step of 2 degrees (the default
#: before 2026-12-02) made the greedy policy of near trials cycle between states 2 degrees apart
#: (docs/results.md, "A smaller largest step").
DEFAULT_ACTIONS_DEG = (-1.0, -0.5, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.5, 1.0)


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




@dataclass
class LearnerConfig:
    """Hyperparameters of :class:`JointLearner`.

    Defaults are the paper's values where it gives them and they can reach the targets; where
    they differ (action set, reward, actor-critic settings) docs/paper-mapping.md says why, and
    ``preset=paper`` (:data:`aectorch.runtime.config.PAPER_PRESET`) restores the paper's values.

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
    algorithm: Algorithm = Algorithm.mp
    scales: tuple[str, ...] = DEFAULT_SCALES
    centred_patches: bool = True
    render_scales: bool = True
    dictionary_lr: float = 0.1
    dictionary_decay: Optional[float] = 500.0
    dictionary_decay_power: float = 1.0
    pooling: Pooling = Pooling.mean
    feature_scale: float = 10.0
    actions_deg: tuple[float, ...] = DEFAULT_ACTIONS_DEG
    control: ActorCriticConfig = field(default_factory=lambda: default_control())
    skip_fixation_boundary: bool = True
    reward: Reward = Reward.improvement
    features: Features = Features.pooled
    symmetry: tuple[str, ...] = ("parallax", "stereo")
    depth_hidden: int = 10
    depth_every_trials: int = 256
    depth_max_samples: int = 20000
    depth_max_epochs: int = 200

    def __post_init__(self) -> None:
        owner = "LearnerConfig"
        self.algorithm = check_choice(self.algorithm, f"{owner}.algorithm", Algorithm)
        self.features = check_choice(self.features, f"{owner}.features", Features)
        self.reward = check_choice(self.reward, f"{owner}.reward", Reward)
        self.pooling = check_choice(self.pooling, f"{owner}.pooling", Pooling)
        self.scales = tuple(self.scales)
        try:
            self.actions_deg = tuple(float(a) for a in self.actions_deg)
        except (TypeError, ValueError):
            raise ValueError(f"{owner}.actions_deg must be a list of numbers (degrees), got {self.actions_deg!r}") from None
        self._check_symmetry(owner)
        if not self.scales or any(s not in SCALE_NAMES for s in self.scales):
            raise ValueError(f"{owner}.scales must be a non-empty subset of {SCALE_NAMES}, got {self.scales!r}")
        for name in ("num_atoms", "sparsity", "depth_hidden", "depth_every_trials",
                     "depth_max_samples", "depth_max_epochs"):
            check_int(getattr(self, name), f"{owner}.{name}", 1)
        check_real(self.feature_scale, f"{owner}.feature_scale", above=0)
        check_real(self.dictionary_lr, f"{owner}.dictionary_lr", minimum=0)
        check_bool(self.render_scales, f"{owner}.render_scales")
        check_bool(self.centred_patches, f"{owner}.centred_patches")
        if self.dictionary_decay is not None and not (is_real(self.dictionary_decay) and self.dictionary_decay > 0):
            raise ValueError(f"{owner}.dictionary_decay must be null or a number > 0, got {self.dictionary_decay!r}")
        check_real(self.dictionary_decay_power, f"{owner}.dictionary_decay_power", above=0)
        if isinstance(self.control, dict):
            self.control = ActorCriticConfig(**self.control)

    def _check_symmetry(self, owner: str) -> None:
        try:
            self.symmetry = tuple(self.symmetry)
        except TypeError:
            self.symmetry = (self.symmetry,)
        if any(c not in Cue.values() for c in self.symmetry) or len(set(self.symmetry)) != len(self.symmetry):
            raise ValueError(f"{owner}.symmetry must be a list of distinct cues from ('parallax', 'stereo'), "
                             f"got {list(self.symmetry)!r}")
        self.symmetry = tuple(str(c) for c in self.symmetry)
        if self.symmetry and sorted(-a for a in self.actions_deg) != sorted(self.actions_deg):
            raise ValueError(f"{owner}.actions_deg must be symmetric (-a for every a) with "
                             f"{owner}.symmetry={list(self.symmetry)!r}, got {list(self.actions_deg)!r}; "
                             "use a symmetric set or symmetry=[]")
        if self.symmetry and self.num_atoms % 2:
            raise ValueError(f"{owner}.num_atoms must be even with {owner}.symmetry (atoms come in "
                             f"pairs), got {self.num_atoms}")
