"""The pursuit velocity, driven by retinal slip (the ``slip`` cue; `TrialProtocol.pursuit_velocity`).

It sees the left eye's previous frame (the end of the last iteration: its pans after every
movement, the body and the object where they were; in a fixation's first iteration, the fixation's
first image) against its current one; between the two the object and the body moved on and the
eyes moved by their pursuit velocity, so the image slips by the object's motion the eye did not
follow. It adds its increments to the velocity (degrees per iteration), which moves the eyes
between iterations (both with ``yoked_pursuit``, else the left) within the oculomotor range; its
error is that velocity against the optimal left pan's change over the next iteration. Each
fixation starts with the eyes still.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2, pursuit_velocity=True), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> list(env.CUES), env.cue("slip").velocity_deg.tolist()  # it sees the eyes before any step
    (['slip', 'parallax', 'stereo'], [0.0, 0.0])
"""

from __future__ import annotations


import torch
from torch import Tensor

from aectorch.sim.movements.base import Movement


__all__ = ["Slip"]


class Slip(Movement):
    """The eyes' pursuit velocity ``[B]`` (degrees per iteration) and the pans the last iteration
    ended with ``[B, 2]`` (``None`` in a fixation's first iteration)."""

    name = "pursuit_velocity"
    images = ("left_previous", "left")
    STATE = {"pursuit_velocity_deg": "velocity_deg", "previous_pans_deg": "previous_pans"}

    def __init__(self, env) -> None:
        super().__init__(env)
        self.velocity_deg: Tensor | None = None
        self.previous_pans: Tensor | None = None

    def observe(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        env = self.env
        images = env.images
        key = images.key(scales, window)
        if self.previous_pans is None:
            first = images.first_left(key, scales, window)
        else:
            # the object where it was during the last iteration
            plane = env.motion.at(env.iteration - 1)[:2] if env.moving else None
            first = images.render(env.body_shift(env.iteration - 1), self.previous_pans, slice(0, 1),
                                  scales=scales, window=window, plane=plane)
        second = images.current_left(key, scales, window)
        return {name: torch.cat((first[name], second[name]), dim=1) for name in first}

    def act(self, delta_deg: Tensor) -> None:
        self.velocity_deg = self.velocity() + self.increments(delta_deg)

    def velocity(self) -> Tensor:
        """The pursuit velocity ``[B]`` of this fixation (``RuntimeError`` before one began)."""
        if self.velocity_deg is None:
            raise RuntimeError("the pursuit velocity is set at a fixation's start")
        return self.velocity_deg

    def optimal_velocity_deg(self) -> Tensor:
        """`ActiveDepthEnv.optimal_velocity_deg`."""
        env = self.env
        pursuit = env.movements["pursuit"]
        # the target where the object will be
        target = env.motion.at(env.iteration + 1)[2] if env.moving else env.target_m
        return pursuit.optimal_pan_deg(target, env.body_shift(env.iteration + 1)) - pursuit.optimal_pan_deg()

    def to_optimum(self) -> Tensor:
        return self.optimal_velocity_deg() - self.velocity()

    def start_fixation(self, fixation: int) -> None:
        env = self.env  # the eyes start still
        self.velocity_deg = torch.zeros(env.num_envs, dtype=env.dtype, device=env.device)
        self.previous_pans = None

    def between_iterations(self) -> None:
        env = self.env  # the eyes move on at their pursuit velocity
        self.previous_pans = env.pan_deg
        env.pan_deg = env.clamp_pan_deg(env.pan_deg + env.movements["pursuit"].step(self.velocity()))
        env.images.moved()
