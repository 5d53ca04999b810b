"""The geometry of a trial of `ActiveDepthEnv`: the fixation target and the ideal final eye movements.

The fixation target is where the left eye's axis at its start pan meets the object's plane at the
fixation's start position; the optimal pursuit keeps it on the left axis
(`aectorch.sim.movements.pursuit`). The ideal ``q`` is what a perfectly fixating trial ends with,
the geometry the depth MLP has to invert.

**The optimum stays on the object** of a `SceneLayout` (its pivot straight ahead of the left eye's
start position, where a fixation from the standard start, pan 0, fixates): the fixation target is
on the object's plane (slanted, extended past its edges), and the optimal vergence puts the right
eye's axis through the point where the left axis meets that plane now
(`aectorch.sim.movements.vergence`), even where the left axis has slipped past the edge onto the
background. The trial's distance (the depth's ground truth) is the pivot's.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> ideal_q_deg(env, torch.tensor([1.0, 2.0, 3.0])).shape
    torch.Size([3, 4])
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from aectorch.sim.scene import axis_point


__all__ = ["fixation_target", "ideal_q_deg"]


def fixation_target(env: Any, left_pan_deg: Tensor, plane_x_m: Tensor) -> Tensor:
    """The fixation target ``[N, 3]``: where the left axis meets the plane at the start position."""
    start = env.head.eye_centres(torch.zeros_like(plane_x_m))[:, 0]  # [N, 3]
    shift = env.eye_optics.eye_shift()
    if shift is not None:  # the left camera's own place (camera_shift)
        start = start + shift[0]
    slant = env.layout_draws.slant_rad()
    if slant is not None and slant.shape == plane_x_m.shape:  # the slanted object's plane (its pivot)
        return axis_point(start, left_pan_deg, plane_x_m, slant, env.scene.object_center_yz_m[0])
    along = torch.tan(torch.deg2rad(left_pan_deg)) * (plane_x_m - start[:, 0])
    return torch.stack((plane_x_m, start[:, 1] + along, start[:, 2]), dim=-1)


def ideal_q_deg(env: Any, distance_m: Tensor | None = None, start_pan_deg: float = 0.0) -> Tensor:
    """`ActiveDepthEnv.ideal_q_deg`: the final eye movements ``q`` ``[N, 4]`` of a perfectly
    fixating trial at ``distance_m`` ``[N]`` (default the current trials'), degrees."""
    d = env.distance_m if distance_m is None else torch.as_tensor(distance_m, dtype=env.dtype, device=env.device)
    if d.dim() != 1 or not bool((d > 0).all()):
        raise ValueError(f"distance_m must be a [N] tensor of distances > 0 (metres), got {d!r}")
    plane_x = d + float(env.head.eye_x_m)
    target = fixation_target(env, torch.full_like(d, float(start_pan_deg)), plane_x)
    columns = []
    for direction in (1.0, -1.0):
        shift = torch.full_like(d, direction * env.shift_m)
        left = env.head.pursuit_pan_deg(target, shift)
        columns += [left, env.head.vergence_pan_deg(left, plane_x, shift) - left]
    return torch.stack(columns, dim=-1)
