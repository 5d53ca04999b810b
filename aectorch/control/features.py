"""Online z-scoring of an agent's features: Welford's running moments, merged batch by batch.

Both agents (`NaturalActorCritic`, `PPO`) may see their features as ``(f - mean) / sqrt(var +
eps)`` with running statistics held as buffers (``feature_count``, ``feature_mean``,
``feature_m2``), optionally scaled to a fixed norm. These are the two pure functions they share.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

__all__ = ["merge_moments", "scale_to_norm", "standardize"]


def standardize(features: Tensor, count: Tensor, mean: Tensor, m2: Tensor, eps: float,
                norm: float | None = None, *, out: Tensor | None = None, unscaled: int = 0) -> Tensor:
    """``(features - mean) / sqrt(var + eps)`` with the sample variance ``m2 / (count - 1)`` (1
    before two samples), then, when ``norm`` is given, each row scaled to that Euclidean norm
    (all but its last ``unscaled`` entries: `scale_to_norm`).
    ``out``: the result is written there (it may be ``features`` itself; no gradient).

    Shape:
        features `[..., F]`; count `[]`; mean, m2 `[F]` -> `[..., F]`.

    Example:
        >>> f = torch.tensor([[1.0, 2.0], [3.0, 6.0]])
        >>> count, mean, m2 = merge_moments(torch.zeros((), dtype=torch.int64), torch.zeros(2), torch.zeros(2),
        ...                                 f, torch.ones(2, dtype=torch.bool), lambda t: t)
        >>> count.item(), mean.tolist(), standardize(f, count, mean, m2, 0.0).tolist()
        (2, [2.0, 4.0], [[-0.7071067690849304, -0.7071067690849304], [0.7071067690849304, 0.7071067690849304]])
    """
    n = count.to(features.dtype)
    sample_var = m2 / (n - 1).clamp_min(1)
    var = torch.where(n > 1, sample_var, torch.ones_like(sample_var))
    # The same operations as ``(features - mean) / sqrt(var + eps)`` then ``x * (norm / length)``,
    # the division and the product in place on the difference (a new tensor) when no gradient
    # flows: one large temporary instead of three, the same bits.
    inplace = not (torch.is_grad_enabled() and (features.requires_grad or mean.requires_grad or m2.requires_grad))
    if out is not None and not inplace:
        raise RuntimeError("standardize: out= with a gradient")
    x = features - mean if out is None else torch.sub(features, mean, out=out)
    x = x.div_(torch.sqrt(var + eps)) if inplace else x / torch.sqrt(var + eps)
    return x if norm is None else _scale_to_norm(x, norm, inplace, unscaled)


def scale_to_norm(x: Tensor, norm: float, unscaled: int = 0) -> Tensor:
    """Each row of ``x`` `[..., F]` scaled to Euclidean norm ``norm`` (a zero row stays zero);
    ``unscaled`` > 0: the first ``F - unscaled`` entries scaled to it, the last ``unscaled``
    (a cue's proprioception) left as they are.

    Example:
        >>> scale_to_norm(torch.tensor([[3.0, 4.0, 5.0]]), 1.0, unscaled=1).tolist()
        [[0.6000000238418579, 0.800000011920929, 5.0]]
    """
    return _scale_to_norm(x, norm, False, unscaled)


def _scale_to_norm(x: Tensor, norm: float, inplace: bool, unscaled: int = 0) -> Tensor:
    """`scale_to_norm`, in place on ``x`` when ``inplace``."""
    if unscaled >= x.shape[-1]:  # nothing to scale (an agent that senses its proprioception alone)
        return x
    head = x[..., : x.shape[-1] - unscaled] if unscaled else x
    scale = norm / torch.linalg.vector_norm(head, dim=-1, keepdim=True).clamp_min(torch.finfo(x.dtype).tiny)
    if not unscaled:
        return x.mul_(scale) if inplace else x * scale
    if inplace:
        head.mul_(scale)
        return x
    return torch.cat((head * scale, x[..., x.shape[-1] - unscaled:]), -1)


def merge_moments(count: Tensor, mean: Tensor, m2: Tensor, f: Tensor, mask: Tensor | None,
                  reduce: Callable[[Tensor], Tensor], window: int | None = None, *,
                  workspace: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Welford count, mean and M2 with the rows of ``f`` `[B, F]` selected by ``mask`` `[B]` merged in
    (Chan's rule); ``reduce`` sums over the processes that share the batch (identity for one).
    ``window``: the old statistics weigh at most ``window - n_batch`` samples (``None``: all).
    ``mask=None``: every row (the same numbers as an all-True mask, without its products).
    ``workspace``: a tensor of ``f``'s shape and dtype to hold the squared deviations (no gradient;
    else a new one)."""
    if mask is None:
        # Multiplying by a mask of ones changes no bit: the same sums, one pass less each.
        m = None
        nb = reduce(torch.tensor(float(f.shape[0]), dtype=f.dtype, device=f.device))
        rows = torch.tensor(f.shape[0], dtype=torch.int64, device=f.device)
    else:
        m = mask.to(f.dtype)[:, None]
        nb = reduce(m.sum())
        rows = mask.sum()
    n = count.to(f.dtype)
    m2_old = m2
    if window is not None:  # the old statistics weigh at most `window - nb` samples
        n_eff = torch.minimum(n, (window - nb).clamp_min(1))
        m2_old = m2_old * (n_eff / n.clamp_min(1))
        n = n_eff
    total = (n + nb).clamp_min(1)
    mean_b = reduce((f if m is None else m * f).sum(0)) / nb.clamp_min(1)
    if torch.is_grad_enabled() and (f.requires_grad or mean_b.requires_grad):
        deviation = (f - mean_b).square()
        deviation = deviation if m is None else m * deviation
    else:  # the same operations, in place on one temporary
        deviation = (f - mean_b if workspace is None else torch.sub(f, mean_b, out=workspace)).square_()
        deviation = deviation if m is None else deviation.mul_(m)
    m2_b = reduce(deviation.sum(0))
    diff = mean_b - mean
    new_mean = mean + diff * (nb / total)
    new_m2 = m2_old + m2_b + diff.square() * (n * nb / total)
    if window is None:
        new_count = count + reduce(rows)
    else:  # the weight of the statistics, at most `window`
        new_count = n.round().to(count.dtype) + reduce(rows)
    return new_count, new_mean, new_m2
