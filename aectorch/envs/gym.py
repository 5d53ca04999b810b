"""Gymnasium's API over `EyeTask`: `EyeEnv` (one environment, ``gymnasium.make``) and `EyeVectorEnv`
(N environments in lockstep, one batched simulator, ``gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")``).

Inside, everything is torch (`EyeTask`); NumPy appears only at Gymnasium's boundary: observations
``float32``, rewards ``float64``, actions read as integer arrays. The vector environment declares
``metadata["autoreset_mode"] = AutoresetMode.SAME_STEP``: the step that ends an episode (by its
time limit, in every environment at once) returns the next episode's first observation, with the
ended episode's last one in ``infos["final_obs"]`` (and ``infos["final_info"]``), as Gymnasium's
own vector environments do in that mode.

Seeding: ``reset(seed=s)`` restarts the simulation's draws (textures, distances) and the internal
encoders from ``s``; ``reset()`` without a seed starts a new trial drawn from the environment's
``np_random`` and keeps what the encoders learned.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from aectorch.envs.core import EyeTask, Observation, TaskConfig

__all__ = ["EyeEnv", "EyeVectorEnv", "observation_space", "action_space"]


def observation_space(task: EyeTask) -> spaces.Space:
    """The space of one environment's observation."""
    if task.config.observation == Observation.features:
        return spaces.Box(0.0, task.features_high, task.observation_shapes["features"], np.float32)
    return spaces.Dict({key: spaces.Box(0.0, 1.0, shape, np.float32) for key, shape in task.observation_shapes.items()})


def action_space(task: EyeTask) -> spaces.Space:
    """``Discrete(A)``, or ``MultiDiscrete([A, A])`` (pursuit, vergence) for ``active_depth``."""
    n = len(task.actions_deg)
    return spaces.Discrete(n) if len(task.cues) == 1 else spaces.MultiDiscrete([n] * len(task.cues))


def _numpy(observation: dict[str, torch.Tensor], features: bool):
    out = {k: v.detach().to("cpu", torch.float32).numpy() for k, v in observation.items()}
    return out["features"] if features else out


def _row(observation, features: bool, i: int = 0):
    """Environment ``i``'s entry of a batched NumPy observation."""
    return observation[i] if features else {k: v[i] for k, v in observation.items()}


def _info(info: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    return {k: v.detach().to("cpu", torch.float64).numpy() for k, v in info.items()}


def _seed_from(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 2**31 - 1))


class EyeEnv(gym.Env):
    """One simulated head as a Gymnasium environment (see the module docstring and `TaskConfig`
    for the options: ``observation``, ``reward``, ``actions_deg``, ``textures``, ``distances_m``,
    ``fixation_iterations``, ``device``, ...).

    Example:
        >>> import gymnasium as gym, aectorch.envs
        >>> env = gym.make("aectorch/Vergence-v0", fixation_iterations=4)
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, env.action_space
        ((1152,), Discrete(11))
        >>> obs, reward, terminated, truncated, info = env.step(5)
        >>> sorted(info)[:3], terminated, truncated
        (['distance_m', 'left_pan_deg', 'pursuit_error_deg'], False, False)
        >>> env.close()
    """

    metadata = {"render_modes": []}

    def __init__(self, **options: Any) -> None:
        super().__init__()
        self.task = EyeTask(1, TaskConfig(**options))
        self.observation_space = observation_space(self.task)
        self.action_space = action_space(self.task)
        self._features = self.task.config.observation == Observation.features

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        # Without a seed: a new trial drawn from np_random; the encoders keep what they learned.
        observation = self.task.reset(seed if seed is not None else _seed_from(self.np_random),
                                      keep_encoders=seed is None)
        return _row(_numpy(observation, self._features), self._features), {}

    def step(self, action):
        actions = torch.as_tensor(np.asarray(action, dtype=np.int64))[None]
        out = self.task.step(actions)
        observation = out.final_observation if out.truncated else out.observation
        obs = _row(_numpy(observation, self._features), self._features)
        info = {k: float(v[0]) for k, v in _info(out.info).items()}
        return obs, float(out.reward[0]), False, bool(out.truncated), info

    def close(self) -> None:
        self.task.close()


class EyeVectorEnv(VectorEnv):
    """N simulated heads in lockstep as one Gymnasium `VectorEnv` over one batched `EyeTask` (see
    the module docstring).

    Example:
        >>> import gymnasium as gym, aectorch.envs
        >>> envs = gym.make_vec("aectorch/Vergence-v0", num_envs=4, vectorization_mode="vector_entry_point",
        ...                     fixation_iterations=2)
        >>> obs, infos = envs.reset(seed=0)
        >>> obs.shape, envs.metadata["autoreset_mode"]
        ((4, 1152), <AutoresetMode.SAME_STEP: 'SameStep'>)
        >>> _ = envs.step(envs.action_space.sample())
        >>> obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
        >>> truncated.all(), infos["final_obs"].shape
        (np.True_, (4, 1152))
        >>> envs.close()
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, **options: Any) -> None:
        self.task = EyeTask(num_envs, TaskConfig(**options))
        self.num_envs = num_envs
        self.single_observation_space = observation_space(self.task)
        self.single_action_space = action_space(self.task)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self._features = self.task.config.observation == Observation.features

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if isinstance(seed, (list, tuple)):  # one simulator: the first seed seeds it
            seed = seed[0]
        super().reset(seed=seed)
        observation = self.task.reset(seed if seed is not None else _seed_from(self.np_random),
                                      keep_encoders=seed is None)
        return _numpy(observation, self._features), {}

    def step(self, actions):
        out = self.task.step(torch.as_tensor(np.asarray(actions, dtype=np.int64)))
        n = self.num_envs
        infos: dict[str, Any] = _info(out.info)
        if out.truncated:
            infos["final_obs"] = _numpy(out.final_observation, self._features)
            infos["_final_obs"] = np.ones(n, dtype=bool)
            infos["final_info"] = _info(out.info)
            infos["_final_info"] = np.ones(n, dtype=bool)
        truncated = np.full(n, bool(out.truncated))
        return (_numpy(out.observation, self._features), out.reward.detach().to("cpu", torch.float64).numpy(),
                np.zeros(n, dtype=bool), truncated, infos)

    def close_extras(self, **kwargs: Any) -> None:
        self.task.close()
