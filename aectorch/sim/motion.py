"""A moving object: where the object plane is at an iteration of a fixation, and the checks of its speeds.

The object plane starts each fixation at the trial's distance, straight ahead, and moves in
every iteration: its distance changes by the depth speed ``v`` (metres per iteration) and its
centre turns by the sideways speed ``w`` (degrees per iteration) as seen from the eyes' midpoint
at the fixation's start. During
iteration ``i`` (0-based) of a fixation, as the body shift's profile counts, it has moved
``k = i + 1`` steps:

    distance = d + k v,      y = distance * tan(k w)

(``y``: the sideways offset of its centre, world y, positive to the robot's left). The
fixation target is the point of the object the left eye's axis met at the fixation's start;
it moves with the object, and the eye movements' ground truth follows it.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

__all__ = ["MIN_OBJECT_DISTANCE_M", "MAX_OBJECT_TURN_DEG", "check_object_motion", "object_place"]

#: The nearest the object may come to the eyes (metres).
MIN_OBJECT_DISTANCE_M = 0.2
#: The farthest the object may turn sideways within a fixation (degrees): ``tan`` stays finite.
MAX_OBJECT_TURN_DEG = 80.0


def object_place(distance_m: Tensor, speed: Tensor, steps: int) -> tuple[Tensor, Tensor]:
    """The object's distance and sideways offset after ``steps`` iterations of motion.

    Args:
        distance_m: the trial's distances ``[B]`` (metres from the eyes along the robot's forward axis).
        speed: ``[B, 2]``: each object's sideways speed (degrees per iteration) and depth speed
            (metres per iteration).
        steps: iterations moved (``k`` of the module docstring, >= 0).

    Returns:
        ``(distance_m [B], y_m [B])``.

    Example:
        >>> d, y = object_place(torch.tensor([1.0]), torch.tensor([[45.0, -0.1]]), 1)
        >>> round(float(d), 6), round(float(y), 6)
        (0.9, 0.9)
    """
    sideways, depth = speed.unbind(-1)
    distance = distance_m + depth * steps
    return distance, distance * torch.tan(torch.deg2rad(sideways * steps))


def check_object_motion(speed_deg: tuple[float, float], depth_speed_m: tuple[float, float],
                        distances_m: Sequence[float], iterations: int, farthest_m: float) -> None:
    """``ValueError`` naming the argument where a fixation of ``iterations`` would carry the object
    too far: turned by ``MAX_OBJECT_TURN_DEG`` or more, nearer than ``MIN_OBJECT_DISTANCE_M``, or
    beyond ``farthest_m`` (the background)."""
    turn = max(abs(v) for v in speed_deg) * iterations
    if turn >= MAX_OBJECT_TURN_DEG:
        raise ValueError(f"object_speed_deg={tuple(speed_deg)} turns the object by {turn:g} degrees in a fixation of "
                         f"{iterations} iterations; keep it under {MAX_OBJECT_TURN_DEG:g} degrees")
    near = min(distances_m) + min(depth_speed_m[0], 0.0) * iterations
    far = max(distances_m) + max(depth_speed_m[1], 0.0) * iterations
    if near < MIN_OBJECT_DISTANCE_M or far >= farthest_m:
        raise ValueError(f"object_depth_speed_m={tuple(depth_speed_m)} carries the object from distances_m "
                         f"{min(distances_m):g}..{max(distances_m):g} m to {near:g}..{far:g} m in a fixation of "
                         f"{iterations} iterations; it must stay within [{MIN_OBJECT_DISTANCE_M:g}, "
                         f"{farthest_m:g}) m")
