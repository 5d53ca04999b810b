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
                norm: float | None = None) -> Tensor:
    """``(features - mean) / sqrt(var + eps)`` with the sample variance ``m2 / (count - 1)`` (1
    before two samples), then, when ``norm`` is given, each row scaled to that Euclidean norm.

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
    x = (features - mean) / torch.sqrt(var + eps)
    return x if norm is None else scale_to_norm(x, norm)


def scale_to_norm(x: Tensor, norm: float) -> Tensor:
    """Each row of ``x`` `[..., F]` scaled to Euclidean norm ``norm`` (a zero row stays zero)."""
    length = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    return x * (norm / length.clamp_min(torch.finfo(x.dtype).tiny))


def merge_moments(count: Tensor, mean: Tensor, m2: Tensor, f: Tensor, mask: Tensor,
                  reduce: Callable[[Tensor], Tensor], window: int | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Welford count, mean and M2 with the rows of ``f`` `[B, F]` selected by ``mask`` `[B]` merged in
    (Chan's rule); ``reduce`` sums over the processes that share the batch (identity for one).
    ``window``: the old statistics weigh at most ``window - n_batch`` samples (``None``: all)."""
    m = mask.to(f.dtype)[:, None]
    nb = reduce(m.sum())
    n = count.to(f.dtype)
    m2_old = m2
    if window is not None:  # the old statistics weigh at most `window - nb` samples
        n_eff = torch.minimum(n, (window - nb).clamp_min(1))
        m2_old = m2_old * (n_eff / n.clamp_min(1))
        n = n_eff
    total = (n + nb).clamp_min(1)
    mean_b = reduce((m * f).sum(0)) / nb.clamp_min(1)
    m2_b = reduce((m * (f - mean_b).square()).sum(0))
    diff = mean_b - mean
    new_mean = mean + diff * (nb / total)
    new_m2 = m2_old + m2_b + diff.square() * (n * nb / total)
    if window is None:
        new_count = count + reduce(mask.sum())
    else:  # the weight of the statistics, at most `window`
        new_count = n.round().to(count.dtype) + reduce(mask.sum())
    return new_count, new_mean, new_m2
