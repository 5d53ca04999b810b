"""The eyes' optics of an `ActiveDepthEnv`: their perturbations (`Optics`), aperture and focus.

`EyeOptics` holds what the eyes are now: the `Optics` they see through (rolled, offset, moved,
blurred, dimmed, magnified), the pupil's ``aperture_m`` and each eye's focus (``None``: each eye
focused on the object, wherever it is). The defocus it derives blurs the renderers' images
(`aectorch.sim.observations`) and is the accommodation movement's error
(`aectorch.sim.movements.accommodation`).

Example:
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
    ...                      seed=0)
    >>> env.eye_optics.focus_dioptres is None  # each eye focused on the object
    True
    >>> env.set_focus(0.0)  # both at infinity
    >>> bool((env.eye_optics.defocus() < 0).all())
    True
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from aectorch.sim.perturbations import NEUTRAL, Optics


__all__ = ["EyeOptics"]


class EyeOptics:
    """The optics, aperture and focus of ``env``'s eyes (an `ActiveDepthEnv`, whose object distance it reads)."""

    #: Its part of the environment's batch state (`ActiveDepthEnv.state_dict`): the state's key -> its
    #: attribute, a tensor ``[B, ...]`` stored while it is not ``None``.
    STATE = {"focus_dioptres": "focus_dioptres"}

    def __init__(self, env: Any) -> None:
        self.env = env
        self.optics: Optics = NEUTRAL
        self.focus_dioptres: Tensor | None = None  # [B, 2]; None: each eye focused on the object
        self._tensors: dict[str, Tensor] = {}

    @property
    def aperture_m(self) -> float:
        """The pupil's diameter, metres (0: pinholes, never out of focus): ``env.aperture_m``."""
        return self.env.aperture_m

    def set_optics(self, optics: Optics) -> None:
        """Perturb the eyes by ``optics`` (checked: a refractive error needs an aperture)."""
        if not isinstance(optics, Optics):
            raise TypeError(f"optics must be an aectorch.sim.perturbations.Optics, got {type(optics).__name__}")
        if optics.refraction_D != NEUTRAL.refraction_D and self.aperture_m == 0:
            raise ValueError(f"optics.refraction_D={optics.refraction_D}: a refractive error blurs only through an "
                             "aperture, and this environment's eyes are pinholes (aperture_m=0); give aperture_m > 0")
        self.optics = optics
        self._tensors = {}

    def tensor(self, name: str) -> Tensor:
        """``optics.<name>`` as a tensor of the environment's dtype and device (kept until the optics change)."""
        tensor = self._tensors.get(name)
        if tensor is None:
            tensor = torch.tensor(getattr(self.optics, name), dtype=self.env.dtype, device=self.env.device)
            self._tensors[name] = tensor
        return tensor

    def eye_shift(self) -> Tensor | None:
        """The cameras' translations ``[2, 3]`` (camera_shift), or ``None`` when neither moved."""
        return None if self.optics.shift_m == NEUTRAL.shift_m else self.tensor("shift_m")

    def set_focus(self, dioptres=None) -> None:
        """Each eye's focus from now on (`ActiveDepthEnv.set_focus`), checked."""
        if dioptres is None:
            self.focus_dioptres = None
            return
        env = self.env
        focus = torch.as_tensor(dioptres, dtype=env.dtype, device=env.device)
        if focus.shape not in ((), (2,), (env.num_envs, 2)) or not bool((torch.isfinite(focus) & (focus >= 0)).all()):
            raise ValueError(f"dioptres must be None or finite values >= 0 of shape [], [2] or [B, 2] = "
                             f"[{env.num_envs}, 2], got {dioptres!r}")
        self.focus_dioptres = focus.expand(env.num_envs, 2).clone()

    def focus_by(self, delta_dioptres: Tensor, eyes: tuple[float, float]) -> None:
        """Change the focus of the eyes weighted by ``eyes`` by ``delta_dioptres`` ``[B]``, at least 0 D
        (an eye that followed the object starts from its distance)."""
        env = self.env
        focus = self.focus_dioptres if self.focus_dioptres is not None else \
            (1.0 / env.object_distance_m)[:, None].expand(env.num_envs, 2)
        self.focus_dioptres = (focus + delta_dioptres[:, None] * focus.new_tensor(eyes)).clamp_min(0.0)

    @property
    def degrees_per_dioptre(self) -> float:
        """The blur disc's angular diameter per dioptre of defocus, degrees (``aperture_m`` in radians)."""
        return math.degrees(self.aperture_m)

    def defocus(self, optics: Optics | None = None) -> Tensor:
        """Each eye's defocus ``[B, 2]`` (dioptres) with the refractive errors of ``optics`` (default the eyes')."""
        env, optics = self.env, self.optics if optics is None else optics
        refraction = None if optics.refraction_D == NEUTRAL.refraction_D else \
            torch.tensor(optics.refraction_D, dtype=env.dtype, device=env.device)
        if self.focus_dioptres is None:
            defocus = torch.zeros(env.num_envs, 2, dtype=env.dtype, device=env.device)
        else:
            defocus = self.focus_dioptres - 1.0 / env.object_distance_m[:, None]
        return defocus if refraction is None else defocus + refraction

    def world_blur_arcmin(self, optics: Optics) -> Tensor | None:
        """Each eye's defocus blur disc ``[B, 2]`` (diameter, arcmin) with the refractive errors of
        ``optics``, or ``None`` where no eye is out of focus."""
        if self.aperture_m == 0 or (self.focus_dioptres is None and optics.refraction_D == NEUTRAL.refraction_D):
            return None
        return self.aperture_m * self.defocus(optics).abs() * (180.0 * 60.0 / math.pi)
