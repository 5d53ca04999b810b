"""Foveal two-scale patch extraction: the input stage of the binocular sparse coder.

Two grey images (a stereo pair, or two successive frames of the dominant eye) are each cropped
around their centre, reduced with a Gaussian pyramid, and cut into 10 x 10 patches. The two
monocular halves of a patch are each made zero-mean and unit-norm and then concatenated, first
image first, into one binocular vector of length 200. See ``docs/sensory-coding.md`` for why the
coarse scale is the 128 px crop reduced by 8 and the fine scale the 80 px crop reduced by 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from aectorch._checks import check_bool, check_int
from aectorch._checks import check_finite as _check_finite

__all__ = [
    "Scale",
    "COARSE",
    "FINE",
    "WIDE",
    "FULL",
    "SCALE_NAMES",
    "DEFAULT_SCALES",
    "as_scale",
    "pyramid_down",
    "WINDOW",
    "extract_patches",
    "reduced_patches",
    "scale_patches",
    "window_patches",
    "patch_permutation",
    "patch_energy",
    "fovea_weights",
    "FovealPatches",
]

#: The key of an observation's whole rendered window, ``[B, 2, H, W]``, beside the scales' entries
#: ``{scale name: [B, 2, side, side]}`` (`aectorch.sim.ActiveDepthEnv`'s observations, whose
#: ``aectorch.sim.WINDOW`` is the same key): a scale whose entry is missing is cut from the window
#: (crop and pyramid).
WINDOW = "window"

# Burt & Adelson's 5-tap binomial kernel, the one OpenCV's pyrDown uses. The taps are dyadic
# rationals, so they are exact in every float dtype.
_BINOMIAL_5 = (1.0 / 16, 4.0 / 16, 6.0 / 16, 4.0 / 16, 1.0 / 16)
#: The centred reduce's kernel: binomial of order 5, symmetric about a half-pixel position.
_BINOMIAL_6 = (1.0 / 32, 5.0 / 32, 10.0 / 32, 10.0 / 32, 5.0 / 32, 1.0 / 32)

# A flat half only becomes exactly flat after the pyramid and the mean up to rounding, which is a
# few ulps of the pixel values, i.e. ~1e-7 in float32 -- far above an absolute eps of 1e-8. The
# flat test therefore adds a rounding allowance of this many machine epsilons per unit of
# sqrt(patch pixels) * max|pixel| (1e-5 for a float32 half of values near 1; 2e-14 in float64).
_ROUNDING_ULPS = 8.0


@dataclass(frozen=True)
class Scale:
    """One foveal scale: a central square crop, a pyramid reduction and a patch grid.

    Args:
        name: label used in logs and configs (``"coarse"``, ``"fine"``).
        crop: side of the central square crop in pixels of the full image.
        downsample: Gaussian-pyramid reduction factor, a power of two (1 = no reduction).
        patch_size: side of a square monocular patch in pixels of the reduced crop.
        stride: step between neighbouring patches in pixels of the reduced crop (keyword-only,
            no default).
        centred: mirror-centred sampling (keyword-only, default ``False``): every pyramid level
            keeps samples centred between two pixels (:func:`pyramid_down` with ``centred``) and
            the patch grid sits in the middle of the reduced crop, so the patches of mirrored
            images are exactly the mirrored patches. The classic reduce keeps even samples, which
            moves the sampling 0.5 px (one level) to 7.5 px (four levels) off the crop's centre,
            and the fine scale's grid of 8 patches at stride 4 covers columns 0-37 of 40.

    Example:
        >>> s = Scale("coarse", crop=128, downsample=8, stride=1)
        >>> s.grid, s.num_patches, s.dim
        (7, 49, 200)
    """

    name: str
    crop: int
    downsample: int
    patch_size: int = 10
    stride: int = field(kw_only=True)
    centred: bool = field(default=False, kw_only=True)

    def __post_init__(self) -> None:
        for name in ("crop", "downsample", "patch_size", "stride"):
            check_int(getattr(self, name), f"Scale.{name}")
        if self.downsample & (self.downsample - 1):
            raise ValueError(
                f"Scale.downsample must be a power of two (Gaussian pyramid), got {self.downsample}"
            )
        if self.crop % self.downsample:
            raise ValueError(
                f"Scale.crop={self.crop} must be divisible by Scale.downsample={self.downsample}"
            )
        side = self.crop // self.downsample
        if self.downsample > 1 and side < 2:
            # the last pyramid level reads a 2*side image and reflect-101 padding needs >= 3 px
            raise ValueError(
                f"Scale.crop={self.crop} is too small for Scale.downsample={self.downsample}: "
                f"the reduced crop must be at least 2 px, got {side}"
            )
        if self.patch_size > side:
            raise ValueError(
                f"Scale.patch_size={self.patch_size} does not fit in the reduced crop "
                f"{side}x{side} (crop {self.crop} / downsample {self.downsample})"
            )
        check_bool(self.centred, "Scale.centred")
        if self.centred and (self.side - self.patch_size - (self.grid - 1) * self.stride) % 2:
            raise ValueError(
                f"Scale {self.name!r} cannot be centred: its grid leaves an odd number of the reduced "
                f"crop's {self.side} px uncovered"
            )

    @property
    def levels(self) -> int:
        """Number of pyramid reductions, log2(downsample)."""
        return self.downsample.bit_length() - 1

    @property
    def side(self) -> int:
        """Side of the reduced crop in pixels, crop // downsample."""
        return self.crop // self.downsample

    @property
    def grid(self) -> int:
        """Patches per side of the grid."""
        return (self.side - self.patch_size) // self.stride + 1

    @property
    def offset(self) -> int:
        """First row and column of the patch grid in the reduced crop (0 unless centred)."""
        if not self.centred:
            return 0
        return (self.side - self.patch_size - (self.grid - 1) * self.stride) // 2

    @property
    def num_patches(self) -> int:
        """Patches per image pair, grid**2."""
        return self.grid**2

    @property
    def dim(self) -> int:
        """Length of a binocular patch vector, 2 * patch_size**2."""
        return 2 * self.patch_size**2


def fovea_weights(scale: Scale | str, sigma_px: float, *, dtype: torch.dtype | None = None,
                  device: torch.device | str | None = None) -> Tensor:
    """A foveal weighting of a scale's patches ``[num_patches]``: a Gaussian of standard deviation
    ``sigma_px`` (full-resolution pixels, > 0) of each patch centre's distance from the crop's
    centre, scaled so that the weights' mean is 1 (a uniform image keeps its mean reward).

    Patches in the grid's order (row-major, as :func:`extract_patches` cuts them), their centres
    measured in the full-resolution pixels of the crop (a reduced pixel spans ``downsample``).

    Example:
        >>> w = fovea_weights("full", 5.0)
        >>> w.shape, round(float(w.mean()), 6), bool(w[24] == w.max())
        (torch.Size([49]), 1.0, True)
    """
    scale = as_scale(scale)
    if not (isinstance(sigma_px, (int, float)) and not isinstance(sigma_px, bool) and sigma_px > 0):
        raise ValueError(f"sigma_px must be a number of pixels > 0, got {sigma_px!r}")
    g = scale.grid
    centres = (scale.offset + scale.stride * torch.arange(g, dtype=torch.float64) + scale.patch_size / 2
               - scale.side / 2) * scale.downsample
    r2 = centres[:, None] ** 2 + centres[None, :] ** 2
    weights = torch.exp(-r2 / (2.0 * float(sigma_px) ** 2)).reshape(-1)
    return (weights / weights.mean()).to(dtype=dtype or torch.get_default_dtype(), device=device)


def patch_permutation(patch_size: int, *, flip: bool = True, swap: bool = False) -> Tensor:
    """A symmetry of binocular patch vectors as an index, ``x[..., perm]``: mirror and/or swap.

    A patch vector is two ``patch_size x patch_size`` halves, row-major, ``first``'s half first
    (:func:`extract_patches`). ``flip`` reverses the columns of each half (the left-right mirror of
    both images), ``swap`` exchanges the halves. The two symmetries of the experiment:

    - mirroring the world about a vertical plane mirrors both images of the motion-parallax
      pair (one eye before and after the shift) and negates the pursuit it needs
      (``flip=True``);
    - exchanging the two eyes' images of a stereo pair negates the disparity, so the vergence
      error (``flip=False, swap=True``; a fronto-parallel plane, textures statistically mirror
      symmetric).

    Either way the index is an involution: ``perm[perm]`` is the identity.

    Example:
        >>> patch_permutation(2)
        tensor([1, 0, 3, 2, 5, 4, 7, 6])
        >>> patch_permutation(2, flip=False, swap=True)
        tensor([4, 5, 6, 7, 0, 1, 2, 3])
    """
    check_int(patch_size, "patch_size")
    half = torch.arange(patch_size * patch_size)
    if flip:
        half = half.view(patch_size, patch_size).flip(-1).reshape(-1)
    halves = (half + half.numel(), half) if swap else (half, half + half.numel())
    return torch.cat(halves)


COARSE = Scale("coarse", crop=128, downsample=8, stride=1)
"""Parafoveal scale: 128 px crop reduced by 8 to 16 x 16, 10 x 10 patches at stride 1, 49 patches."""

FINE = Scale("fine", crop=80, downsample=2, stride=4)
"""Foveal scale: 80 px crop reduced by 2 to 40 x 40, 10 x 10 patches at stride 4, 64 patches."""

WIDE = Scale("wide", crop=128, downsample=16, patch_size=6, stride=1)
"""Wide scale (not in the paper): 128 px crop reduced by 16 to 8 x 8, 6 x 6 patches at stride 1, 9 patches."""

FULL = Scale("full", crop=40, downsample=1, stride=5)
"""Full-resolution scale (not in the paper): the central 40 px unreduced, 10 x 10 patches at stride 5, 49 patches."""

_NAMED_SCALES = {"wide": WIDE, "coarse": COARSE, "fine": FINE, "full": FULL}

#: The names :func:`as_scale` (and ``LearnerConfig.scales``) accept, widest first.
SCALE_NAMES: tuple[str, ...] = tuple(_NAMED_SCALES)

#: ``JointLearner``'s default scales (``CueConfig.scales``): the paper's coarse and fine scale, the
#: wider one, which tells the direction of large pursuit errors, and the full-resolution one, whose
#: 0.22 deg pixels let the code tell a tenth of a degree from none (docs/results.md).
DEFAULT_SCALES: tuple[str, ...] = ("wide", "coarse", "fine", "full")


def as_scale(scale: Scale | str) -> Scale:
    """Return ``scale`` itself, or the named scale (one of :data:`SCALE_NAMES`).

    Args:
        scale: a :class:`Scale`, or one of the strings ``"wide"``, ``"coarse"``, ``"fine"``, ``"full"``.

    Returns:
        The :class:`Scale`.

    Example:
        >>> as_scale("fine") is FINE
        True
    """
    if isinstance(scale, Scale):
        return scale
    if isinstance(scale, str):
        try:
            return _NAMED_SCALES[scale]
        except KeyError:
            raise ValueError(
                f"scale must be a Scale or one of {sorted(_NAMED_SCALES)}, got {scale!r}"
            ) from None
    raise TypeError(f"scale must be a Scale or a str, got {type(scale).__name__}")


def _check_image(images: Tensor, name: str) -> None:
    if not isinstance(images, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(images).__name__}")
    if images.dim() != 3:
        raise ValueError(
            f"{name} must have shape [B, H, W] (rank 3), got shape {tuple(images.shape)}"
        )
    if not images.is_floating_point():
        raise TypeError(
            f"{name} has dtype {images.dtype}: expected a floating-point image in [0, 1]; "
            "convert uint8 with x.float() / 255"
        )


def _check_pair(first: Tensor, second: Tensor) -> None:
    """Two ``[B, H, W]`` float images of one shape, dtype and device."""
    _check_image(first, "first")
    _check_image(second, "second")
    if first.shape != second.shape:
        raise ValueError(
            f"first and second must have the same shape, got {tuple(first.shape)} "
            f"and {tuple(second.shape)}"
        )
    if first.dtype != second.dtype or first.device != second.device:
        raise TypeError(
            f"first and second must share dtype and device, got {first.dtype} on {first.device} "
            f"and {second.dtype} on {second.device}"
        )


def _reduce_matrix_1d(n: int, levels: int, centred: bool = False) -> Tensor:
    """The 1-D pyramid reduce as a matrix ``[ceil(n / 2**levels), n]`` (float64, CPU)."""
    taps = torch.tensor(_BINOMIAL_6 if centred else _BINOMIAL_5, dtype=torch.float64)
    operator = torch.eye(n, dtype=torch.float64)
    for _ in range(levels):
        # Rows of `operator` are signals; blur each with reflect-101 borders, keep even samples
        # (centred: the 6-tap kernel's output i is centred at 2i + 0.5, between two pixels).
        rows = F.pad(operator.T.unsqueeze(1), (2, 2), mode="reflect")  # [n, 1, m + 4]
        operator = F.conv1d(rows, taps.view(1, 1, -1), stride=2).squeeze(1).T  # [ceil(m/2), n]
    return operator


_REDUCE_CACHE: dict[tuple, Tensor] = {}


def _reduce_matrix(n: int, levels: int, dtype: torch.dtype, device: torch.device,
                   centred: bool = False) -> Tensor:
    if torch.compiler.is_compiling():  # traced (and constant-folded) inside a compiled graph
        return _reduce_matrix_1d(n, levels, centred).to(dtype=dtype, device=device)
    key = (n, levels, dtype, device, centred)
    matrix = _REDUCE_CACHE.get(key)
    if matrix is None:
        matrix = _REDUCE_CACHE[key] = _reduce_matrix_1d(n, levels, centred).to(dtype=dtype, device=device)
    return matrix


def _pyramid_down(x: Tensor, levels: int, centred: bool = False) -> Tensor:
    """Reduce a ``[N, 1, H, W]`` tensor ``levels`` times; no checks.

    The reduce is linear and separable, so all levels fold into one matrix per axis and the whole
    pyramid is two matrix products, ``R_h X R_w^T`` (several times faster than per-level
    single-channel convolutions on CPU).
    """
    rows = _reduce_matrix(x.shape[-2], levels, x.dtype, x.device, centred)
    cols = rows if x.shape[-1] == x.shape[-2] else _reduce_matrix(x.shape[-1], levels, x.dtype, x.device, centred)
    return rows @ x @ cols.T


def pyramid_down(images: Tensor, levels: int, *, centred: bool = False) -> Tensor:
    """Gaussian-pyramid reduce ``images`` ``levels`` times (Burt & Adelson, like ``cv2.pyrDown``).

    Each level blurs with the separable binomial kernel [1, 4, 6, 4, 1] / 16 along both axes,
    with reflect-101 borders (``... c b | a b c ... | ... b c``, no edge pixel repeated), and keeps
    the pixels with even row and column indices, so a side n becomes ceil(n / 2). With
    ``centred`` the kernel is [1, 5, 10, 10, 5, 1] / 32 over pixels 2i - 2 .. 2i + 3, so output i
    is centred at 2i + 0.5, between two pixels: the reduce of a mirrored image is the mirrored
    reduce (even sides only), which the classic one, whose samples sit 0.5 px left of centre at
    every level, is not.

    Args:
        images: grey images, any floating dtype, any device.
        levels: number of reductions (0 returns ``images`` unchanged).
        centred: the mirror-centred reduce (every intermediate side must be even).

    Returns:
        The reduced images, same dtype and device as ``images``.

    Shape:
        - images: :math:`(B, H, W)`, every intermediate side at least 3 px.
        - output: :math:`(B, H', W')` with ``H' = ceil(H / 2**levels)``, likewise ``W'``.

    Example:
        >>> x = torch.rand(2, 240, 320)
        >>> pyramid_down(x, 3).shape
        torch.Size([2, 30, 40])
        >>> torch.allclose(pyramid_down(torch.full((1, 8, 8), 0.5), 2), torch.full((1, 2, 2), 0.5))
        True
    """
    _check_image(images, "images")
    check_int(levels, "levels", 0)
    h, w = images.shape[-2:]
    for level in range(levels):
        if h < 3 or w < 3:
            raise ValueError(
                f"images of shape {tuple(images.shape)} are too small for {levels} pyramid levels: "
                f"level {level} would read a {h}x{w} image, reflect-101 borders need >= 3 px"
            )
        if centred and (h % 2 or w % 2):
            raise ValueError(f"centred=True needs even sides at every level; level {level} reads a {h}x{w} image")
        h, w = (h + 1) // 2, (w + 1) // 2
    if levels == 0:
        return images
    return _pyramid_down(images.unsqueeze(1), levels, centred).squeeze(1)


def extract_patches(
    first: Tensor,
    second: Tensor,
    scale: Scale | str,
    *,
    eps: float = 1e-8,
    check_finite: bool = True,
) -> Tensor:
    """Cut normalised binocular patches from the centre of two grey images at one foveal scale.

    Both images are cropped to the central ``scale.crop`` square (offset ``(H - crop) // 2`` rows
    and ``(W - crop) // 2`` columns: when the difference is odd the crop sits half a pixel up and
    left of the true centre), reduced by ``scale.downsample`` with :func:`pyramid_down`, and cut
    into ``patch_size x patch_size`` patches at ``scale.stride``. Patches are ordered row-major over
    the grid and pixels row-major within a patch. Each monocular half is made zero-mean and
    unit-L2-norm; a flat half (centred norm at most ``eps`` plus a dtype rounding allowance of
    ``8 * finfo.eps * sqrt(patch_size**2) * max|half|``) becomes all zeros, never NaN. The
    halves are concatenated with ``first``'s half first.

    Args:
        first: first images (dominant eye, or the frame before the body shift), floats in [0, 1].
        second: second images (other eye, or the frame after the shift), same shape as ``first``.
        scale: a :class:`Scale`, or ``"coarse"`` / ``"fine"``.
        eps: absolute floor of the centred norm below which a half counts as flat.
        check_finite: raise on NaN/inf in the inputs. This costs a pass over the data and a host
            sync; pass ``False`` on hot paths. Skipped automatically inside ``torch.compile``.

    Returns:
        Binocular patch vectors, same dtype and device as the inputs. A textured patch has
        squared norm 2 (1 per half).

    Shape:
        - first, second: :math:`(B, H, W)` with ``H, W >= scale.crop``.
        - output: :math:`(B, N, 2 P^2)` with ``N = scale.num_patches`` and ``P = scale.patch_size``.

    Example:
        >>> first, second = torch.rand(3, 240, 320), torch.rand(3, 240, 320)
        >>> extract_patches(first, second, "coarse").shape
        torch.Size([3, 49, 200])
        >>> x = extract_patches(first, second, FINE)
        >>> x.shape
        torch.Size([3, 64, 200])
        >>> torch.allclose(x.square().sum(-1), torch.full((3, 64), 2.0))
        True
    """
    scale = as_scale(scale)
    _check_pair(first, second)
    b, h, w = first.shape
    crop = scale.crop
    if h < crop or w < crop:
        raise ValueError(
            f"first and second of shape {tuple(first.shape)} are smaller than the "
            f"{crop}x{crop} crop of scale {scale.name!r}"
        )
    if check_finite:
        _check_finite(first, "first")
        _check_finite(second, "second")

    return window_patches(torch.stack((first, second), dim=1), scale, eps=eps)


def window_patches(pair: Tensor, scale: Scale | str, *, eps: float = 1e-8) -> Tensor:
    """:func:`extract_patches` of an image pair stacked as ``[B, 2, H, W]`` (``first`` at index 0),
    without the checks: what `BinocularEncoder` calls on an environment's observation."""
    scale = as_scale(scale)
    b, _, h, w = pair.shape
    crop = scale.crop
    if h < crop or w < crop:
        raise ValueError(f"images of shape {tuple(pair.shape)} are smaller than the {crop}x{crop} crop of "
                         f"scale {scale.name!r}")
    top, left = (h - crop) // 2, (w - crop) // 2
    # One pyramid call for both eyes: [B, 2, crop, crop] viewed as 2B single-channel images.
    pair = pair[:, :, top : top + crop, left : left + crop]
    reduced = _pyramid_down(pair.reshape(2 * b, 1, crop, crop), scale.levels, scale.centred)
    return _cut(reduced, scale, b, eps)


def reduced_patches(first: Tensor, second: Tensor, scale: Scale | str, *, eps: float = 1e-8) -> Tensor:
    """:func:`extract_patches` from images already at the scale's resolution (no crop, no pyramid).

    For images rendered directly at each scale's resolution
    (``ActiveDepthEnv.stereo_observation(scales=...)``): each is the scale's central ``crop``
    seen on a grid of ``downsample x downsample`` blocks, ``[B, side, side]`` with
    ``side = crop // downsample``. The patch grid, the normalisation and the layout are those of
    :func:`extract_patches`.

    Example:
        >>> reduced_patches(torch.rand(3, 16, 16), torch.rand(3, 16, 16), "coarse").shape
        torch.Size([3, 49, 200])
    """
    _check_pair(first, second)
    return scale_patches(torch.stack((first, second), dim=1), scale, eps=eps)


def scale_patches(pair: Tensor, scale: Scale | str, *, eps: float = 1e-8) -> Tensor:
    """:func:`reduced_patches` of an image pair at the scale's resolution stacked as
    ``[B, 2, side, side]`` (``first`` at index 0), without the checks."""
    scale = as_scale(scale)
    side = scale.side
    if tuple(pair.shape[-2:]) != (side, side):
        raise ValueError(f"images at scale {scale.name!r} must be [B, {side}, {side}] (crop {scale.crop} / "
                         f"downsample {scale.downsample}), got {tuple(pair.shape)}")
    b = pair.shape[0]
    return _cut(pair.reshape(2 * b, 1, side, side), scale, b, eps)


def patch_energy(pair: Tensor, scale: Scale | str) -> Tensor:
    """The energy the coder's normalisation divides out: each image's patches at ``scale``, made
    zero-mean, their mean square per pixel, averaged over the patch grid and the images.

    The coder sees every patch half at unit norm, so a view of little texture (a flat background,
    a blurred region) reaches it as amplified rendering noise; this is how much contrast there
    was to see at each scale. A flat image gives 0 (up to rounding); an image ``a x`` gives
    ``a^2`` times the energy of ``x``.

    Args:
        pair: images at the scale's resolution ``[B, K, side, side]`` (K images per row, e.g. the
            two of a stereo pair; ``ActiveDepthEnv.stereo_observation(scales=...)``), or
            ``[B, side, side]``.
        scale: the scale (its patch grid: size, stride, offset).

    Returns:
        ``[B]``: the mean over the K images and the grid of ``|patch - mean(patch)|^2 / patch_size^2``
        (intensity units squared).

    Example:
        >>> flat = torch.full((2, 2, 16, 16), 0.5)
        >>> patch_energy(flat, "coarse")
        tensor([0., 0.])
        >>> stripes = torch.arange(16.).remainder(2).expand(1, 2, 16, 16)  # 0, 1, 0, 1, ...
        >>> patch_energy(stripes, "coarse")
        tensor([0.2500])
    """
    scale = as_scale(scale)
    side = scale.side
    if pair.dim() == 3:
        pair = pair.unsqueeze(1)
    if pair.dim() != 4 or tuple(pair.shape[-2:]) != (side, side):
        raise ValueError(f"pair at scale {scale.name!r} must be [B, K, {side}, {side}] or [B, {side}, {side}] "
                         f"(crop {scale.crop} / downsample {scale.downsample}), got {tuple(pair.shape)}")
    o, p = scale.offset, scale.patch_size
    crop = pair[..., o:side - o, o:side - o] if o else pair
    tiles = crop.unfold(-2, p, scale.stride).unfold(-2, p, scale.stride)  # [B, K, g, g, p, p]
    halves = tiles.reshape(*pair.shape[:2], -1, p * p)
    centred = halves - halves.mean(dim=-1, keepdim=True)
    return centred.square().mean(dim=-1).mean(dim=(1, 2))


def _cut(reduced: Tensor, scale: Scale, b: int, eps: float) -> Tensor:
    """Patches ``[B, N, 2 P^2]`` of the reduced crops ``[2B, 1, side, side]`` (first images at even rows).

    Without a graph to build, on CPU: one fused kernel (``aectorch::pair_patches``), the same
    arithmetic in one pass instead of about ten of torch's.
    """
    from aectorch.ops.backend import fused_kernels_apply

    if not (torch.is_grad_enabled() and reduced.requires_grad) and fused_kernels_apply(reduced):
        rounding = _ROUNDING_ULPS * torch.finfo(reduced.dtype).eps * scale.patch_size
        return torch.ops.aectorch.pair_patches(reduced.reshape(2 * b, *reduced.shape[-2:]), scale.offset,
                                               scale.patch_size, scale.stride, scale.grid, eps, rounding)
    if scale.offset:  # a centred grid
        o = scale.offset
        reduced = reduced[..., o:scale.side - o, o:scale.side - o]

    p, stride, g = scale.patch_size, scale.stride, scale.grid
    # [2B, 1, side, side] -> [2B, 1, g, g, p, p]: grid row, grid column, pixel row, pixel column.
    tiles = reduced.unfold(2, p, stride).unfold(3, p, stride)
    halves = tiles.reshape(b, 2, g * g, p * p)

    centred = halves - halves.mean(dim=-1, keepdim=True)
    # A second pass removes the first one's rounding (about eps * max|half|), which division by a
    # small contrast would otherwise magnify into a visible non-zero mean in float32.
    centred = centred - centred.mean(dim=-1, keepdim=True)
    norm = torch.linalg.vector_norm(centred, dim=-1, keepdim=True)
    rounding = _ROUNDING_ULPS * torch.finfo(halves.dtype).eps * (p * p) ** 0.5
    flat = norm <= eps + rounding * halves.abs().amax(dim=-1, keepdim=True)
    # Divide by 1 where flat so neither the value nor its gradient ever sees 0 / 0.
    unit = centred / torch.where(flat, torch.ones_like(norm), norm)
    unit = torch.where(flat, torch.zeros_like(unit), unit)

    # [B, 2, N, P^2] -> [B, N, 2, P^2] -> [B, N, 2 P^2]: first image's half first.
    return unit.transpose(1, 2).reshape(b, g * g, 2 * p * p)


class FovealPatches(nn.Module):
    """Module form of :func:`extract_patches` for one fixed scale (no parameters).

    Args:
        scale: a :class:`Scale`, or ``"coarse"`` / ``"fine"``.
        eps: see :func:`extract_patches`.
        check_finite: see :func:`extract_patches`.

    Shape:
        - first, second: :math:`(B, H, W)`.
        - output: :math:`(B, N, 2 P^2)`.

    Example:
        >>> coarse = FovealPatches("coarse")
        >>> coarse(torch.rand(1, 240, 320), torch.rand(1, 240, 320)).shape
        torch.Size([1, 49, 200])
    """

    def __init__(self, scale: Scale | str, *, eps: float = 1e-8, check_finite: bool = True):
        super().__init__()
        self.scale = as_scale(scale)
        self.eps = eps
        self.check_finite = check_finite

    def forward(self, first: Tensor, second: Tensor) -> Tensor:
        return extract_patches(
            first, second, self.scale, eps=self.eps, check_finite=self.check_finite
        )

    def extra_repr(self) -> str:
        s = self.scale
        return (
            f"scale={s.name!r}, crop={s.crop}, downsample={s.downsample}, "
            f"patch_size={s.patch_size}, stride={s.stride}, num_patches={s.num_patches}"
        )
