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
from typing import NamedTuple

import torch
from torch import Tensor, nn

from aectorch.coding import BinocularEncoder
from aectorch.coding.patches import as_scale
from aectorch.control import NaturalActorCritic
from aectorch.depth.learner import DepthLearner
from aectorch.framework.config import LearnerConfig
from aectorch.framework.cue import CueLearner, CueRecord
from aectorch.framework.shard import Shard
from aectorch.profiling import stage

__all__ = ["IterationRecord", "JointLearner"]


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
            (`Shard`; the environment gets the same slice; default: one process, `Shard.single`): the learning
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
        shard: Shard | None = None,
    ) -> None:
        super().__init__()
        self.config = config = config or LearnerConfig()
        self.generator = generator or torch.Generator().manual_seed(0)
        self.shard = shard = shard or Shard.single()
        scales = [dataclasses.replace(as_scale(s), centred=True) if config.centred_patches else s
                  for s in config.scales]
        kwargs = dict(num_atoms=config.num_atoms, sparsity=config.sparsity, algorithm=config.algorithm,
                      scales=scales, lr=config.dictionary_lr, pooling=config.pooling,
                      generator=self.generator, dtype=dtype, device=device)
        parallax = BinocularEncoder(**kwargs, symmetry="mirror" if "parallax" in config.symmetry else None)
        stereo = BinocularEncoder(**kwargs, symmetry="swap" if "stereo" in config.symmetry else None)
        agent = dict(actions_deg=config.actions_deg, config=config.control,
                     generator=self.generator, dtype=dtype, device=device)
        pursuit = NaturalActorCritic(parallax.num_features, **agent)
        vergence = NaturalActorCritic(stereo.num_features, **agent)
        cue = dict(config=config, generator=self.generator, shard=shard)
        self.parallax_cue = CueLearner(parallax, pursuit, **cue)
        self.stereo_cue = CueLearner(stereo, vergence, **cue)
        self.depth_learner = DepthLearner(
            config.depth_hidden, every_trials=config.depth_every_trials, max_samples=config.depth_max_samples,
            max_epochs=config.depth_max_epochs, generator=self.generator, device=device, dtype=dtype)
        # Checkpoints name the parts as they were before the cue and depth learners existed.
        self.register_state_dict_post_hook(_old_names)
        self.register_load_state_dict_pre_hook(_new_names)
        self.register_load_state_dict_post_hook(_report_old_names)

    # -- the parts, by the names the paper's roles give them ----------------------------------------
    parallax = property(lambda self: self.parallax_cue.encoder, doc="The motion-parallax `BinocularEncoder` (cue m).")
    stereo = property(lambda self: self.stereo_cue.encoder, doc="The stereo `BinocularEncoder` (cue s).")
    pursuit = property(lambda self: self.parallax_cue.agent, doc="Pursuit's `NaturalActorCritic`.")
    vergence = property(lambda self: self.stereo_cue.agent, doc="Vergence's `NaturalActorCritic`.")
    depth = property(lambda self: self.depth_learner.mlp, doc="The `DepthMLP`.")
    depth_inputs = property(lambda self: self.depth_learner.inputs, doc="Stored trials' q ``[n, 4]``.")
    depth_targets = property(lambda self: self.depth_learner.targets, doc="Their distances ``[n]``.")
    depth_trained = property(lambda self: self.depth_learner.trained, doc="Whether the MLP was fitted.")
    trials_seen = property(lambda self: self.depth_learner.trials_seen, doc="Finished trials so far.")

    @property
    def dictionary_steps(self) -> dict[str, int]:
        """Learning steps each cue's dictionaries took, ``{"m": ..., "s": ...}``."""
        return {"m": self.parallax_cue.dictionary_steps, "s": self.stereo_cue.dictionary_steps}

    def dictionary_rate(self, steps: int) -> float:
        """The dictionaries' learning rate after ``steps`` steps (``dictionary_decay``)."""
        return self.parallax_cue.dictionary_rate(steps)

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
        parallax = self.parallax_cue.step(pair, learn=learn, greedy=greedy)
        with stage("env"):
            env.apply_pursuit(parallax.increments_deg)
        with stage("render"):
            pair = env.stereo_observation() if scales is None else env.stereo_observation(scales=scales)
        stereo = self.stereo_cue.step(pair, learn=learn, greedy=greedy)
        with stage("env"):
            info = env.apply_vergence(stereo.increments_deg)
        if info.fixation_end and self.config.skip_fixation_boundary:
            self.forget_transitions()
        prediction, retrained = None, False
        if info.trial_end:
            with stage("depth"):
                prediction = self.predict_depth(info.q_deg)
                if learn:
                    retrained = self.depth_learner.add_trials(info.q_deg, info.distance_m, self.shard.gather)
        return IterationRecord(
            parallax=parallax, stereo=stereo,
            pursuit_error_deg=info.pursuit_error_deg, vergence_error_deg=info.vergence_error_deg,
            fixation_end=info.fixation_end, trial_end=info.trial_end,
            q_deg=info.q_deg, distance_m=info.distance_m,
            depth_prediction_m=prediction, depth_retrained=retrained,
        )

    def forget_transitions(self) -> None:
        """Start the next iteration without a previous transition (e.g. after ``env.reset``)."""
        self.parallax_cue.forget()
        self.stereo_cue.forget()

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
        return self.depth_learner.calibrate(q_deg, distance_m, seed=seed)

    # -- checkpoints -------------------------------------------------------------------------------
    @staticmethod
    def state_name(name: str) -> str:
        """The checkpoint's name of a parameter or buffer named ``name`` by ``named_parameters``
        (``"stereo_cue.encoder.dictionaries.fine.atoms"`` -> ``"stereo.dictionaries.fine.atoms"``)."""
        return _checkpoint_name(name)

    def get_extra_state(self) -> dict:
        return {
            "trials_seen": self.depth_learner.trials_seen,
            "trials_at_last_fit": self.depth_learner.trials_at_last_fit,
            "previous": {"m": self.parallax_cue.previous, "s": self.stereo_cue.previous},
            "generator": self.generator.get_state(),
            "dictionary_steps": self.dictionary_steps,
        }

    def set_extra_state(self, state: dict) -> None:
        self.depth_learner.trials_seen = int(state["trials_seen"])
        self.depth_learner.trials_at_last_fit = int(state["trials_at_last_fit"])
        self.parallax_cue.previous, self.stereo_cue.previous = state["previous"]["m"], state["previous"]["s"]
        self.generator.set_state(state["generator"])
        # Checkpoints from before the count existed: their learners had a constant rate.
        steps = state.get("dictionary_steps", {"m": 0, "s": 0})
        self.parallax_cue.dictionary_steps, self.stereo_cue.dictionary_steps = int(steps["m"]), int(steps["s"])


#: The parts' state-dict prefixes, as checkpoints name them (the names from before the cue and
#: depth learners existed, so every checkpoint loads) -> as the modules name them.
_STATE_NAMES = (
    ("parallax.", "parallax_cue.encoder."),
    ("pursuit.", "parallax_cue.agent."),
    ("stereo.", "stereo_cue.encoder."),
    ("vergence.", "stereo_cue.agent."),
    ("depth.", "depth_learner.mlp."),
    ("depth_inputs", "depth_learner.inputs"),
    ("depth_targets", "depth_learner.targets"),
    ("depth_trained", "depth_learner.trained"),
)


def _rename(state_dict, prefix: str, pairs) -> None:
    """Rename, in place and in order, the keys of ``state_dict`` under ``prefix`` by ``pairs``."""
    items = list(state_dict.items())
    state_dict.clear()
    for key, value in items:
        if key.startswith(prefix):
            local = key[len(prefix):]
            for old, new in pairs:
                if local.startswith(old):
                    key = prefix + new + local[len(old):]
                    break
        state_dict[key] = value


def _old_names(module, state_dict, prefix, local_metadata):
    _rename(state_dict, prefix, [(new, old) for old, new in _STATE_NAMES])


def _new_names(module, state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs):
    _rename(state_dict, prefix, _STATE_NAMES)


def _report_old_names(module, incompatible_keys) -> None:
    """Missing and unexpected keys named as the checkpoint names them."""
    for keys in (incompatible_keys.missing_keys, incompatible_keys.unexpected_keys):
        keys[:] = [_checkpoint_name(key) for key in keys]


def _checkpoint_name(key: str) -> str:
    """``key`` (possibly under a parent module's prefix) with the part's checkpoint name."""
    for old, new in _STATE_NAMES:
        at = key.find(new)
        if at != -1 and (at == 0 or key[at - 1] == "."):
            return key[:at] + old + key[at + len(new):]
    return key
