"""`BinocularEncoder`: the sensory coding model of one depth cue (paper sec. 2.2-2.3).

Two images (the two eyes for the stereo cue, or one eye before and after a body
shift for the motion-parallax cue) are cut into foveal patches at each scale (the
paper's coarse and fine scale, by default also a wider one), each scale coded by its
own `SparseDictionary`. The pooled activities of all scales are the state features
f = [f^C; f^F] (eq. 5), and minus the sum of the scales' mean reconstruction errors is
the reward (eq. 6). `EncoderConfig` holds the coder's hyperparameters.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable, NamedTuple, Optional, Sequence

import torch
from torch import Tensor, nn

from aectorch._checks import check_bool, check_choice, check_finite, check_int, check_real, is_real
from aectorch.choices import Algorithm, DictionaryStart, Pooling
from aectorch.coding.dictionary import DictionaryOutput, SparseDictionary, learn_together_
from aectorch.coding.patches import (
    DEFAULT_SCALES, WINDOW, Scale, as_scale, fovea_weights, patch_permutation, scale_patches, window_patches,
)

__all__ = ["BinocularEncoder", "EncoderConfig", "EncoderOutput", "SYMMETRIES"]

#: The symmetries a `BinocularEncoder` can keep (``None``: none; see `patch_permutation`).
SYMMETRIES = (None, "mirror", "swap")


@dataclass
class EncoderConfig:
    """Hyperparameters of `BinocularEncoder`: the sparse coder and its dictionary learning.

    Attributes:
        num_atoms: atoms per dictionary, N (paper: 288).
        sparsity: non-zero coefficients per patch (paper: 10).
        algorithm: ``"mp"`` (the paper's matching pursuit) or ``"omp"``.
        pooling: ``"mean"`` over patches (the lineage; keeps the features' norm near 1, which the
            critic's step size needs) or ``"sum"`` (eq. 3 literally).
        lr: the dictionaries' learning rate per step (the lineage: 0.01-0.5; default 0.1; 0
            freezes them).
        decay: tau (> 0; default 500), or ``None`` for a constant rate (the lineage): the rate
            after t learning steps is ``lr * (tau / (tau + t)) ** decay_power``, so the code settles
            once the eye movements have shaped it (the lineage raised its rate over training;
            online dictionary learning decays it).
        decay_power: p of ``decay`` (> 0).
        floor: ``None`` (default: the rate decays on), or a fraction in (0, 1]: the decaying rate
            falls no lower than ``floor * lr``, so the code stays plastic (a perturbation
            experiment's choice: `aectorch.runtime.config`, ``plasticity=floor``).
        close_at: ``None`` (default: no critical period), or the learning step (>= 0) at which a
            critical period starts to close: from there the rate (after ``decay``) falls linearly
            to 0 over ``close_over`` steps and stays there (``floor`` still holds it at
            ``floor * lr``: a residual adult plasticity). The code is shaped by what the eyes see
            before; a change of the world after it is met by the policies alone (the rearing
            conditions' choice, :data:`aectorch.runtime.presets.REARING_SETTINGS`).
        close_over: the steps (>= 0; 0: at once) over which the critical period closes.
        centred: mirror-centred sampling at every scale (`aectorch.coding.patches.Scale`'s
            ``centred``): each pyramid level samples between pixel pairs and the fine scale's
            patch grid sits in the middle of its crop, so the patches of mirrored images are the
            mirrored patches and the parallax cue's symmetry holds exactly. ``False`` is the classic
            reduce (``cv2.pyrDown``), whose samples drift 0.5-7.5 px left of the crop's centre:
            measured on a trained learner, the features of a mirrored pair then differ from the
            permuted features by 14-60 % (by scale), so the mirrored transitions the symmetry
            learns from are not the real ones.
        fovea_px: ``None`` (default: every patch counts alike, the lineage), or the standard
            deviation (> 0) in full-resolution pixels of a foveal weighting: each patch counts by a
            Gaussian of its centre's distance from the crop's centre (`fovea_weights`, mean 1 per
            scale) in the reward (its normalised error times the weight) and in the pooled
            features (its patch vector scaled by the square root of the weight, which scales its
            squared coefficients by the weight and leaves its code, which atoms, unchanged). The
            dictionaries learn from every patch alike. Where a window spans several depths, the
            centre's surface then dominates what the policy sees and is rewarded for
            (experiments/stereo_pairs/README.md).
        start: the dictionaries' first atoms: ``"random"`` (Gaussian, the default) or
            ``"binocular"`` (Gaussian, each atom's second image half a copy of its first: every
            atom starts tuned to zero disparity, so the first code is best where the two images
            agree). The paper does not state its start; without the swap symmetry, a random
            start can let stereo settle on a disparity of its own (docs/paper-mapping.md).
    """

    num_atoms: int = 288
    sparsity: int = 10
    algorithm: Algorithm = Algorithm.mp
    pooling: Pooling = Pooling.mean
    lr: float = 0.1
    decay: Optional[float] = 500.0
    decay_power: float = 1.0
    floor: Optional[float] = None
    close_at: Optional[int] = None
    close_over: int = 0
    centred: bool = True
    start: DictionaryStart = DictionaryStart.random
    fovea_px: Optional[float] = None

    def __post_init__(self) -> None:
        owner = "encoder"
        check_int(self.num_atoms, f"{owner}.num_atoms", 1)
        check_int(self.sparsity, f"{owner}.sparsity", 1)
        self.algorithm = check_choice(self.algorithm, f"{owner}.algorithm", Algorithm)
        self.pooling = check_choice(self.pooling, f"{owner}.pooling", Pooling)
        check_real(self.lr, f"{owner}.lr", minimum=0)
        if self.decay is not None and not (is_real(self.decay) and self.decay > 0):
            raise ValueError(f"{owner}.decay must be null or a number > 0, got {self.decay!r}")
        check_real(self.decay_power, f"{owner}.decay_power", above=0)
        if self.floor is not None and not (is_real(self.floor) and 0 < self.floor <= 1):
            raise ValueError(f"{owner}.floor must be null or a fraction in (0, 1], got {self.floor!r}")
        if self.close_at is not None:
            check_int(self.close_at, f"{owner}.close_at", 0)
        check_int(self.close_over, f"{owner}.close_over", 0)
        check_bool(self.centred, f"{owner}.centred")
        self.start = check_choice(self.start, f"{owner}.start", DictionaryStart)
        if self.fovea_px is not None and not (is_real(self.fovea_px) and self.fovea_px > 0):
            raise ValueError(f"{owner}.fovea_px must be null or a number of pixels > 0, got {self.fovea_px!r}")

    def rate(self, steps: int) -> float:
        """The dictionaries' learning rate after ``steps`` learning steps (``decay``, the critical
        period's ``close_at`` and ``close_over``, ``floor``).

        Example:
            >>> config = EncoderConfig(lr=2.0, decay=None, close_at=100, close_over=50)
            >>> tuple(config.rate(t) for t in (0, 100, 125, 150, 1000))
            (2.0, 2.0, 1.0, 0.0, 0.0)
        """
        rate = self.lr if self.decay is None else self.lr * (self.decay / (self.decay + steps)) ** self.decay_power
        if self.close_at is not None and steps >= self.close_at:
            rate *= max(0.0, 1.0 - (steps - self.close_at) / self.close_over) if self.close_over else 0.0
        return rate if self.floor is None else max(rate, self.floor * self.lr)

    def steps_at(self, fraction: float) -> int:
        """The learning steps after which the decaying rate is ``fraction`` of ``lr`` (rounded
        down; 0 for a constant rate): where `BinocularEncoder.raise_rate` puts the decay's clock."""
        if self.decay is None:
            return 0
        return int(math.floor(self.decay * (fraction ** (-1.0 / self.decay_power) - 1.0) + 1e-9))


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
    """Multi-scale sparse coder of an image pair, for one cue.

    Args:
        config: the coder's hyperparameters (default `EncoderConfig()`).
        scales: the patch scales (default `DEFAULT_SCALES`: wide, coarse, fine, full; the paper's:
            ``("coarse", "fine")``).
        symmetry: ``None`` (default), or a symmetry of the image pairs that every dictionary then
            keeps (atoms in pairs, `SparseDictionary`'s ``mirror``; `patch_permutation`):
            ``"mirror"`` mirrors both images left-right (the motion-parallax cue's symmetry: it
            negates the pursuit needed), ``"swap"`` exchanges the two images (the stereo cue's: it
            negates the disparity). The features of the transformed pair are then
            ``features[..., feature_permutation]`` (a buffer, ``None`` without a symmetry).
        generator: optional `torch.Generator` for the initial atoms.
        dtype, device: of the dictionaries.
        **options: fields of `EncoderConfig` that override ``config``, e.g. ``num_atoms=32``.

    Attributes:
        dictionaries: one `SparseDictionary` per scale, by name (also ``encoder.coarse``, ...).
        steps: learning steps taken so far (the learning rate's decay, `EncoderConfig.rate`).

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
        (torch.Size([3, 1152]), torch.Size([3]))
        >>> _ = enc.learn_(out)   # one dictionary-learning step on every scale
    """

    def __init__(
        self,
        config: EncoderConfig | None = None,
        scales: Sequence[Scale | str] = DEFAULT_SCALES,
        *,
        symmetry: str | None = None,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
        **options,
    ) -> None:
        super().__init__()
        config = EncoderConfig() if config is None else config
        if not isinstance(config, EncoderConfig):
            raise TypeError(f"config must be an EncoderConfig or None, got {type(config).__name__}")
        unknown = sorted(set(options) - {f.name for f in dataclasses.fields(EncoderConfig)})
        if unknown:
            raise TypeError(f"unexpected keyword argument(s) {unknown}; options must be fields of EncoderConfig")
        self.config = cfg = dataclasses.replace(config, **options) if options else config
        scales = tuple(as_scale(s) for s in scales)
        self.scales = tuple(dataclasses.replace(s, centred=True) if cfg.centred else s for s in scales)
        if len(self.scales) == 0:
            raise ValueError("scales must name at least one scale")
        names = [s.name for s in self.scales]
        if len(set(names)) != len(names):
            raise ValueError(f"scales must have distinct names, got {names}")
        if symmetry not in SYMMETRIES:
            raise ValueError(f"symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
        if symmetry is not None and cfg.num_atoms % 2:
            raise ValueError(f"num_atoms must be even with a symmetry (atoms come in pairs), got {cfg.num_atoms}")
        self.pooling = str(cfg.pooling)
        self.symmetry = symmetry
        self.steps = 0
        self.dictionaries = nn.ModuleDict(
            {
                s.name: SparseDictionary(
                    cfg.num_atoms, s.dim, cfg.sparsity, str(cfg.algorithm), generator=generator, dtype=dtype,
                    device=device, mirror=None if symmetry is None else patch_permutation(
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
        # The square roots of the foveal weights, one buffer per scale [num_patches] (derived, not saved).
        self.fovea = cfg.fovea_px is not None
        for s in self.scales:
            root = fovea_weights(s, float(cfg.fovea_px), dtype=dtype, device=device).sqrt() if self.fovea else None
            self.register_buffer(f"fovea_{s.name}", root, persistent=False)
        if cfg.start == DictionaryStart.binocular:
            if symmetry == "swap":
                raise ValueError("encoder.start=binocular gives atoms that the swap symmetry pairs with "
                                 "themselves (duplicate atoms); use it with symmetry null or mirror")
            with torch.no_grad():
                for d in self.dictionaries.values():
                    half = d.dim // 2
                    d.atoms[half:] = d.atoms[:half]
                    d.symmetrize_()
                    d.renormalize_()

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

    def forward(self, first, second=None, *, check: bool = True) -> EncoderOutput:
        """Encode an image pair; see the class docstring for shapes.

        ``first`` and ``second`` may also be dicts ``{scale name: [B, side, side]}`` of images
        already at each scale's resolution (and ``WINDOW``: whole images for the scales missing).
        Without ``second``, ``first`` is an observation of pairs (:meth:`encode`).
        """
        if second is None:
            return self._encode(first, check)
        if isinstance(first, dict) != isinstance(second, dict):
            raise TypeError("first and second must both be tensors or both dicts of tensors")
        firsts, seconds = (first, second) if isinstance(first, dict) else ({WINDOW: first}, {WINDOW: second})
        if set(firsts) != set(seconds):
            raise ValueError(f"first and second must hold the same images, got {sorted(firsts)} and {sorted(seconds)}")
        for name, images in (("first", firsts), ("second", seconds)):
            for key, part in images.items():
                if not isinstance(part, Tensor) or not part.is_floating_point():
                    raise TypeError(f"{name} must be a floating-point tensor [B, H, W] in [0, 1], got "
                                    f"{type(part).__name__} {getattr(part, 'dtype', '')}")
                if part.ndim != 3:
                    raise ValueError(f"{name} must have shape [B, H, W], got {tuple(part.shape)}")
                if part.shape != seconds[key].shape:
                    raise ValueError(f"first[{key!r}] and second[{key!r}] must have one shape, got "
                                     f"{tuple(firsts[key].shape)} and {tuple(seconds[key].shape)}")
                if check:
                    check_finite(part, name)
        return self._encode({key: torch.stack((firsts[key], seconds[key]), dim=1) for key in firsts}, check)

    def encode(self, observation: dict[str, Tensor], *, check: bool = False) -> EncoderOutput:
        """Encode an observation ``{scale name: [B, 2, side, side]}`` (pairs at each scale's
        resolution) and/or ``{WINDOW: [B, 2, H, W]}`` (whole images, cropped and reduced for the
        scales without an entry of their own): what `aectorch.sim.ActiveDepthEnv` observes.
        ``check`` also checks the dictionaries' inputs. The same as ``encoder(observation)``
        (through ``forward``, so that ``encoder.compile()`` applies)."""
        return self(observation, check=check)

    def _encode(self, observation: dict[str, Tensor], check: bool) -> EncoderOutput:
        patches, codes, features, errors = [], [], [], []
        for scale in self.scales:
            dictionary = self.dictionaries[scale.name]
            if scale.name in observation:
                x = scale_patches(observation[scale.name], scale)
            elif WINDOW in observation:
                x = window_patches(observation[WINDOW], scale)
            else:
                raise ValueError(f"the observation holds neither scale {scale.name!r} nor {WINDOW!r}: "
                                 f"{sorted(observation)}")
            root = getattr(self, f"fovea_{scale.name}").to(x.dtype) if self.fovea else None
            if root is not None:  # the squared coefficients, so the pooled features, scale by the weight
                x = x * root[:, None]
            out, pooled = dictionary.forward_pooled(x, check=check, reduction=self.pooling)
            patches.append(x)
            codes.append(out)
            features.append(pooled)
            # (the errors are normalised by each patch's energy: the weight is applied to them here)
            errors.append(out.error.mean(-1) if root is None else (out.error * root.square()).mean(-1))
        errors_t = torch.stack(errors, -1)
        return EncoderOutput(
            torch.cat(features, -1), -errors_t.sum(-1), errors_t, tuple(patches), tuple(codes)
        )

    def rate(self) -> float:
        """The learning rate of the next `learn_` step (`EncoderConfig.rate` of `steps`)."""
        return self.config.rate(self.steps)

    def raise_rate(self, fraction: float) -> float:
        """Make the dictionaries plastic again: a decayed rate is raised to ``fraction`` (in (0, 1])
        of ``lr`` by winding the decay's clock back (`EncoderConfig.steps_at`), from where it
        decays again; a rate above that stays. The clock is also the critical period's: a
        constant rate's clock goes back to 0, which opens a closed period again. Returns the
        rate of the next step."""
        if not (is_real(fraction) and 0 < fraction <= 1):
            raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
        self.steps = min(self.steps, self.config.steps_at(fraction))
        return self.rate()

    @torch.no_grad()
    def learn_(self, output: EncoderOutput, lr: float | None = None, *,
               reduce: Callable[[Tensor], Tensor] | None = None) -> "BinocularEncoder":
        """One dictionary-learning step on every scale, then renormalise; counts a step.

        Gradient descent on ``-output.reward.mean()`` (closed form, no graph):
        with B environments this is the mean of the B per-environment updates.
        Equivalent to ``(-output.reward.mean()).backward()`` followed by an SGD
        step of size ``lr`` (default: :meth:`rate`) and `SparseDictionary.renormalize_`; a rate of
        0 leaves the atoms as they are (and costs nothing).
        ``reduce`` sums over processes that share the batch (`aectorch.runtime.distributed`), so
        the mean runs over all of them.
        """
        lr = self.rate() if lr is None else lr
        if lr == 0:  # frozen (``lr`` 0, a closed critical period): the atoms stay bit for bit
            self.steps += 1
            return self
        learn_together_([self.dictionaries[scale.name] for scale in self.scales], output.patches, output.codes, lr,
                        reduce=reduce)
        self.steps += 1
        return self

    def get_extra_state(self) -> dict:
        return {"steps": self.steps}

    def set_extra_state(self, state: dict) -> None:
        self.steps = int(state["steps"])
