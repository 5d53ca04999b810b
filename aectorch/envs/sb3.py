"""Stable-Baselines3's ``VecEnv`` over `EyeTask`: `EyeSB3VecEnv`, built by `aectorch.envs.make_sb3_vec_env`.

One batched simulator for all N environments (not N copies in a ``DummyVecEnv``). SB3's own
conventions: the step that ends an episode returns the next episode's first observation, with the
ended episode's last one in ``infos[i]["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]``
true (episodes end by their time limit only, so SB3 bootstraps their last value). ``seed(s)``
takes effect at the next ``reset()``, as in SB3.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from aectorch.envs.core import EyeTask, Observation
from aectorch.envs.gym import _numpy, _row, action_space, observation_space

__all__ = ["EyeSB3VecEnv"]


class EyeSB3VecEnv(VecEnv):
    """N simulated heads as one SB3 ``VecEnv`` (see the module docstring).

    Args:
        task: the batched `EyeTask`.
        seed: the first reset's seed.
    """

    render_mode = None
    _actions: np.ndarray | None

    def __init__(self, task: EyeTask, *, seed: int | None = None) -> None:
        self.task = task
        self._features = task.config.observation == Observation.features
        super().__init__(task.num_envs, observation_space(task), action_space(task))
        self._first_seed, self._actions = seed, None

    def reset(self):
        seed = self._seeds[0] if self._seeds[0] is not None else self._first_seed
        self._first_seed = None
        observation = self.task.reset(seed, keep_encoders=seed is None)
        self._reset_seeds()
        self._reset_options()
        return _numpy(observation, self._features)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        out = self.task.step(torch.as_tensor(np.asarray(self._actions, dtype=np.int64)))
        n = self.task.num_envs
        details = {k: v.detach().cpu().numpy() for k, v in out.info.items()}
        infos: list[dict[str, Any]] = [{k: float(v[i]) for k, v in details.items()} for i in range(n)]
        if out.truncated:
            final = _numpy(out.final_observation, self._features)
            for i, info in enumerate(infos):
                info["terminal_observation"] = _row(final, self._features, i)
                info["TimeLimit.truncated"] = True
        dones = np.full(n, bool(out.truncated))
        return _numpy(out.observation, self._features), out.reward.detach().cpu().numpy().astype(np.float32), dones, infos

    def close(self) -> None:
        self.task.close()

    # SB3's per-environment attribute access: one simulator serves them all.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = getattr(self, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]
