"""Batched least-squares fits of a 2-D Gabor to images, in torch: every image at once.

The lineage reads a binocular atom's receptive field as a Gabor fitted to each eye's half
(Klimmasch et al. 2021, eLife 10:e56212); :func:`aectorch.coding.readouts.gabor_binocularity`
uses :func:`fit_gabor` for its index. The fit is Levenberg-Marquardt with an analytic Jacobian, one
8 x 8 solve per image and step, from starts read off the periodogram and the energy's moments.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from aectorch._checks import check_int

__all__ = ["GABOR_PARAMETERS", "GaborFit", "fit_gabor"]


#: The columns of `GaborFit.parameters`, the 2-D Gabor of :func:`fit_gabor`.
GABOR_PARAMETERS = ("amplitude", "x0", "y0", "theta", "frequency", "phase", "sigma_x", "sigma_y")


class GaborFit(NamedTuple):
    """What :func:`fit_gabor` returns, per image.

    Attributes:
        fitted: the fitted Gabors with their means removed, ``[M, p, p]``.
        parameters: ``[M, 8]``, the columns of :data:`GABOR_PARAMETERS`: amplitude (> 0), centre
            ``x0, y0`` (pixels from the patch's centre; x along columns, y along rows, downward),
            ``theta`` (the carrier's wave vector from the x axis towards y, in [0, pi) rad),
            ``frequency`` (cycles per pixel, >= 0), ``phase`` (rad, in [-pi, pi)) and the envelope's
            ``sigma_x`` (along the wave vector) and ``sigma_y`` (along the stripes), pixels.
        residual: ``||image - fitted||^2 / ||image||^2`` (1 for a zero image), ``[M]``.
    """

    fitted: Tensor
    parameters: Tensor
    residual: Tensor


def _gabor(params: Tensor, x: Tensor, y: Tensor, jacobian: bool = False):
    """The Gabors of ``params [M, 8]`` (``log sigma`` in the last two columns) on the grid ``x, y
    [p^2]``, with their means removed, ``[M, p^2]``, and (``jacobian``) their Jacobian ``[M, p^2, 8]``."""
    a, x0, y0, theta, f, phi, log_sx, log_sy = (c.unsqueeze(-1) for c in params.unbind(-1))
    cos_t, sin_t = torch.cos(theta), torch.sin(theta)
    dx, dy = x - x0, y - y0
    u, v = dx * cos_t + dy * sin_t, -dx * sin_t + dy * cos_t  # along the wave vector, along the stripes
    isx2, isy2 = torch.exp(-2 * log_sx), torch.exp(-2 * log_sy)
    envelope = torch.exp(-0.5 * (u.square() * isx2 + v.square() * isy2))
    carrier = 2 * math.pi * f * u + phi
    ec, es = envelope * torch.cos(carrier), envelope * torch.sin(carrier)
    model = a * ec
    if not jacobian:
        return model - model.mean(-1, keepdim=True)
    d_u = a * (-ec * u * isx2 - es * 2 * math.pi * f)  # d model / d u
    d_v = -a * ec * v * isy2
    jac = torch.stack([ec, -d_u * cos_t + d_v * sin_t, -d_u * sin_t - d_v * cos_t, d_u * v - d_v * u,
                       -a * es * 2 * math.pi * u, -a * es, model * u.square() * isx2, model * v.square() * isy2], -1)
    return model - model.mean(-1, keepdim=True), jac - jac.mean(-2, keepdim=True)


def _gabor_start(images: Tensor, x: Tensor, y: Tensor, widths: tuple[float, ...]) -> Tensor:
    """Starting parameters ``[R, M, 8]``, one set per envelope width in ``widths`` (times the
    energy's spread): the carrier from the peak of the zero-padded periodogram, the centre from the
    energy's centroid, amplitude and phase from linear least squares given the rest."""
    m, p = images.shape[0], images.shape[-1]
    n = max(4 * p, 32)
    power = torch.fft.fft2(images, s=(n, n)).abs().square().flatten(-2)
    freqs = torch.fft.fftfreq(n, dtype=images.dtype, device=images.device)
    peak = power.argmax(-1)
    fy, fx = freqs[peak // n], freqs[peak % n]
    energy = images.flatten(-2).square()
    weight = energy / energy.sum(-1, keepdim=True).clamp_min(torch.finfo(images.dtype).tiny)
    x0, y0 = (weight * x).sum(-1), (weight * y).sum(-1)
    spread = ((weight * ((x - x0[:, None]).square() + (y - y0[:, None]).square())).sum(-1)).sqrt().clamp(0.5, p)
    starts = []
    for width in widths:
        log_s = torch.log(spread * width)
        params = torch.stack([torch.ones_like(x0), x0, y0, torch.atan2(fy, fx), torch.hypot(fx, fy),
                              torch.zeros_like(x0), log_s, log_s], -1)
        cos_part = _gabor(params, x, y)
        sin_part = _gabor(params + torch.tensor([0, 0, 0, 0, 0, math.pi / 2, 0, 0], dtype=params.dtype,
                                                device=params.device), x, y)
        basis = torch.stack([cos_part, sin_part], -1)  # [M, p^2, 2]
        coef = torch.linalg.lstsq(basis, images.reshape(m, -1, 1)).solution.squeeze(-1)  # a cos(phi), -a sin(phi)
        params[:, 0], params[:, 5] = torch.hypot(coef[:, 0], coef[:, 1]), torch.atan2(-coef[:, 1], coef[:, 0])
        starts.append(params)
    return torch.stack(starts)


def _levenberg_marquardt(params: Tensor, target: Tensor, x: Tensor, y: Tensor, steps: int, bounds: Tensor) -> Tensor:
    """``steps`` batched Levenberg-Marquardt steps from ``params [M, 8]`` towards ``target [M, p^2]``,
    each image with its own damping; a step is kept only where it lowers that image's error."""
    damping = torch.full_like(params[:, 0], 1e-2)
    model = _gabor(params, x, y)
    cost = (model - target).square().sum(-1)
    eye = torch.eye(params.shape[-1], dtype=params.dtype, device=params.device)
    for _ in range(steps):
        model, jac = _gabor(params, x, y, jacobian=True)
        hess = jac.transpose(-1, -2) @ jac
        grad = (jac.transpose(-1, -2) @ (model - target).unsqueeze(-1)).squeeze(-1)
        scaled = damping[:, None, None] * (hess.diagonal(dim1=-2, dim2=-1).unsqueeze(-1) * eye + 1e-9 * eye)
        step = torch.linalg.solve(hess + scaled, -grad.unsqueeze(-1)).squeeze(-1)
        trial = params + step
        trial[:, 6:] = trial[:, 6:].clamp(bounds[0], bounds[1])
        trial_cost = (_gabor(trial, x, y) - target).square().sum(-1)
        better = trial_cost < cost
        params = torch.where(better[:, None], trial, params)
        cost = torch.where(better, trial_cost, cost)
        damping = torch.where(better, damping / 3, damping * 3).clamp(1e-7, 1e7)
    return params


def _canonical(params: Tensor) -> Tensor:
    """One of the equivalent parameter sets: amplitude and frequency >= 0, theta in [0, pi), phase in
    [-pi, pi); sigmas in pixels."""
    a, x0, y0, theta, f, phi, log_sx, log_sy = params.unbind(-1)
    phi = torch.where(a < 0, phi + math.pi, phi)
    theta = torch.where(f < 0, theta + math.pi, theta)  # (f, theta, phi) ~ (-f, theta + pi, phi)
    flip = torch.remainder(theta, 2 * math.pi) >= math.pi  # (theta, phi) ~ (theta - pi, -phi)
    phi = torch.where(flip, -phi, phi)
    theta = torch.remainder(theta, math.pi)
    phi = torch.remainder(phi + math.pi, 2 * math.pi) - math.pi
    return torch.stack([a.abs(), x0, y0, theta, f.abs(), phi, log_sx.exp(), log_sy.exp()], -1)


def fit_gabor(images: Tensor, steps: int = 60, widths: tuple[float, ...] = (0.5, 1.0)) -> GaborFit:
    """Least-squares fits of a 2-D Gabor to each image, all images at once.

    The model is ``A exp(-u^2 / (2 sx^2) - v^2 / (2 sy^2)) cos(2 pi f u + phase)`` with ``u, v`` the
    pixel's offset from the centre ``(x0, y0)`` along and across the wave vector at angle
    ``theta``, with its mean over the patch removed (the images are zero-mean halves,
    :func:`atom_halves`). Each fit starts from the periodogram's peak (carrier), the energy's
    centroid and spread (envelope) and the linear least-squares amplitude and phase, once per
    envelope width in ``widths``; ``steps`` batched Levenberg-Marquardt steps (analytic Jacobian,
    one 8 x 8 solve per image and step) refine every start and the best fit is kept.

    Args:
        images: ``[M, p, p]``, floating point (computed in their dtype, on their device).
        steps: Levenberg-Marquardt steps per start (>= 1).
        widths: the starting envelope widths, as multiples of the energy's spread.

    Returns:
        A :class:`GaborFit`: the fitted images, the parameters (:data:`GABOR_PARAMETERS`) and the
        relative residual per image.

    Example:
        >>> y, x = torch.meshgrid(torch.arange(10.0) - 4.5, torch.arange(10.0) - 4.5, indexing="ij")
        >>> gabor = torch.exp(-(x ** 2 + y ** 2) / 8) * torch.cos(2 * math.pi * 0.2 * x)
        >>> fit = fit_gabor((gabor - gabor.mean())[None].double())
        >>> fit.residual < 1e-6, fit.parameters[0, 4].item().__round__(3)
        (tensor([True]), 0.2)
    """
    if not isinstance(images, Tensor) or images.ndim != 3 or images.shape[-1] != images.shape[-2] \
            or not images.is_floating_point():
        raise ValueError(f"images must be a floating-point [M, p, p] tensor, got {tuple(getattr(images, 'shape', ()))}")
    check_int(steps, "steps")
    m, p = images.shape[0], images.shape[-1]
    images = images.detach()
    coords = torch.arange(p, dtype=images.dtype, device=images.device) - (p - 1) / 2
    y, x = (c.reshape(-1) for c in torch.meshgrid(coords, coords, indexing="ij"))
    target = images.reshape(m, -1)
    bounds = torch.tensor([math.log(0.3), math.log(2.0 * p)], dtype=images.dtype)
    starts = _gabor_start(images, x, y, tuple(widths))  # [R, M, 8]
    fits = _levenberg_marquardt(starts.flatten(0, 1), target.repeat(len(widths), 1), x, y, steps, bounds)
    errors = (_gabor(fits, x, y) - target.repeat(len(widths), 1)).square().sum(-1).reshape(len(widths), m)
    best = fits.reshape(len(widths), m, -1)[errors.argmin(0), torch.arange(m, device=images.device)]
    fitted = _gabor(best, x, y)
    norm = target.square().sum(-1)
    residual = torch.where(norm > 0, (target - fitted).square().sum(-1) / norm.clamp_min(torch.finfo(norm.dtype).tiny),
                           torch.ones_like(norm))
    return GaborFit(fitted.reshape(m, p, p), _canonical(best), residual)
