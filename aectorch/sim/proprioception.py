"""What the eyes of an `ActiveDepthEnv` sense of themselves: efference copies of the commands.

One column per name of `aectorch.choices.Proprioception`: ``vergence`` (the commanded vergence
angle, degrees), ``pan`` (the left eye's commanded pan, degrees), ``focus`` (the left eye's focus,
dioptres; only where the eyes accommodate, ``accommodation_start_D`` or ``set_focus``: an eye that
follows the object would sense its distance) and ``shift`` (the body's sideways shift since the
fixation's start, metres). Not ground truth: a squint's offset is not in them.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> proprioception(env, ["vergence", "shift"]).shape
    torch.Size([2, 2])
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from aectorch._checks import check_choice
from aectorch.choices import Proprioception


__all__ = ["proprioception"]


def proprioception(env: Any, names) -> Tensor:
    """`ActiveDepthEnv.proprioception`: the senses ``names`` now, ``[B, len(names)]``."""
    names = [check_choice(n, "proprioception", Proprioception) for n in names]
    focus = env.eye_optics.focus_dioptres
    if Proprioception.focus in names and focus is None:
        raise ValueError("proprioception 'focus' needs an environment whose eyes accommodate "
                         "(the protocol's accommodation_start_D, env.accommodation_start_D; or set_focus): "
                         "these eyes follow the object")
    if not names:
        return env.pan_deg.new_zeros(env.num_envs, 0)

    def column(name: Proprioception) -> Tensor:
        if name == Proprioception.focus and focus is not None:
            return focus[:, 0]
        return {Proprioception.vergence: env.vergence_deg, Proprioception.pan: env.pan_deg[:, 0],
                Proprioception.shift: env.body_shift_m}[name]

    return torch.stack([column(n) for n in names], -1)
