"""TorchRL's ``EnvBase`` over `EyeTask`: `EyeTorchRLEnv`, built by `aectorch.envs.make_torchrl_env`.

A batched environment (``batch_size=[N]``) on the task's device: tensors go in and out as they
are, with no NumPy round trip. Specs: ``observation`` (features ``[N, F]``) or one entry per
``<cue>/<scale>`` pair (``[N, 2, side, side]``, with ``/`` read as ``_``), a categorical
``action`` (``[N]``; ``[N, 2]`` pursuit and vergence for ``active_depth``), ``reward`` ``[N, 1]``,
``done``, ``terminated`` (always false) and ``truncated`` ``[N, 1]``, and the ground truth
(``distance_m``, ``pursuit_error_deg``, ``vergence_error_deg``, the eye angles, ``[N]``).

An episode ends by its time limit in every environment at once; the task has already started the
next one, so the reset that TorchRL's collectors and rollouts call then returns that episode's
first observation without touching the simulation.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, MultiCategorical, Unbounded
from torchrl.envs import EnvBase

from aectorch.envs.core import EyeTask, Observation

__all__ = ["EyeTorchRLEnv"]

_INFO = ("distance_m", "pursuit_error_deg", "vergence_error_deg", "left_pan_deg", "right_pan_deg")


def _key(name: str) -> str:
    return name.replace("/", "_")


class EyeTorchRLEnv(EnvBase):
    """N simulated heads as one TorchRL environment (see the module docstring).

    Args:
        task: the batched `EyeTask`.
        seed: the first reset's seed (``None``: the task's own).
    """

    _next_first: tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]] | None

    def __init__(self, task: EyeTask, *, seed: int | None = None) -> None:
        super().__init__(device=task.device, batch_size=torch.Size([task.num_envs]))
        self.task, self._seed_value, self._next_first = task, seed, None
        n, dtype = task.num_envs, torch.float32
        if task.config.observation == Observation.features:
            observation = {"observation": Bounded(0.0, task.features_high,
                                                  (n, *task.observation_shapes["features"]), dtype=dtype, device=self.device)}
        else:
            observation = {_key(k): Bounded(0.0, 1.0, (n, *shape), dtype=dtype, device=self.device)
                           for k, shape in task.observation_shapes.items()}
        info = {k: Unbounded((n,), dtype=dtype, device=self.device) for k in _INFO}
        self.observation_spec = Composite(**observation, **info, shape=(n,), device=self.device)
        a = len(task.actions_deg)
        self.action_spec = (Categorical(a, (n,), device=self.device) if len(task.cues) == 1
                            else MultiCategorical(nvec=[a] * len(task.cues), shape=(n, len(task.cues)), device=self.device))
        self.reward_spec = Unbounded((n, 1), dtype=dtype, device=self.device)
        flag = Categorical(2, (n, 1), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(done=flag.clone(), terminated=flag.clone(), truncated=flag.clone(), shape=(n,),
                                   device=self.device)

    def _observation(self, observation: dict, info: dict | None) -> dict:
        if self.task.config.observation == Observation.features:
            out = {"observation": observation["features"].to(torch.float32)}
        else:
            out = {_key(k): v.to(torch.float32) for k, v in observation.items()}
        n = self.task.num_envs
        zero = torch.zeros(n, dtype=torch.float32, device=self.device)
        out.update({k: (zero if info is None else info[k].to(torch.float32)) for k in _INFO})
        return out

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.task.num_envs
        if self._next_first is not None and tensordict is not None:  # the next episode has begun
            observation, info = self._next_first
        else:
            seed, self._seed_value = self._seed_value, None
            observation, info = self.task.reset(seed), None
        self._next_first = None
        flags = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
        return TensorDict({**self._observation(observation, info), "done": flags, "terminated": flags.clone(),
                           "truncated": flags.clone()}, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = self.task.step(tensordict["action"])
        n = self.task.num_envs
        truncated = torch.full((n, 1), bool(out.truncated), dtype=torch.bool, device=self.device)
        if out.truncated:  # this step's next state is the ended episode's last; keep the new first
            self._next_first = (out.observation, out.info)
            observation = out.final_observation
        else:
            observation = out.observation
        return TensorDict({**self._observation(observation, out.info),  # type: ignore[arg-type]  # set when truncated
                           "reward": out.reward.to(torch.float32)[:, None],
                           "done": truncated, "terminated": torch.zeros_like(truncated), "truncated": truncated.clone()},
                          batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        self._seed_value = seed
        self.task.reset(seed)
        self._next_first = None

    def close(self, *, raise_if_closed: bool = True) -> None:
        self.task.close()
        super().close(raise_if_closed=raise_if_closed)
