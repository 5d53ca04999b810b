"""`Movement`: one eye movement of an `ActiveDepthEnv`, over the head state the environment keeps.

The environment keeps the head (the eyes' pans and roll, the body's shift), the scene and the
object, the renderers, the protocol and the trial clock; a movement is what one eye movement adds
to them: what it observes (an image pair), how it acts (an increment ``[B]``), its optimum (the
increment that reaches it) and its error, and its part of the batch state. A cue of the
environment (`ActiveDepthEnv.CUES`) names the movement class it drives.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> {cue: env.cue(cue).name for cue in env.CUES}
    {'parallax': 'pursuit', 'stereo': 'vergence'}
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
from torch import Tensor


__all__ = ["Movement"]


class Movement:
    """One eye movement of ``env`` (an `ActiveDepthEnv`); a subclass says what it is.

    Attributes:
        name: the movement's name: its error is ``IterationInfo.errors_deg[name]``.
        images: names of its observation's two images (the eye, and ``_before`` for the image at
            the fixation's start position): the viewer's titles, the LeRobot recording's cameras.
        STATE: its part of the environment's batch state (`ActiveDepthEnv.state_dict`): the state's
            key -> the movement's attribute, a tensor ``[B, ...]`` stored while it is not ``None``.
    """

    name: ClassVar[str]
    images: ClassVar[tuple[str, str]]
    STATE: ClassVar[dict[str, str]] = {}

    def __init__(self, env: Any) -> None:
        # the `ActiveDepthEnv` (typed Any: env.py imports this module, and no module imports
        # itself through others, not even for its types)
        self.env = env

    def increments(self, delta_deg) -> Tensor:
        """``delta_deg`` as a ``[B]`` tensor of the environment's dtype and device, checked."""
        env = self.env
        delta = torch.as_tensor(delta_deg, device=env.device)
        if not delta.is_floating_point():
            delta = delta.to(env.dtype)
        if delta.shape != (env.num_envs,):
            raise ValueError(f"delta_deg must have shape [B] = [{env.num_envs}] (num_envs), got {tuple(delta.shape)}")
        return delta.to(env.dtype)

    def observe(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """Its image pair: ``{scale name: [B, 2, side, side]}`` for the foveal ``scales`` asked for
        and ``{WINDOW: [B, 2, h, w]}`` without scales or with ``window=True``."""
        raise NotImplementedError

    def act(self, delta_deg: Tensor) -> None:
        """Add the increments ``[B]`` (degrees) to the movement."""
        raise NotImplementedError

    def to_optimum(self) -> Tensor:
        """The increments ``[B]`` that put the movement at its optimum now (`ActiveDepthEnv.hold`)."""
        raise NotImplementedError

    def error_deg(self) -> Tensor:
        """Its error ``[B]`` now, actual minus optimal (reported by `ActiveDepthEnv.end_iteration`)."""
        return -self.to_optimum()

    def start_fixation(self, fixation: int) -> None:
        """Its state at the start of ``fixation`` (after the eyes' start pans and the object's motion)."""

    def between_iterations(self) -> None:
        """What it does between two iterations of a fixation (after the body and the object moved)."""
