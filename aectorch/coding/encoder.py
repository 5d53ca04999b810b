"""`BinocularEncoder`: the sensory coding model of one depth cue (paper sec. 2.2-2.3).

Two images (the two eyes for the stereo cue, or one eye before and after a body
shift for the motion-parallax cue) are cut into foveal patches at a coarse and a
fine scale, each scale coded by its own `SparseDictionary`. The pooled activities
of both scales are the state features f = [f^C; f^F] (eq. 5), and minus the sum
of the scales' mean reconstruction errors is the reward (eq. 6).
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import torch
from torch import nn

from aectorch.coding.dictionary import DictionaryOutput, SparseDictionary
from aectorch._checks import check_finite
from aectorch.coding.patches import COARSE, FINE, Scale, as_scale, extract_patches, patch_permutation, reduced_patches

__all__ = ["BinocularEncoder", "EncoderOutput", "SYMMETRIES"]

#: The symmetries a `BinocularEncoder` can keep (``None``: none; see `patch_permutation`).
SYMMETRIES = (None, "mirror", "swap")


class EncoderOutput(NamedTuple):
    """What `BinocularEncoder.forward` returns.

    Attributes:
        features: f = [f^C; f^F], pooled activities of both scales, `[B, 2N]` (eq. 5).
        reward: -(e^C + e^F), `[B]` (eq. 6).
        errors: e^j per scale, mean eq. (4) error over that scale's patches, `[B, n_scales]`.
        patches: the binocular patches per scale, each `[B, n_patches_j, P]`.
        codes: the `DictionaryOutput` per scale (codes, reconstructions, per-patch errors).
    """

    features: torch.Tensor
    reward: torch.Tensor
    errors: torch.Tensor
    patches: tuple[torch.Tensor, ...]
    codes: tuple[DictionaryOutput, ...]


class BinocularEncoder(nn.Module):
    """Two-scale sparse coder of an image pair, for one cue.

    Args:
        num_atoms: atoms per scale N (the paper: 288).
        sparsity: non-zero coefficients per patch k (the paper: 10).
        algorithm: ``"mp"`` (the paper's matching pursuit, default) or ``"omp"``.
        scales: the patch scales, coarse first (default: `COARSE`, `FINE`).
        lr: default dictionary learning rate of `learn_`.
        pooling: ``"sum"`` (eq. 3) or ``"mean"`` over patches for the features.
        symmetry: ``None`` (default), or a symmetry of the image pairs that every dictionary then
            keeps (atoms in pairs, `SparseDictionary`'s ``mirror``; `patch_permutation`):
            ``"mirror"`` mirrors both images left-right (the motion-parallax cue's symmetry: it
            negates the pursuit needed), ``"swap"`` exchanges the two images (the stereo cue's: it
            negates the disparity). The features of the transformed pair are then
            ``features[..., feature_permutation]`` (a buffer, ``None`` without a symmetry).
        generator: optional `torch.Generator` for the initial atoms.
        dtype, device: of the dictionaries.

    Attributes:
        coarse, fine: the two `SparseDictionary` modules (also in `dictionaries`).

    Shape:
        first, second: `[B, H, W]` grey images in [0, 1] -> `EncoderOutput`.

    Example:
        >>> import torch
        >>> from aectorch.coding import BinocularEncoder
        >>> enc = BinocularEncoder(generator=torch.Generator().manual_seed(0))
        >>> left, right = torch.rand(2, 3, 240, 320).unbind(0)
        >>> with torch.no_grad():
        ...     out = enc(left, right)
        >>> out.features.shape, out.reward.shape
        (torch.Size([3, 576]), torch.Size([3]))
        >>> _ = enc.learn_(out)   # one dictionary-learning step on both scales
    """

    def __init__(
        self,
        num_atoms: int = 288,
        sparsity: int = 10,
        algorithm: str = "mp",
        scales: Sequence[Scale | str] = (COARSE, FINE),
        *,
        lr: float = 0.05,
        pooling: str = "sum",
        symmetry: str | None = None,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        self.scales = tuple(as_scale(s) for s in scales)
        if len(self.scales) == 0:
            raise ValueError("scales must name at least one scale")
        names = [s.name for s in self.scales]
        if len(set(names)) != len(names):
            raise ValueError(f"scales must have distinct names, got {names}")
        if pooling not in ("sum", "mean"):
            raise ValueError(f"pooling must be 'sum' or 'mean', got {pooling!r}")
        if not lr >= 0:
            raise ValueError(f"lr must be a non-negative float, got {lr!r}")
        if symmetry not in SYMMETRIES:
            raise ValueError(f"symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
        self.lr = float(lr)
        self.pooling = pooling
        self.symmetry = symmetry
        self.dictionaries = nn.ModuleDict(
            {
                s.name: SparseDictionary(
                    num_atoms, s.dim, sparsity, algorithm, generator=generator, dtype=dtype, device=device,
                    mirror=None if symmetry is None else patch_permutation(
                        s.patch_size, flip=symmetry == "mirror", swap=symmetry == "swap"),
                )
                for s in self.scales
            }
        )
        # With a symmetry: the index mapping the features of a pair to those of the transformed pair
        # (each atom's partner, scale by scale), `[num_features]`; else None. Derived, not saved.
        permutation = None
        if symmetry is not None:
            parts, offset = [], 0
            for d in self.dictionaries.values():
                parts.append(d.partner + offset)
                offset += d.num_atoms
            permutation = torch.cat(parts)
        self.register_buffer("feature_permutation", permutation, persistent=False)

    def __getattr__(self, name: str):
        # `encoder.coarse` / `encoder.fine` reach the per-scale dictionaries.
        try:
            return super().__getattr__(name)
        except AttributeError:
            dictionaries = self._modules.get("dictionaries")
            if dictionaries is not None and name in dictionaries:
                return dictionaries[name]
            raise

    @property
    def num_features(self) -> int:
        """Length of the feature vector, ``n_scales * N``."""
        return sum(d.num_atoms for d in self.dictionaries.values())

    def forward(self, first, second, *, check: bool = True) -> EncoderOutput:
        """Encode an image pair; see the class docstring for shapes.

        ``first`` and ``second`` may also be dicts ``{scale name: [B, side, side]}`` of images
        already at each scale's resolution (``ActiveDepthEnv``'s observations with ``scales``),
        cut with `reduced_patches` instead of cropped and reduced.
        """
        if check:  # once here, not once per scale inside extract_patches
            for name, images in (("first", first), ("second", second)):
                for part in (images.values() if isinstance(images, dict) else (images,)):
                    if isinstance(part, torch.Tensor):  # other types: extract_patches says why
                        check_finite(part, name)
        patches, codes, features, errors = [], [], [], []
        for scale in self.scales:
            dictionary = self.dictionaries[scale.name]
            if isinstance(first, dict):
                x = reduced_patches(first[scale.name], second[scale.name], scale)
            else:
                x = extract_patches(first, second, scale, check_finite=False)
            out = dictionary(x, check=check)
            patches.append(x)
            codes.append(out)
            features.append(dictionary.pooled_activity(out.code, reduction=self.pooling))
            errors.append(out.error.mean(-1))
        errors_t = torch.stack(errors, -1)
        return EncoderOutput(
            torch.cat(features, -1), -errors_t.sum(-1), errors_t, tuple(patches), tuple(codes)
        )

    @torch.no_grad()
    def learn_(self, output: EncoderOutput, lr: float | None = None, *,
               reduce: Callable[[torch.Tensor], torch.Tensor] | None = None) -> "BinocularEncoder":
        """One dictionary-learning step on every scale, then renormalise.

        Gradient descent on ``-output.reward.mean()`` (closed form, no graph):
        with B environments this is the mean of the B per-environment updates.
        Equivalent to ``(-output.reward.mean()).backward()`` followed by an SGD
        step of size `lr` and `SparseDictionary.renormalize_`. ``reduce`` sums over processes
        that share the batch (`aectorch.runtime.distributed`), so the mean runs over all of them.
        """
        lr = self.lr if lr is None else lr
        for scale, x, out in zip(self.scales, output.patches, output.codes):
            self.dictionaries[scale.name].learn_(x, out, lr, reduce=reduce)
        return self
