"""Procedural textures: 1/f^alpha random-phase noise and dead leaves, from explicit generators.

The amplitude spectrum of natural images falls roughly as 1/f, so `pink_noise_images` stands in
for the paper's photographs (`TextureBank.procedural`, `TextureBank.default`); `dead_leaves_image`
adds the occlusion edges and flat regions of natural scenes (`TextureBank.dead_leaves`).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from aectorch._checks import check_int, is_real

__all__ = ["dead_leaves_image", "pink_noise_images"]


def pink_noise_images(
    batch: int,
    height: int,
    width: int,
    *,
    alpha: float = 1.1,
    generator: torch.Generator,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Tensor:
    """Random textures with a 1/f^alpha amplitude spectrum and uniform random phase.

    The amplitude of every non-zero spatial frequency f (cycles per pixel, radial) is exactly
    ``f ** -alpha`` before the final rescaling; the phases are i.i.d. uniform in [0, 2 pi).
    Each image is then rescaled affinely to span [0, 1], which leaves the spectrum's shape
    (all bins but the mean) unchanged. The textures are periodic (they come from an inverse FFT).

    Args:
        batch, height, width: output shape (each >= 1).
        alpha: spectral exponent of the amplitude (natural images: about 1; power falls as
            f^(-2 alpha)).
        generator: source of the random phases; its device is used when `device` is None.
        dtype: float32 or float64.
        device: device of the output (must match the generator's device type).

    Returns:
        Grey images in [0, 1], min 0 and max 1 per image.

    Shape:
        output: `[batch, height, width]`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = pink_noise_images(2, 240, 336, generator=g)
        >>> x.shape, float(x.amin()), float(x.amax())
        (torch.Size([2, 240, 336]), 0.0, 1.0)
    """
    for name, value in (("batch", batch), ("height", height), ("width", width)):
        check_int(value, name)
    if not math.isfinite(alpha):
        raise ValueError(f"alpha must be finite, got {alpha!r}")
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    device = torch.device(device) if device is not None else generator.device

    fy = torch.fft.fftfreq(height, dtype=dtype, device=device)
    fx = torch.fft.rfftfreq(width, dtype=dtype, device=device)
    radius = torch.sqrt(fy[:, None].square() + fx[None, :].square())
    # The mean (f = 0) gets amplitude 0: it is set by the rescaling anyway.
    amplitude = torch.where(radius > 0, radius.clamp_min(1e-12).pow(-alpha), torch.zeros_like(radius))
    phase = torch.rand(
        (batch, height, width // 2 + 1), generator=generator, dtype=dtype, device=device
    ) * (2 * math.pi)
    images = torch.fft.irfft2(torch.polar(amplitude.expand_as(phase), phase), s=(height, width))

    low = images.amin(dim=(-2, -1), keepdim=True)
    span = (images.amax(dim=(-2, -1), keepdim=True) - low).clamp_min(torch.finfo(dtype).tiny)
    return ((images - low) / span).clamp_(0.0, 1.0)


def dead_leaves_image(
    height: int,
    width: int,
    *,
    generator: torch.Generator,
    radius_px: tuple[float, float] = (2.0, 96.0),
    leaves: int | None = None,
    inner_contrast: float = 0.15,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """A dead-leaves texture (Lee, Mumford and Huang 2001): opaque discs of uniform random grey
    fall on the image one after the other, each hiding what lies under it.

    The radii follow the scale-invariant density ``r ** -3`` between ``radius_px``'s bounds, so
    the image has natural images' 1/f-like spectrum together with what Gaussian 1/f noise lacks:
    sharp occluding edges, flat regions and non-Gaussian statistics. Each disc carries a faint
    1/f texture (``inner_contrast`` of a `pink_noise_images` field), so that no region is
    exactly flat. The result spans [0, 1].

    Args:
        height, width: the image's size (each >= 2).
        generator: the source of every random draw (CPU).
        radius_px: the smallest and largest radius, pixels (0 < low <= high).
        leaves: how many discs fall (default: enough to cover the image about 5 times over
            on average, so that almost none of the first layer shows).
        inner_contrast: the faint texture's share of the grey range (>= 0).
        dtype: float32 or float64.

    Example:
        >>> x = dead_leaves_image(64, 64, generator=torch.Generator().manual_seed(0))
        >>> x.shape, float(x.amin()) >= 0, float(x.amax()) <= 1
        (torch.Size([64, 64]), True, True)
    """
    check_int(height, "height", 2)
    check_int(width, "width", 2)
    low, high = (float(r) for r in radius_px)
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
        raise ValueError(f"radius_px must be (low, high) with 0 < low <= high, got {radius_px!r}")
    if not (is_real(inner_contrast) and inner_contrast >= 0):
        raise ValueError(f"inner_contrast must be a number >= 0, got {inner_contrast!r}")
    if leaves is None:  # the mean disc area under r^-3 on [low, high]: 2 pi ln(high/low) / (low^-2 - high^-2)
        area = 2 * math.pi * math.log(high / low) / (low ** -2 - high ** -2) if high > low else math.pi * low ** 2
        leaves = max(1, math.ceil(5 * height * width / area))
    check_int(leaves, "leaves", 1)
    u = torch.rand(leaves, generator=generator, dtype=torch.float64)
    radii = (low ** -2 - u * (low ** -2 - high ** -2)) ** -0.5  # inverse CDF of the r^-3 density
    centres_y = torch.rand(leaves, generator=generator, dtype=torch.float64) * height
    centres_x = torch.rand(leaves, generator=generator, dtype=torch.float64) * width
    greys = torch.rand(leaves, generator=generator, dtype=torch.float64)
    # numpy for the loop over the discs: thousands of small in-place writes.
    canvas = np.full((height, width), 0.5)
    ys = np.arange(height)[:, None] + 0.5
    xs = np.arange(width)[None, :] + 0.5
    for r, cy, cx, grey in zip(radii.tolist(), centres_y.tolist(), centres_x.tolist(), greys.tolist()):
        top, bottom = max(0, int(cy - r)), min(height, int(cy + r) + 1)
        left, right = max(0, int(cx - r)), min(width, int(cx + r) + 1)
        if top >= bottom or left >= right:
            continue
        inside = (ys[top:bottom] - cy) ** 2 + (xs[:, left:right] - cx) ** 2 <= r * r
        canvas[top:bottom, left:right][inside] = grey
    image = torch.from_numpy(canvas)
    if inner_contrast > 0:
        texture = pink_noise_images(1, height, width, generator=generator, dtype=torch.float64)[0]
        image = (1 - inner_contrast) * image + inner_contrast * texture
    low_value, high_value = image.amin(), image.amax()
    return ((image - low_value) / (high_value - low_value).clamp_min(1e-12)).to(dtype)
