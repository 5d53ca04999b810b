"""Vergence: the right eye's pan, driven by stereo (the ``stereo`` cue).

It sees both eyes' images at the shifted position; it adds its increments to the right eye's pan
(the vergence angle, right pan minus left pan, stays within the oculomotor range); its optimum
puts the right eye's axis through the point where the left eye's axis meets the object's plane.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> env.cue("stereo").observe()["window"].shape  # the left and the right eye
    torch.Size([2, 2, 128, 128])
    >>> env.hold("stereo")
    >>> float(env.cue("stereo").error_deg().abs().max()) < 1e-4
    True
"""

from __future__ import annotations

import torch
from torch import Tensor

from aectorch.sim.movements.base import Movement
from aectorch.sim.scene import axis_point

__all__ = ["Vergence"]


class Vergence(Movement):
    """The right eye's pan, looking where the left eye's axis meets the object's plane."""

    name = "vergence"
    images = ("left", "right")

    def observe(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        return self.env.images.stereo(scales, window)

    def act(self, delta_deg: Tensor) -> None:
        env = self.env
        delta = self.increments(delta_deg)
        step = torch.stack((torch.zeros_like(delta), delta), dim=-1)
        env.pan_deg = env.clamp_pan_deg(env.pan_deg + step)

    def optimal_pan_deg(self, left_pan_deg: Tensor | None = None) -> Tensor:
        """`ActiveDepthEnv.optimal_right_pan_deg`."""
        env = self.env
        left = env.eye_pan_deg[:, 0] if left_pan_deg is None else left_pan_deg
        shift = env.eye_optics.eye_shift()
        slant = env.layout_draws.slant_rad()
        if slant is not None:  # where the left axis meets the slanted object's plane, never the background
            eye = env.head.eye_centres(env.body_shift_m)[:, 0]
            point = axis_point(eye if shift is None else eye + shift[0], left, env.plane_x_m, slant,
                               env.scene.object_center_yz_m[0])
            return env.head.pursuit_pan_deg(point if shift is None else point - shift[1], env.body_shift_m,
                                            eye="right")
        if shift is None:
            return env.head.vergence_pan_deg(left, env.plane_x_m, env.body_shift_m)
        # Each camera where camera_shift put it: the left axis from its place, the right eye's pan
        # toward that point from its own.
        point = env.head.plane_point_m(left, env.plane_x_m - shift[0, 0], env.body_shift_m) + shift[0]
        return env.head.pursuit_pan_deg(point - shift[1], env.body_shift_m, eye="right")

    def to_optimum(self) -> Tensor:
        return self.optimal_pan_deg() - self.env.eye_pan_deg[:, 1]
