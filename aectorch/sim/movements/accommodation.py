"""Accommodation: the eyes' focus (the ``accommodation`` cue, and ``accommodation_right`` where the
eyes do not accommodate together; `TrialProtocol.accommodation_start_D`).

It sees the stereo pair after vergence; it changes the focus by increments in degrees of the blur
disc's diameter (``delta_deg / degrees_per_dioptre`` dioptres; positive: nearer), at least 0 D
(infinity); its error is the eye's defocus as its blur disc's signed angular diameter (positive:
focused nearer than the object). Each fixation starts with both eyes at ``accommodation_start_D``.

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2, accommodation_start_D=0.0), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> float(env.cue("accommodation").error_deg()[0]) < 0  # focused at infinity: farther than the object
    True
    >>> env.hold("accommodation")
    >>> float(env.cue("accommodation").error_deg().abs().max()) < 1e-4
    True
"""

from __future__ import annotations

import torch
from torch import Tensor

from aectorch.sim.movements.base import Movement

__all__ = ["Accommodation", "AccommodationRight"]


class Accommodation(Movement):
    """Both eyes' focus (the left eye's alone without ``yoked_accommodation``)."""

    name = "accommodation"
    images = ("left", "right")
    #: the eye whose defocus is the error (0: left, 1: right)
    eye = 0

    def observe(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        return self.env.images.stereo(scales, window)

    def focused(self) -> tuple[float, float]:
        """The weights of the eyes' focus changes (left, right)."""
        return 1.0, 1.0 if self.env.yoked_accommodation else 0.0

    def act(self, delta_deg: Tensor) -> None:
        env = self.env
        optics = env.eye_optics
        optics.focus_by(self.increments(delta_deg) / optics.degrees_per_dioptre, self.focused())
        env.images.moved()

    def error_deg(self) -> Tensor:
        """The defocus of its eye as its blur disc's signed angular diameter, degrees."""
        optics = self.env.eye_optics
        return optics.defocus()[:, self.eye] * optics.degrees_per_dioptre

    def to_optimum(self) -> Tensor:
        return -self.error_deg()

    def start_fixation(self, fixation: int) -> None:
        env = self.env  # both eyes at the start focus, as vergence starts parallel
        if env.accommodation_start_D is not None:
            env.eye_optics.focus_dioptres = torch.full((env.num_envs, 2), float(env.accommodation_start_D),
                                                       dtype=env.dtype, device=env.device)


class AccommodationRight(Accommodation):
    """The right eye's focus alone, a cue of its own where accommodation is not yoked."""

    name = "accommodation_right"
    eye = 1

    def focused(self) -> tuple[float, float]:
        return 0.0, 1.0

    def start_fixation(self, fixation: int) -> None:
        """(`Accommodation` started both eyes' focus.)"""
