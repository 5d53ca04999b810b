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

from typing import Any, Sequence

import torch
from torch import Tensor


__all__ = ["MIN_OBJECT_DISTANCE_M", "MAX_OBJECT_TURN_DEG", "MovingObject", "check_object_motion", "object_place"]

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


class MovingObject:
    """The moving object of ``env`` (an `ActiveDepthEnv`): its speeds, drawn per fixation from the
    ranges ``speed_deg`` and ``depth_speed_m`` or pinned (:meth:`pin`), and where it is. It moves
    the environment's object plane (``env.plane_x_m``) and fixation target (``env.target_m``)."""

    #: Its part of the environment's batch state (`ActiveDepthEnv.state_dict`): the state's key -> its
    #: attribute, a tensor ``[B, ...]`` stored while it is not ``None``.
    STATE = {"object_speed": "speed", "object_pinned_speed": "pinned_speed",
             "object_trial_depth_speed": "trial_depth_speed", "object_start_target_m": "start_target_m"}

    def __init__(self, env: Any, speed_deg: tuple[float, float], depth_speed_m: tuple[float, float]) -> None:
        self.env, self.speed_deg, self.depth_speed_m = env, speed_deg, depth_speed_m
        # The speeds [B, 2] (sideways deg, depth m per iteration; None: it stands still), those
        # pinned by pin(), the trial's depth speed, the target it started from, and its sideways
        # offsets [B] (None: not moved).
        self.speed: Tensor | None = None
        self.pinned_speed: Tensor | None = None
        self.trial_depth_speed: Tensor | None = None
        self.start_target_m: Tensor | None = None
        self.plane_y_m: Tensor | None = None
        self.start_plane: tuple[Tensor, Tensor] | None = None

    @property
    def moves(self) -> bool:
        """Whether the next fixation moves the object: speeds pinned, or ranges other than ``(0, 0)``."""
        return self.pinned_speed is not None or self.speed_deg != (0.0, 0.0) or self.depth_speed_m != (0.0, 0.0)

    def pin(self, speed_deg=None, depth_speed_m=None) -> None:
        """`ActiveDepthEnv.set_object_speed`: the speeds of the next fixations, checked (neither: unpinned)."""
        if speed_deg is None and depth_speed_m is None:
            self.pinned_speed = None
            return
        env = self.env
        b = env.num_envs
        columns = []
        for value, name in ((speed_deg, "speed_deg"), (depth_speed_m, "depth_speed_m")):
            column = torch.as_tensor(0.0 if value is None else value, dtype=env.dtype, device=env.device)
            if column.shape not in ((), (b,)) or not bool(torch.isfinite(column).all()):
                raise ValueError(f"{name} must be a finite number or a [B] = [{b}] tensor, got {value!r}")
            columns.append(column.expand(b))
        speed = torch.stack(columns, -1)
        check_object_motion((float(speed[:, 0].min()), float(speed[:, 0].max())),
                            (float(speed[:, 1].min()), float(speed[:, 1].max())),
                            env.distances_m.tolist(), env.fixation_iterations,
                            env.scene.background_x_m - float(env.head.eye_x_m))
        self.pinned_speed = speed

    def stop(self) -> None:
        """The object back at its start (the trial's distance, straight ahead), still."""
        env = self.env
        env.plane_x_m = env.distance_m + float(env.head.eye_x_m)
        self.speed = self.plane_y_m = None

    def start(self, fixation: int) -> None:
        """A fixation's object motion: its speeds (pinned, or drawn: sideways per fixation, in
        depth per trial), the target it starts from, and its place in the first iteration."""
        env = self.env
        if self.pinned_speed is not None:
            self.speed = self.pinned_speed.clone()
        else:
            sideways = env.uniform(self.speed_deg)
            depth = env.uniform(self.depth_speed_m) if fixation == 0 or self.trial_depth_speed is None \
                else self.trial_depth_speed
            self.trial_depth_speed = depth
            self.speed = torch.stack((sideways, depth), -1)
        self.start_target_m = env.target_m
        self.start_plane = (env.plane_x_m, torch.zeros_like(env.plane_x_m))
        self.place(0)

    def place(self, iteration: int) -> None:
        """The object where it is during ``iteration`` of the fixation; the fixation target moves with it."""
        env = self.env
        env.plane_x_m, self.plane_y_m, env.target_m = self.at(iteration)

    def at(self, iteration: int) -> tuple[Tensor, Tensor, Tensor]:
        """Where the moving object is during ``iteration`` of the fixation: its plane's world x and
        sideways offset ``[B]``, and the fixation target on it ``[B, 3]``."""
        env, speed, start = self.env, self.speed, self.start_target_m
        if speed is None or start is None:
            raise RuntimeError("the object does not move in this fixation")
        distance, y = object_place(env.distance_m, speed, iteration + 1)
        plane_x = distance + float(env.head.eye_x_m)
        return plane_x, y, torch.stack((plane_x, start[:, 1] + y, start[:, 2]), -1)

    def loaded(self) -> None:
        """After `ActiveDepthEnv.load_state_dict`: the object where the state's fixation had it."""
        env = self.env
        self.plane_y_m = None
        if self.speed is not None:
            self.start_plane = (env.distance_m + float(env.head.eye_x_m), torch.zeros_like(env.distance_m))
            self.place(env.iteration)
