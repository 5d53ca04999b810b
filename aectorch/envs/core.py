"""`EyeTask`: the batched core behind the standard environments, torch in and torch out.

One `EyeTask` holds one batched :class:`~aectorch.sim.ActiveDepthEnv` (N environments in
lockstep) and, for the coding observation or reward, one internal
:class:`~aectorch.coding.BinocularEncoder` per learned cue, which learns online from what it
codes (active efficient coding: the agent's reward is how well the code it shapes reconstructs
what its eyes see). The Gymnasium, TorchRL and Stable-Baselines3 adapters
(`aectorch.envs.gym`, `aectorch.envs.torchrl`, `aectorch.envs.sb3`) only convert at their
boundary.

The three tasks (``task``):

- ``"vergence"``: one fixation of h steps; the action is the vergence increment; pursuit is held
  at its optimum (the lineage's vergence-only model). The observation is the stereo pair.
- ``"pursuit"``: one fixation of h steps; the action is the pursuit increment; vergence is held
  at its optimum. The observation is the motion-parallax pair.
- ``"accommodation"``: one fixation of h steps; the action is the accommodation increment (degrees
  of the blur disc's diameter: both eyes' focus); pursuit and vergence are held at their optimum.
  The observation is the stereo pair; the coding reward is the information the code keeps
  (`aectorch.coding.focus`), which prefers focus. Each fixation starts focused at
  ``accommodation_start_D`` (default 0 D, infinity).
- ``"active_depth"``: a whole trial, both fixations (2h steps); the action is the pair (pursuit,
  vergence increment); the observation holds both cues' pairs, observed at the start of the
  iteration (the joint learner observes the stereo pair after the pursuit step instead).

A step takes the action(s), ends the environment's iteration and observes the next state. An
episode ends by its time limit (``truncated``; never ``terminated``), in every environment at
once; the environment then continues by itself with its next fixation (the other body shift of
the same trial, or a new trial): :meth:`EyeTask.step` returns that episode's first observation
and the ended episode's last one as ``final_observation`` (Gymnasium's ``SAME_STEP`` autoreset).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_choice, check_int
from aectorch.choices import Choice
from aectorch.coding import BinocularEncoder, EncoderConfig
from aectorch.coding.focus import focus_reward, input_energy
from aectorch.coding.patches import DEFAULT_SCALES, as_scale
from aectorch.control import DEFAULT_ACTIONS_DEG, RewardScale, learned_reward
from aectorch.sim import DEFAULT_DISTANCES_M, DEFAULT_PROTOCOL, ActiveDepthEnv, TextureBank, TrialProtocol

__all__ = ["EyeTask", "Observation", "Reward", "Step", "Task", "TaskConfig"]


class Task(Choice):
    """The environments: `aectorch/Vergence-v0`, `aectorch/Pursuit-v0`, `aectorch/ActiveDepth-v0`,
    `aectorch/Accommodation-v0`."""

    vergence = "vergence"
    pursuit = "pursuit"
    accommodation = "accommodation"
    active_depth = "active_depth"


class Observation(Choice):
    """``features``: the pooled sparse code of the internal encoder (eq. 5) times ``feature_scale``;
    ``images``: each scale's binocular pair."""

    features = "features"
    images = "images"


class Reward(Choice):
    """The intrinsic rewards, from the internal encoder's coding reward R = -(e^C + e^F) (summed over
    the cues), in the forms the joint learner has (`aectorch.control.rewards.learned_reward`):
    ``improvement`` (the default): R(s') - R(s), the change the step caused; ``coding``: R(s') of
    the next observation; ``scaled``: the improvement over a running root mean square of itself.
    And ``error``: minus the absolute angle error(s) after the step, in degrees (an oracle
    baseline)."""

    improvement = "improvement"
    coding = "coding"
    scaled = "scaled"
    error = "error"


#: The cues each task observes (in the environment's order) and the movements it acts on.
_CUES = {Task.vergence: ("stereo",), Task.pursuit: ("parallax",), Task.active_depth: ("parallax", "stereo"),
         Task.accommodation: ("accommodation",)}
_HELD = {Task.vergence: ("parallax",), Task.pursuit: ("stereo",), Task.active_depth: (),
         Task.accommodation: ("parallax", "stereo")}


@dataclass
class TaskConfig:
    """The options of the standard environments (keyword arguments of ``gymnasium.make``).

    Attributes:
        task: ``vergence``, ``pursuit`` or ``active_depth`` (set by the id).
        observation: ``features`` (default) or ``images``.
        reward: ``scaled`` (default: the improvement over a running scale, what the documented
            agents learn from; SB3's PPO ends 3.3x closer on it than on the raw improvement, whose
            size is a few thousandths: docs/rl-environments.md), ``improvement``, ``coding`` or
            ``error`` (`Reward`).
        actions_deg: the action set of pan increments (default `DEFAULT_ACTIONS_DEG`).
        textures: a folder of images, a `TextureBank`, or ``None`` (the 100 procedural training
            textures, ``TextureBank.default("train")``).
        distances_m: the plane distances a trial draws from (default 1.0 to 3.0 m in 0.1 m steps).
        fixation_iterations: h, the steps of a fixation (default 30).
        scales: the foveal scales of the observation and of the encoder (default `DEFAULT_SCALES`:
            wide, coarse, fine, full).
        encoder: the internal encoder's settings (`EncoderConfig`; default the learner's).
        learn_encoder: the internal encoder takes one dictionary step per step (default true).
        feature_scale: the features observed are ``feature_scale * f`` (default 10).
        renderer: ``torch`` (default) or ``pyrender``.
        object_speed_deg: a moving target: ``(low, high)``, the range of the object's sideways
            speed in degrees per step, drawn per fixation (``(-1, 1)``: both directions; default
            ``(0, 0)``: it stands still; `aectorch.sim.TrialProtocol`).
        object_depth_speed_m: the range of its speed in depth, metres per step, drawn per trial
            (negative: approaching; default ``(0, 0)``). ``info["distance_m"]`` is where it is.
        accommodation_start_D: with ``task="accommodation"``, both eyes' focus at each fixation's
            start, dioptres (default 0: infinity, the relaxed eye).
        pan_range_deg: ``(low, high)``, each eye's pan range in degrees (default +-45, the
            HOAP-3's joint limits), and
        vergence_range_deg: ``(low, high)``, the vergence's (default -2 to 40): the oculomotor
            range every step ends within (`aectorch.sim.oculomotor`).
        device: the torch device of the simulation and the encoder.
    """

    task: Task = Task.vergence
    observation: Observation = Observation.features
    reward: Reward = Reward.scaled
    actions_deg: Sequence[float] = DEFAULT_ACTIONS_DEG
    textures: object = None
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M
    fixation_iterations: int = DEFAULT_PROTOCOL.fixation_iterations
    scales: Sequence[str] = DEFAULT_SCALES
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    learn_encoder: bool = True
    feature_scale: float = 10.0
    renderer: str = DEFAULT_PROTOCOL.renderer
    object_speed_deg: Sequence[float] = DEFAULT_PROTOCOL.object_speed_deg
    object_depth_speed_m: Sequence[float] = DEFAULT_PROTOCOL.object_depth_speed_m
    accommodation_start_D: float = 0.0
    pan_range_deg: Sequence[float] = DEFAULT_PROTOCOL.pan_range_deg
    vergence_range_deg: Sequence[float] = DEFAULT_PROTOCOL.vergence_range_deg
    device: str = "cpu"

    def __post_init__(self) -> None:
        self.task = check_choice(self.task, "task", Task)
        self.observation = check_choice(self.observation, "observation", Observation)
        self.reward = check_choice(self.reward, "reward", Reward)
        self.actions_deg = tuple(float(a) for a in self.actions_deg)
        if not self.actions_deg:
            raise ValueError("actions_deg must be a non-empty list of pan increments (degrees)")
        self.scales = tuple(as_scale(s).name for s in self.scales)
        protocol = self.protocol  # the trial's fields, checked by `TrialProtocol`
        for name in ("object_speed_deg", "object_depth_speed_m", "pan_range_deg", "vergence_range_deg"):
            setattr(self, name, getattr(protocol, name))
        if isinstance(self.encoder, dict):
            self.encoder = EncoderConfig(**self.encoder)

    @property
    def protocol(self) -> TrialProtocol:
        """The trial protocol of these options (`TrialProtocol`; the accommodation start only
        with ``task="accommodation"``)."""
        return TrialProtocol(renderer=self.renderer, fixation_iterations=self.fixation_iterations,
                             object_speed_deg=self.object_speed_deg, object_depth_speed_m=self.object_depth_speed_m,
                             accommodation_start_D=self.accommodation_start_D if self.task == Task.accommodation
                             else None, pan_range_deg=self.pan_range_deg, vergence_range_deg=self.vergence_range_deg)


class Step(NamedTuple):
    """What :meth:`EyeTask.step` returns (torch tensors, ``[N]`` unless noted)."""

    observation: dict[str, Tensor]  #: the next observation (a new episode's first when ``truncated``)
    reward: Tensor
    truncated: bool  #: the episode ended by its time limit (in every environment at once)
    final_observation: dict[str, Tensor] | None  #: the ended episode's last observation, when ``truncated``
    info: dict[str, Tensor]  #: ``distance_m``, ``pursuit_error_deg``, ``vergence_error_deg``, the eye angles


class EyeTask:
    """N simulated heads as one batched task (see the module docstring).

    Args:
        num_envs: N.
        config: the options (`TaskConfig`); ``**options`` replace its fields.
        seed: the first :meth:`reset`'s seed.

    Attributes:
        env: the `ActiveDepthEnv`.
        encoders: the internal encoder of each observed cue (empty with ``observation="images"``
            and ``reward="error"``).
        episode_steps: steps per episode (h, or 2h for ``active_depth``).
        observation_shapes: ``{key: shape without N}`` of the observation's entries: ``features``
            ``(F,)``, or ``<cue>/<scale>`` ``(2, side, side)``.

    Example:
        >>> task = EyeTask(2, TaskConfig(fixation_iterations=3, textures=torch.rand(2, 64, 64)), seed=0)
        >>> obs = task.reset(seed=0)
        >>> step = task.step(torch.tensor([5, 5]))   # index 5 of DEFAULT_ACTIONS_DEG: 0 deg
        >>> obs["features"].shape, step.reward.shape, step.truncated
        (torch.Size([2, 1152]), torch.Size([2]), False)
    """

    def __init__(self, num_envs: int = 1, config: TaskConfig | None = None, *, seed: int | None = None, **options) -> None:
        check_int(num_envs, "num_envs")
        config = TaskConfig(**options) if config is None else (
            TaskConfig(**{**config.__dict__, **options}) if options else config)
        self.config, self.num_envs = config, num_envs
        self.cues = _CUES[config.task]
        textures = config.textures
        if textures is None:
            textures = TextureBank.default("train")
        elif isinstance(textures, str):
            textures = TextureBank.from_folder(textures)
        self.env = ActiveDepthEnv(num_envs, protocol=config.protocol, textures=textures, distances_m=config.distances_m,
                                  device=config.device, seed=0 if seed is None else seed)
        self.device = self.env.device
        self.scales = tuple(as_scale(s) for s in config.scales)
        self.actions_deg = torch.tensor(config.actions_deg, dtype=self.env.dtype, device=self.device)
        self.needs_encoder = config.observation == Observation.features or config.reward != Reward.error
        self.encoders: dict[str, BinocularEncoder] = {}
        self.reward_scale: RewardScale | None = None  # the ``scaled`` reward's running scale
        self._previous: Tensor | None = None  # the coding reward of the current observation
        self._loaded = False  # encoders given by load_encoders stay across seeded resets
        self._seed_encoders(0 if seed is None else seed)
        per_fixation = config.fixation_iterations
        self.episode_steps = 2 * per_fixation if config.task == Task.active_depth else per_fixation
        self.steps = 0
        if config.observation == Observation.features:
            self.observation_shapes = {"features": (len(self.cues) * len(self.scales) * config.encoder.num_atoms,)}
        else:
            self.observation_shapes = {f"{cue}/{s.name}": (2, s.crop // s.downsample, s.crop // s.downsample)
                                       for cue in self.cues for s in self.scales}

    @property
    def features_high(self) -> float:
        """The largest feature value: a binocular patch has norm^2 2 (each half unit norm) and
        matching pursuit's coefficients never hold more energy than the patch; OMP's may
        (then the largest float32)."""
        if str(self.config.encoder.algorithm) == "mp":
            return 2.0 * self.config.feature_scale
        return float(torch.finfo(torch.float32).max)

    def _seed_encoders(self, seed: int) -> None:
        if not self.needs_encoder:
            return
        generator = torch.Generator().manual_seed(int(seed))
        self.reward_scale = RewardScale().to(self.device) if self.config.reward == Reward.scaled else None
        self.encoders = {cue: BinocularEncoder(self.config.encoder, self.scales, generator=generator,
                                               dtype=self.env.dtype, device=self.device) for cue in self.cues}

    def load_encoders(self, encoders: dict) -> None:
        """Take over the internal encoders' states (``{cue: BinocularEncoder or its state dict}``,
        e.g. another task's ``encoders``: to evaluate a policy on the features it learned with).
        Loaded encoders stay across seeded resets; with ``learn_encoder=False`` they stay frozen."""
        missing = [cue for cue in self.encoders if cue not in encoders]
        if missing or not self.encoders:
            raise ValueError(f"encoders must hold the cues {list(self.encoders)} (this task's), got {list(encoders)}")
        for cue, encoder in self.encoders.items():
            given = encoders[cue]
            encoder.load_state_dict(given.state_dict() if hasattr(given, "state_dict") else given)
        self._loaded = True

    # -- the episode ------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, *, keep_encoders: bool = False) -> dict[str, Tensor]:
        """Start a new trial in every environment (``seed``: its textures and distances, and the
        internal encoders start anew from it unless ``keep_encoders``; without a seed they keep
        what they learned)."""
        if seed is not None and not keep_encoders and not self._loaded:
            self._seed_encoders(seed)
        self.env.reset(seed)
        self.steps = 0
        observation, self._previous = self._observe(learn=False)
        return observation

    def step(self, actions: Tensor) -> Step:
        """Take the actions (indices into ``actions_deg``: ``[N]``, or ``[N, 2]`` (pursuit,
        vergence) for ``active_depth``) and observe the next state."""
        increments = self._increments(actions)
        for cue, increment in zip(self.cues, increments):
            self.env.act(cue, increment)
        self.steps += 1
        truncated = self.steps == self.episode_steps
        final = None
        if truncated:  # the ended episode's last state, before the environment moves on
            final, coding = self._observe(learn=True)
        info = self.env.end_iteration()
        errors = info.errors_deg
        details = {"distance_m": self.env.object_distance_m.clone() if info.distance_m is None else info.distance_m,
                   "pursuit_error_deg": info.pursuit_error_deg, "vergence_error_deg": info.vergence_error_deg,
                   "left_pan_deg": info.left_pan_deg, "right_pan_deg": info.right_pan_deg,
                   **{f"{m}_error_deg": e for m, e in (info.extra_errors_deg or {}).items()}}
        if truncated:  # the next episode's first observation: its improvements start from it
            self.steps = 0
            observation, first = self._observe(learn=False)
        else:
            observation, coding = self._observe(learn=True)
            first = coding
        if self.config.reward == Reward.error:
            reward = -sum(errors[self.env.cue(cue).name].abs() for cue in self.cues)
        else:
            reward = learned_reward(self.config.reward.value, coding, self._previous, self.reward_scale)
        self._previous = first
        return Step(observation, reward, truncated, final, details)

    def _increments(self, actions: Tensor) -> list[Tensor]:
        actions = torch.as_tensor(actions, device=self.device).to(torch.int64)
        shape = (self.num_envs, len(self.cues)) if len(self.cues) > 1 else (self.num_envs,)
        if tuple(actions.shape) != shape:
            raise ValueError(f"actions must have shape {list(shape)} (indices into actions_deg), got {list(actions.shape)}")
        if bool(((actions < 0) | (actions >= len(self.actions_deg))).any()):
            raise ValueError(f"actions must be indices in [0, {len(self.actions_deg)}), got {actions.tolist()}")
        columns = actions[:, None] if actions.ndim == 1 else actions
        return [self.actions_deg[columns[:, i]] for i in range(len(self.cues))]

    def _observe(self, *, learn: bool) -> tuple[dict[str, Tensor], Tensor | None]:
        """The held movements put at their optimum, then each cue's pair (and, with an encoder,
        its code: features, coding reward, and a dictionary step when ``learn``)."""
        for cue in _HELD[self.config.task]:
            self.env.hold(cue)
        images, features, reward = {}, [], None
        for cue in self.cues:
            pairs = self.env.observe(cue, self.scales)
            if self.config.observation == Observation.images:
                images.update({f"{cue}/{name}": pair.clamp(0, 1) for name, pair in pairs.items()})
            if self.needs_encoder:
                encoder = self.encoders[cue]
                with torch.no_grad():
                    out = encoder.encode(pairs)
                    if learn and self.config.learn_encoder:
                        encoder.learn_(out)
                    if cue == "accommodation":  # the information the code keeps: it prefers focus
                        out = out._replace(reward=focus_reward([input_energy(pairs[s.name], s) for s in self.scales],
                                                               [code.error for code in out.codes]))
                features.append(out.features * self.config.feature_scale)
                reward = out.reward if reward is None else reward + out.reward
        observation = images if self.config.observation == Observation.images else {"features": torch.cat(features, -1)}
        return observation, reward

    def close(self) -> None:
        """Free the renderers (OpenGL contexts); safe to call twice."""
        self.env.close()
