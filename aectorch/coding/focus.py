"""The coding efficiency of an image pair as a reward that prefers focus.

Eckmann et al. 2020 (PNAS) reward the eyes with the mutual information between the retinal
input R and its code C, ``I(R;C) = H(R) - H(R|C)``. The code is a function of the input, so
``I(R;C) = H(C)``: the information the code carries is what it keeps of the input. In the
Gaussian approximation, per patch and scale, with E the input's contrast energy (its variance
per pixel before the coder normalises it) and e the coder's relative reconstruction error (eq. 4,
of the normalised patch), the code holds the energy ``E (1 - e)`` and

    H(R) = 1/2 log E + c,   H(R|C) = 1/2 log(e E) + c,   I(R;C) = H(C) = 1/2 log(E (1 - e)) + c'

(the last from the code's own Gaussian entropy; the middle pair's difference, ``-1/2 log e``,
is the scale-free part that a coder of normalised patches sees). The two terms pull apart under
defocus: blur is a low-pass filter, so E falls (H(R) prefers focus), while a smooth patch is
easier to reconstruct, so e falls too (the coding reward ``-e`` prefers blur). The focus
reward :func:`focus_reward` is ``sum_scales mean_patches 1/2 log(E (1 - e))``; experiments/accommodation/focus_curve.py
measures each term against defocus (experiments/accommodation/README.md).
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from aectorch.coding.patches import Scale, as_scale

__all__ = ["FOCUS_ENERGY_FLOOR", "focus_reward", "input_energy"]

#: A floor under the contrast energy (variance per pixel, images in [0, 1]) in the logarithm: an
#: 8-bit image's quantisation noise, (1/255)^2 / 12. A flat patch gives a finite reward.
FOCUS_ENERGY_FLOOR = (1.0 / 255.0) ** 2 / 12.0


def input_energy(pair: Tensor, scale: Scale | str) -> Tensor:
    """The contrast energy of each patch of ``pair`` ``[B, 2, side, side]`` (a scale's reduced
    crop, as `aectorch.sim.ActiveDepthEnv` observes it) on ``scale``'s patch grid: the variance
    per pixel of each monocular half, averaged over the two eyes, ``[B, n_patches]``, before the
    coder makes the halves zero-mean and unit-norm.

    Example:
        >>> pair = torch.rand(3, 2, 40, 40)
        >>> input_energy(pair, "full").shape, input_energy(torch.full((1, 2, 40, 40), 0.5), "full").max().item()
        (torch.Size([3, 49]), 0.0)
    """
    scale = as_scale(scale)
    if pair.dim() != 4 or pair.shape[1] != 2 or pair.shape[-2:] != (scale.side, scale.side):
        raise ValueError(f"pair must be [B, 2, {scale.side}, {scale.side}] (the {scale.name} scale's crop), "
                         f"got {tuple(pair.shape)}")
    o, extent = scale.offset, (scale.grid - 1) * scale.stride + scale.patch_size
    region = pair[..., o:o + extent, o:o + extent]
    patches = region.unfold(-2, scale.patch_size, scale.stride).unfold(-2, scale.patch_size, scale.stride)
    patches = patches.flatten(-2)  # [B, 2, grid, grid, p * p]
    return patches.var(dim=-1, unbiased=False).mean(dim=1).flatten(1)


def focus_reward(energy: Tensor | Sequence[Tensor], error: Tensor | Sequence[Tensor], *,
                 floor: float = FOCUS_ENERGY_FLOOR) -> Tensor:
    """The information a code keeps of its input, ``1/2 log(E (1 - e))``, per patch, averaged over
    patches and summed over scales: ``energy`` and ``error`` ``[B, n_scales, n_patches]`` or lists
    of ``[B, n_patches_j]`` per scale (E from :func:`input_energy`, e the coder's per-patch error
    of eq. 4), ``floor`` added to the code's energy. Returns ``[B]``.

    Example:
        >>> E, e = torch.tensor([[[0.01]]]), torch.tensor([[[0.2]]])
        >>> round(float(focus_reward(E, e)), 3), bool(focus_reward(E / 4, e / 2) < focus_reward(E, e))
        (-2.414, True)
    """
    if isinstance(energy, Tensor):
        energy, error = energy.unbind(1), error.unbind(1)  # type: ignore[union-attr]  # both or neither
    if len(energy) != len(error) or any(E.shape != e.shape for E, e in zip(energy, error)):
        raise ValueError(f"energy and error must have one [B, n_patches] tensor per scale of the same shapes, got "
                         f"{[tuple(E.shape) for E in energy]} and {[tuple(e.shape) for e in error]}")
    kept = [(E * (1.0 - e).clamp_min(0.0) + floor).log().mean(-1) / 2 for E, e in zip(energy, error)]
    return torch.stack(kept, -1).sum(-1)
