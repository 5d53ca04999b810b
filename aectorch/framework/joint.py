"""``JointLearner``: the paper's joint learning framework (sections 2-3), batched over B environments.

It composes one learner per depth cue and the depth learner, and drives an
:class:`~aectorch.sim.ActiveDepthEnv`:

- a :class:`CueLearner` per cue of ``config.cues`` (by default the paper's two: motion parallax,
  *m*, the dominant eye before and after the body shift, which drives pursuit; stereo, *s*, both
  eyes, which drives vergence), each a `BinocularEncoder` (a dictionary per scale) and an
  `Agent` (the natural actor-critic, or PPO) built from the cue's `CueConfig`;
- the :class:`~aectorch.depth.DepthMLP`, retrained with our Levenberg-Marquardt on the final eye
  movements ``q`` of the trials seen so far (`aectorch.depth.DepthLearner`).

One :meth:`JointLearner.iteration` advances every environment by one iteration: for each cue of
the environment, in its order (step k1 parallax, step k2 stereo), the cue's observation ->
encode -> features f and reward R = -(e^C + e^F) -> the agent learns the previous transition
(reward R is the reward of the previous action: the coding quality its movement led to) -> the
next action -> one dictionary step on the observation -> the environment applies the action. A
cue the learner does not learn (``config.active_cues``) is held at its optimum by the
environment instead.

Transitions that cross a fixation boundary (a new start state, or a new texture and distance)
are not learned from (``skip_fixation_boundary``; the last state of a fixation does not lead to
the first of the next). Each finished trial's ``q`` is first predicted by the current depth MLP
(so the online depth error is honest) and then joins the depth training data. With B = 1 this is
the paper's sequential algorithm; with B > 1 every learner takes the mean of the B
per-environment updates (see the learners' docstrings).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import torch
from torch import Tensor, nn

from aectorch.depth.learner import DepthLearner
from aectorch.framework.config import LearnerConfig
from aectorch.framework.cue import CueLearner
from aectorch.framework.plasticity import Plasticity, Reopening
from aectorch.framework.shard import Shard
from aectorch.profiling import stage

__all__ = ["IterationRecord", "JointLearner"]

#: ``watch(cue, observation)``: called by `JointLearner.iteration` right after each cue's observation,
#: which then also holds the whole rendered window (``observation["window"]``).
Watch = Callable[[str, dict], None]


class IterationRecord(NamedTuple):
    """What :meth:`JointLearner.iteration` returns.

    ``record.<cue>`` is ``record.cues[<cue>]`` and ``record.<movement>_error_deg`` is
    ``record.errors_deg[<movement>]`` (e.g. ``record.stereo``, ``record.vergence_error_deg``).
    """

    cues: dict  #: ``{cue: CueRecord}`` of the cues the learner learns, in the environment's order
    errors_deg: dict  #: ``{movement: [B]}`` each eye movement's error after this iteration (actual - optimal)
    fixation_end: bool
    trial_end: bool
    q_deg: Tensor | None  #: ``[B, 4]`` at a trial's end
    distance_m: Tensor | None  #: ``[B]`` true distance at a trial's end
    depth_prediction_m: Tensor | None  #: ``[B]`` the MLP's estimate before it saw these trials
    depth_retrained: bool

    def __getattr__(self, name: str):
        cues = tuple.__getitem__(self, 0)
        if name in cues:
            return cues[name]
        if name.endswith("_error_deg") and name[: -len("_error_deg")] in tuple.__getitem__(self, 1):
            return tuple.__getitem__(self, 1)[name[: -len("_error_deg")]]
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r} (cues: {list(cues)})")


class JointLearner(nn.Module):
    """The paper's agent: sparse coding, eye-movement learning and depth learning, together.

    Args:
        config: hyperparameters (:class:`LearnerConfig`).
        generator: seeds the initial dictionaries and policies and draws the actions.
        device, dtype: of every learner.
        shard: this process's part of a batch split across processes
            (`Shard`; the environment gets the same slice; default: one process, `Shard.single`): the learning
            steps reduce over every process, the depth MLP trains on every process's trials and
            actions are drawn for the whole batch, so all processes keep identical learners.

    Attributes:
        cues: one `CueLearner` per learned cue (``config.learned_cues``), by name (also
            ``learner.<cue>``, e.g. ``learner.stereo.encoder``, ``learner.stereo.agent``).
        depth_learner: the `DepthLearner` (its MLP also as ``learner.depth``).

    Example:
        >>> import torch
        >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
        >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
        ...                      seed=0)
        >>> config = LearnerConfig(active_cues=["stereo"])      # the vergence-only model
        >>> learner = JointLearner(config, generator=torch.Generator().manual_seed(0))
        >>> record = learner.iteration(env)
        >>> list(record.cues), record.stereo.reward.shape, record.errors_deg["pursuit"].abs().max() < 1e-4
        (['stereo'], torch.Size([2]), tensor(True))
    """

    def __init__(
        self,
        config: LearnerConfig | None = None,
        *,
        generator: torch.Generator | None = None,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        shard: Shard | None = None,
    ) -> None:
        super().__init__()
        self.config = config = config or LearnerConfig()
        self.generator = generator or torch.Generator().manual_seed(0)
        self.shard = shard = shard or Shard.single()
        names = config.learned_cues
        made = dict(generator=self.generator, dtype=dtype, device=device)
        # Every encoder first, then every agent: the generator's draws in the order they always had,
        # so a seed gives the same initial learner as before the cues were data.
        encoders = {name: CueLearner.build_encoder(config.cues[name], **made) for name in names}
        agents = {name: CueLearner.build_agent(config.cues[name], encoders[name].num_features, **made)
                  for name in names}
        self.cues = nn.ModuleDict({
            name: CueLearner(config.cues[name], encoders[name], agents[name], generator=self.generator, shard=shard)
            for name in names})
        #: when each cue learns (``learn_until``, ``reopen_drop``): plain state, saved by the
        #: training loop beside the module's (``checkpoint["plasticity"]``)
        self.plasticity = Plasticity({name: config.cues[name] for name in names})
        self.depth_learner = DepthLearner(
            config.depth_hidden, every_trials=config.depth_every_trials, max_samples=config.depth_max_samples,
            max_epochs=config.depth_max_epochs, generator=self.generator, device=device, dtype=dtype)

    def __getattr__(self, name: str):
        # `learner.stereo` reaches the cue learner of that name.
        try:
            return super().__getattr__(name)
        except AttributeError:
            cues = self._modules.get("cues")
            if cues is not None and name in cues:
                return cues[name]
            raise

    # -- the parts ---------------------------------------------------------------------------------
    depth = property(lambda self: self.depth_learner.mlp, doc="The `DepthMLP`.")
    depth_inputs = property(lambda self: self.depth_learner.inputs, doc="Stored trials' q ``[n, 4]``.")
    depth_targets = property(lambda self: self.depth_learner.targets, doc="Their distances ``[n]``.")
    depth_trained = property(lambda self: self.depth_learner.trained, doc="Whether the MLP was fitted.")
    trials_seen = property(lambda self: self.depth_learner.trials_seen, doc="Finished trials so far.")

    @property
    def dictionary_steps(self) -> dict[str, int]:
        """Learning steps each cue's dictionaries took, by cue."""
        return {name: cue.encoder.steps for name, cue in self.cues.items()}

    def dictionaries(self) -> dict[str, Tensor]:
        """Every dictionary's atoms ``[P, N]`` by ``"<cue>/<scale>"`` (the parameters themselves)."""
        return {f"{name}/{scale}": d.atoms for name, cue in self.cues.items()
                for scale, d in cue.encoder.dictionaries.items()}

    # -- the schedule ----------------------------------------------------------------------------
    def closed_cues(self, iteration: int) -> tuple[str, ...]:
        """The cues that learn nothing at training iteration ``iteration`` (0-based): those whose
        ``learn_until`` (`CueConfig`) it has reached, unless their coding reward has reopened them
        (``reopen_drop``; `plasticity`, fed by the training loop through `observe_rewards`)."""
        return self.plasticity.closed(iteration)

    def observe_rewards(self, iteration: int, record: IterationRecord) -> list[Reopening]:
        """Show the closing schedule (`plasticity`) training iteration ``iteration``'s record;
        returns the cues that learn again from the next iteration on."""
        if not self.plasticity.configs:
            return []
        rewards = {name: float(c.reward.double().mean()) for name, c in record.cues.items()
                   if name in self.plasticity.configs}
        return self.plasticity.observe(iteration, rewards)

    def iteration(self, env, *, learn: bool = True, greedy: bool = False, watch: Watch | None = None,
                  closed: tuple[str, ...] = ()) -> IterationRecord:
        """Advance every environment of ``env`` by one iteration (each of its cues' steps).

        Args:
            env: an :class:`~aectorch.sim.ActiveDepthEnv` on this learner's device and dtype.
            learn: update dictionaries, agents and the depth MLP; ``False`` freezes
                everything (evaluation) and leaves no pending transition, so a later learning
                step does not learn from a transition it did not see.
            greedy: take the most probable action instead of sampling.
            watch: ``watch(cue, observation)`` after each cue's observation (which then holds the
                whole window as well, ``observation["window"]``): what the viewer and the LeRobot
                recorder keep.
            closed: cues that learn nothing this iteration although ``learn`` is true (their
                plasticity has closed: `closed_cues`); they act as they would.
        """
        missing = [name for name in self.cues if name not in env.CUES]
        if missing:
            raise ValueError(f"the environment has no cue {missing} (its cues: {list(env.CUES)})")
        last = env.iteration == env.fixation_iterations - 1  # the observations end the fixation
        records = {}
        for name in env.CUES:
            cue = self.cues[name] if name in self.cues else None
            if cue is None:  # a cue this learner does not learn: its movement is held at the optimum
                with stage("env"):
                    env.hold(name)
                continue
            scales = cue.encoder.scales if self.config.render_scales else None
            with stage("render"):
                observation = env.observe(name, scales, window=watch is not None)
            if watch is not None:
                watch(name, observation)
            sensed = env.proprioception(cue.config.proprioception) if cue.config.proprioception else None
            records[name] = cue.step(observation, learn=learn and name not in closed, greedy=greedy, last=last,
                                     proprioception=sensed)
            with stage("env"):
                env.act(name, records[name].increments_deg)
        with stage("env"):
            info = env.end_iteration()
        if info.fixation_end and self.config.skip_fixation_boundary:
            self.forget_transitions()
        prediction, retrained = None, False
        if info.trial_end:
            with stage("depth"):
                prediction = self.predict_depth(info.q_deg)
                if learn:
                    retrained = self.depth_learner.add_trials(info.q_deg, info.distance_m, self.shard.gather)
        return IterationRecord(
            cues=records, errors_deg=info.errors_deg, fixation_end=info.fixation_end, trial_end=info.trial_end,
            q_deg=info.q_deg, distance_m=info.distance_m, depth_prediction_m=prediction, depth_retrained=retrained,
        )

    def raise_plasticity(self, fraction: float) -> dict[str, dict[str, float]]:
        """Make the learners plastic again (after a perturbation, `aectorch.runtime`'s
        ``plasticity.raise_to``): every decayed rate, each cue's dictionaries' learning rate and a
        natural actor-critic's actor step, is raised to ``fraction`` (in (0, 1]) of its starting
        value and decays again from there (`BinocularEncoder.raise_rate`); PPO's step is constant
        and stays. Returns the rates now, ``{cue: {"dictionary": rate, "actor": factor}}``."""
        out = {}
        for name, cue in self.cues.items():
            out[name] = {"dictionary": cue.encoder.raise_rate(fraction)}
            raise_rate = getattr(cue.agent, "raise_rate", None)
            if raise_rate is not None:
                out[name]["actor"] = raise_rate(fraction)
        return out

    def forget_transitions(self) -> None:
        """Start the next iteration without a previous transition (e.g. after ``env.reset``)."""
        for cue in self.cues.values():
            cue.forget()

    # -- depth -------------------------------------------------------------------------------------
    def predict_depth(self, q_deg: Tensor) -> Tensor:
        """The MLP's distance estimate ``[B]`` (metres) from ``q`` ``[B, 4]``; NaN before any training."""
        return self.depth_learner.predict(q_deg)

    def fit_depth(self, *, seed: int | None = None):
        """Retrain the depth MLP on the stored trials with Levenberg-Marquardt (from its current weights)."""
        return self.depth_learner.fit(seed=seed)

    def calibrate_depth(self, q_deg: Tensor, distance_m: Tensor, *, seed: int | None = None):
        """Refit the depth MLP on the given trials only, from its current weights.

        Training fits the MLP on trials made with *sampled* actions, whose final eye angles
        scatter more than those of the greedy policy that is evaluated; refitted on greedy
        trials of the training textures (:func:`aectorch.evaluation.run_trials`), the MLP maps the
        evaluated policy's own ``q`` to distance (``train.depth_calibration_trials``). The
        stored training trials (``depth_inputs``, ``depth_targets``) are not changed.

        Args:
            q_deg: the trials' final eye angles, ``[N, 4]`` (N >= 10).
            distance_m: their true distances, ``[N]``.
            seed: seeds the fit's validation split (default: drawn from the learner's generator).

        Returns:
            The Levenberg-Marquardt fit's result.
        """
        return self.depth_learner.calibrate(q_deg, distance_m, seed=seed)

    # -- checkpoints -------------------------------------------------------------------------------
    def get_extra_state(self) -> dict:
        return {
            "trials_seen": self.depth_learner.trials_seen,
            "trials_at_last_fit": self.depth_learner.trials_at_last_fit,
            "generator": self.generator.get_state(),
        }

    def set_extra_state(self, state: dict) -> None:
        self.depth_learner.trials_seen = int(state["trials_seen"])
        self.depth_learner.trials_at_last_fit = int(state["trials_at_last_fit"])
        self.generator.set_state(state["generator"])
