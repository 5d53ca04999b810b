"""The simulated head as standard RL environments: Gymnasium, TorchRL and Stable-Baselines3.

Importing ``aectorch.envs`` registers four Gymnasium ids (docs/rl-environments.md):

- ``aectorch/Vergence-v0``: one fixation of h steps; the action is the vergence increment (pursuit
  held at its optimum);
- ``aectorch/Pursuit-v0``: the motion-parallax fixation; the action is the pursuit increment
  (vergence held at its optimum);
- ``aectorch/ActiveDepth-v0``: a whole trial, both fixations; ``MultiDiscrete`` (pursuit,
  vergence) increments;
- ``aectorch/Accommodation-v0``: one fixation; the action changes both eyes' focus (degrees of the
  blur disc's diameter), pursuit and vergence held; the reward is the information the code keeps,
  which prefers focus; ``info["accommodation_error_deg"]`` is the blur disc's signed diameter.

Options (keyword arguments of ``gymnasium.make``, `TaskConfig`): ``observation="features"`` (the
pooled sparse code of an internal, online-learning `BinocularEncoder`, eq. 5) or ``"images"``
(each scale's binocular pair), ``reward="scaled"`` (the change of that encoder's coding reward over
a running scale, the default), ``"improvement"`` (the change itself), ``"coding"`` (the reward
itself) or ``"error"`` (minus the absolute angle error), ``actions_deg``, ``textures``, ``distances_m``, ``device``,
``object_speed_deg`` and ``object_depth_speed_m`` (a moving target: the ranges of its speeds), ...
``info`` carries ``distance_m``, ``pursuit_error_deg``, ``vergence_error_deg`` and the eye angles.

``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` is one batched
simulator (`EyeVectorEnv`); :func:`make_torchrl_env` and :func:`make_sb3_vec_env` wrap the same
core (`EyeTask`) for TorchRL and Stable-Baselines3. Gymnasium is in the ``rl`` extra.
"""

from __future__ import annotations

from aectorch.envs.core import EyeTask, TaskConfig

__all__ = ["IDS", "EyeTask", "TaskConfig", "make_sb3_vec_env", "make_torchrl_env", "register"]

#: The registered ids and their tasks.
IDS = {"aectorch/Vergence-v0": "vergence", "aectorch/Pursuit-v0": "pursuit", "aectorch/ActiveDepth-v0": "active_depth",
       "aectorch/Accommodation-v0": "accommodation"}


def register() -> None:
    """Register the ids with Gymnasium (done on import; calling it again does nothing)."""
    import gymnasium as gym

    for env_id, task in IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(env_id, entry_point="aectorch.envs.gym:EyeEnv",
                     vector_entry_point="aectorch.envs.gym:EyeVectorEnv", kwargs={"task": task},
                     disable_env_checker=True, order_enforce=True)


def _task(env_id: str) -> str:
    if env_id not in IDS:
        raise ValueError(f"env id must be one of {list(IDS)}, got {env_id!r}")
    return IDS[env_id]


def make_torchrl_env(env_id: str, num_envs: int = 1, *, device=None, seed: int | None = None, **options):
    """A TorchRL ``EnvBase`` over one batched simulator of ``num_envs`` environments
    (``batch_size=[num_envs]``, on ``device``, no NumPy round trip; `aectorch.envs.torchrl`)."""
    from aectorch.envs.torchrl import EyeTorchRLEnv

    if device is not None:
        options["device"] = str(device)
    return EyeTorchRLEnv(EyeTask(num_envs, TaskConfig(task=_task(env_id), **options)),  # type: ignore[arg-type]
                         seed=seed)  # (TaskConfig takes a task's name)


def make_sb3_vec_env(env_id: str, num_envs: int = 1, *, seed: int | None = None, **options):
    """A Stable-Baselines3 ``VecEnv`` over one batched simulator of ``num_envs`` environments
    (`aectorch.envs.sb3`)."""
    from aectorch.envs.sb3 import EyeSB3VecEnv

    return EyeSB3VecEnv(EyeTask(num_envs, TaskConfig(task=_task(env_id), **options)),  # type: ignore[arg-type]
                        seed=seed)  # (TaskConfig takes a task's name)


register()
