"""The batch state of an `ActiveDepthEnv`: its checkpoint (`ActiveDepthEnv.state_dict`), loaded,
joined over the processes of a run and cut into a process's rows.

The state holds the head's and the trial's tensors (:data:`STATE_TENSORS`, each ``[B, ...]``), the
trial clock, the generator's state, the optics, the roll and optics of the fixation's first image,
and the parts' own tensors (the moving object's, the eyes' focus, each movement's, the layout's
draws: each part's ``STATE``, the key -> its attribute, stored while not ``None``). The keys are
those of every earlier version: an old checkpoint loads as it did.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> keys = batch_keys()
    >>> state = state_dict(env)
    >>> whole = join_states([state_rows(state, 0, 1, keys), state_rows(state, 1, 2, keys)], keys)
    >>> torch.equal(whole["pan_deg"], state["pan_deg"]), whole["num_envs"]
    (True, 2)
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch

from aectorch.sim.perturbations import NEUTRAL, Optics


__all__ = ["STATE_TENSORS", "batch_keys", "join_states", "load_state_dict", "state_dict", "state_rows"]

#: The head's and the trial's tensors ``[B, ...]``: the state's key is the environment's attribute.
STATE_TENSORS = ("texture_index", "distance_m", "plane_x_m", "body_shift_m", "pan_deg",
                 "roll_deg", "q_deg", "target_m", "_start_pans", "q_sum_deg")


def batch_keys(*parts) -> tuple[str, ...]:
    """The keys of a state's per-environment tensors, with those of the parts (classes with ``STATE``)."""
    return (*STATE_TENSORS, "first_roll", *(key for part in parts for key in part.STATE))


def state_dict(env: Any) -> dict:
    """`ActiveDepthEnv.state_dict`."""
    images = env.images
    state = {name: getattr(env, name).clone() for name in STATE_TENSORS}
    state.update(
        fixation=env.fixation,
        iteration=env.iteration,
        generator=env._generator.get_state(),
        num_envs=env.num_envs,
        num_textures=len(env.textures),
        first_roll=None if images.first_roll is None else images.first_roll.clone(),
        optics=env.optics.to_dict(),
        first_optics=None if images.first_optics is None else images.first_optics.to_dict(),
    )
    for part in env.state_parts():  # each part's tensors (absent while None: an object standing still)
        for name, attribute in part.STATE.items():
            if getattr(part, attribute) is not None:
                state[name] = getattr(part, attribute).clone()
    return state


def join_states(states: list[dict], keys: tuple[str, ...]) -> dict:
    """`ActiveDepthEnv.join_states`: the per-environment tensors (``keys``) joined, the rest the same."""
    if len(states) == 1:
        return states[0]
    first, whole = states[0], dict(states[0])
    for name, value in first.items():
        if name == "num_envs":
            whole[name] = sum(int(s[name]) for s in states)
        elif name in keys:
            whole[name] = None if value is None else torch.cat([s[name] for s in states])
        elif name == "generator":
            if any(not torch.equal(s[name], value) for s in states):
                raise ValueError("the environments' parts have different generator states: they are not "
                                 "one run's processes")
        elif any(s[name] != value for s in states):
            raise ValueError(f"the environments' parts differ in {name!r} ({[s[name] for s in states]})")
    return whole


def state_rows(state: dict, start: int, stop: int, keys: tuple[str, ...]) -> dict:
    """`ActiveDepthEnv.state_rows`: rows ``start .. stop - 1`` of the per-environment tensors (``keys``)."""
    total = int(state["num_envs"])
    if not 0 <= start < stop <= total:
        raise ValueError(f"rows {start}..{stop - 1} are not within the {total} environments of the state")
    rows = dict(state, num_envs=stop - start)
    for name in keys:
        if rows.get(name) is not None:
            rows[name] = state[name][start:stop].clone()
    return rows


def load_state_dict(env: Any, state: dict) -> None:
    """`ActiveDepthEnv.load_state_dict`."""
    for key, expected in (("num_envs", env.num_envs), ("num_textures", len(env.textures))):
        if state.get(key) != expected:
            raise ValueError(
                f"state was saved with {key}={state.get(key)!r}, this environment has {expected}; "
                "build it with the same arguments as the one that was saved"
            )
    for name in STATE_TENSORS:
        if name == "q_sum_deg" and name not in state:  # saved before q_iterations: q was the last iteration's
            env.q_sum_deg = torch.zeros_like(env.q_sum_deg)
            continue
        setattr(env, name, state[name].to(device=env.device, dtype=getattr(env, name).dtype).clone())
    env.fixation = int(state["fixation"])
    env.iteration = int(state["iteration"])
    env._generator.set_state(state["generator"])
    # The optics (None in states saved before perturbations were data, as
    # `aectorch.runtime.migrations` fills them in: none but the roll, which roll_deg holds);
    # the roll tensor is the state's own.
    roll = env.roll_deg
    env.set_optics(Optics.from_dict(state["optics"]) if state.get("optics") is not None
                   else replace(NEUTRAL, roll_deg=tuple(roll[0].tolist())))
    env.roll_deg = roll
    images = env.images
    first_optics = state.get("first_optics")
    images.first_optics = None if first_optics is None else Optics.from_dict(first_optics)
    images.first_image = {}
    images.moved()
    first_roll = state.get("first_roll")
    images.first_roll = None if first_roll is None else first_roll.to(env.roll_deg)
    for part in env.state_parts():
        for name, attribute in part.STATE.items():
            value = state.get(name)
            setattr(part, attribute, None if value is None else value.to(device=env.device, dtype=env.dtype).clone())
    env.motion.loaded()  # the object where it was
