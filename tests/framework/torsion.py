"""A toy eye movement, the whole of a new movement's code (docs/architecture.md, "Adding a cue"):
a torsion of the right eye that brightens its image. Its observation is the stereo pair so
changed, its action turns the torsion, its optimum is 0 and its state is part of the batch's."""

from __future__ import annotations

import torch

from aectorch.sim import Movement


class Torsion(Movement):
    name = "torsion"
    images = ("left", "right")
    STATE = {"torsion_deg": "torsion_deg"}

    def __init__(self, env):
        super().__init__(env)
        self.torsion_deg = torch.full((env.num_envs,), 1.0)

    def observe(self, scales=None, *, window=False):
        pair = self.env.stereo_observation(scales, window=window)
        return {k: torch.cat((p[:, :1], p[:, 1:] + 0.05 * self.torsion_deg[:, None, None, None]), 1)
                for k, p in pair.items()}

    def act(self, delta_deg):
        self.torsion_deg = self.torsion_deg + delta_deg

    def to_optimum(self):
        return -self.torsion_deg
