"""Pursuit: the left (dominant) eye's pan, driven by motion parallax (the ``parallax`` cue).

It sees the left eye's image at the fixation's start position (taken once per fixation, before
any movement) and its image now, after the body's shift; it adds its increments to the left eye's
pan (and to the right eye's too with ``yoked_pursuit``); its optimum keeps the fixation target
on the left eye's axis.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> env.hold("parallax")  # the increment that reaches the optimum
    >>> float(env.cue("parallax").error_deg().abs().max()) < 1e-4
    True
"""

from __future__ import annotations


import torch
from torch import Tensor

from aectorch.sim.movements.base import Movement


__all__ = ["Pursuit"]


class Pursuit(Movement):
    """The left eye's pan, keeping the fixation target on its axis as the body moves."""

    name = "pursuit"
    images = ("left_before", "left")

    def observe(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        images = self.env.images
        key = images.key(scales, window)
        first = images.first_left(key, scales, window)
        second = images.current_left(key, scales, window)
        return {name: torch.cat((first[name], second[name]), dim=1) for name in first}

    def act(self, delta_deg: Tensor) -> None:
        env = self.env
        delta = self.increments(delta_deg)
        if env.velocity_memory:  # the step also goes on as velocity
            slip = env.movements["pursuit_velocity"]
            slip.velocity_deg = slip.velocity() + delta
        env.pan_deg = env.clamp_pan_deg(env.pan_deg + self.step(delta))
        env.images.moved()

    def step(self, delta: Tensor) -> Tensor:
        """The pans' change ``[B, 2]`` of a pursuit increment ``[B]``: both eyes with
        ``yoked_pursuit``, else the left alone."""
        return torch.stack((delta, delta if self.env.yoked_pursuit else torch.zeros_like(delta)), dim=-1)

    def optimal_pan_deg(self, target_m: Tensor | None = None, body_shift_m: Tensor | None = None) -> Tensor:
        """`ActiveDepthEnv.optimal_left_pan_deg`."""
        env = self.env
        target = env.target_m if target_m is None else target_m
        body = env.body_shift_m if body_shift_m is None else body_shift_m
        shift = env.eye_optics.eye_shift()
        if shift is None:
            return env.head.pursuit_pan_deg(target, body)
        return env.head.pursuit_pan_deg(target - shift[0], body)

    def to_optimum(self) -> Tensor:
        return self.optimal_pan_deg() - self.env.eye_pan_deg[:, 0]
