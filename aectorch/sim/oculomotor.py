"""The oculomotor range: where the eyes can point, inside the HOAP-3's joint limits.

The URDF lets each eye pan +-45 degrees on its own (``left_eye_pan``, ``right_eye_pan``), so the
two axes could diverge by up to 90 degrees. Human eyes cannot: they converge to a near point of
about 8-10 cm and diverge only a few degrees past parallel (fusional divergence at distance,
about 4-8 prism dioptres, 2-4 degrees). A learner whose coding reward is flat (a view with little
texture) can otherwise drift its eyes apart without bound: one trial of the default learner ended
with the eyes 12 degrees past parallel.

:class:`ActiveDepthEnv` keeps the eyes within an **oculomotor range**: each eye's pan within
``pan_range_deg`` and the vergence (right pan minus left pan; positive converging) within
``vergence_range_deg``, after every movement, in both renderers (it acts on the pans, before
anything is rendered). The left (dominant) eye is clamped to its pan range first; the right eye
then to its pan range and to the vergence range around the left eye. The vergence range must hold
0 (parallel, where every fixation starts), so both can always be met. The default,
:data:`PAN_RANGE_DEG` and :data:`VERGENCE_RANGE_DEG`: pans +-45 degrees (the URDF's limits, about
the human oculomotor range) and vergence from 2 degrees of divergence to 40 degrees of
convergence (a near point of 8.2 cm for the HOAP-3's 6 cm baseline).
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

__all__ = ["PAN_RANGE_DEG", "VERGENCE_RANGE_DEG", "check_oculomotor_range", "clamp_eyes", "urdf_pan_limits_deg"]

#: Each eye's pan range by default, degrees: the HOAP-3 URDF's eye pan limits.
PAN_RANGE_DEG = (-45.0, 45.0)
#: The vergence range by default, degrees: 2 degrees past parallel to 40 degrees converged.
VERGENCE_RANGE_DEG = (-2.0, 40.0)


@functools.lru_cache(maxsize=1)
def urdf_pan_limits_deg() -> tuple[float, float]:
    """The pan limits ``(low, high)`` in degrees that the default HOAP-3 URDF gives both eyes."""
    from aectorch.sim.hoap3 import HOAP3Head

    limits = HOAP3Head().limits_deg
    low = max(limits["left_eye_pan"][0], limits["right_eye_pan"][0])
    high = min(limits["left_eye_pan"][1], limits["right_eye_pan"][1])
    return float(low), float(high)


def _pair(value, name: str) -> tuple[float, float]:
    try:
        low, high = value
        pair = (float(low), float(high))
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (low, high) pair of degrees, got {value!r}") from None
    if any(isinstance(v, bool) for v in (low, high)) or not all(math.isfinite(v) for v in pair) or pair[0] > pair[1]:
        raise ValueError(f"{name} must be two finite numbers with low <= high (degrees), got {value!r}")
    return pair


def check_oculomotor_range(pan_range_deg, vergence_range_deg, *, pan_limits_deg: tuple[float, float] | None = None,
                           prefix: str = "") -> tuple[tuple[float, float], tuple[float, float]]:
    """The two ranges as ``(low, high)`` float pairs, else ``ValueError`` naming the argument.

    Args:
        pan_range_deg: each eye's pan range, within ``pan_limits_deg``.
        vergence_range_deg: the vergence range; it must hold 0 (parallel, the start state).
        pan_limits_deg: the joint limits the pan range must lie within (default the HOAP-3
            URDF's, :func:`urdf_pan_limits_deg`).
        prefix: put before the names in messages (``"env."`` for the experiment's config keys).

    Example:
        >>> check_oculomotor_range([-30, 30], [-2, 40])
        ((-30.0, 30.0), (-2.0, 40.0))
        >>> check_oculomotor_range([-60, 30], [-2, 40])
        Traceback (most recent call last):
        ...
        ValueError: pan_range_deg must lie within the HOAP-3's eye pan limits (-45, 45) degrees, got [-60, 30]
    """
    pan = _pair(pan_range_deg, f"{prefix}pan_range_deg")
    vergence = _pair(vergence_range_deg, f"{prefix}vergence_range_deg")
    low, high = urdf_pan_limits_deg() if pan_limits_deg is None else pan_limits_deg
    if pan[0] < low - 1e-9 or pan[1] > high + 1e-9:
        raise ValueError(f"{prefix}pan_range_deg must lie within the HOAP-3's eye pan limits ({low:g}, {high:g}) "
                         f"degrees, got {pan_range_deg!r}")
    if not vergence[0] <= 0.0 <= vergence[1]:
        raise ValueError(f"{prefix}vergence_range_deg must hold 0 (parallel eyes, where every fixation starts): "
                         f"low <= 0 <= high, got {vergence_range_deg!r}")
    if vergence[1] - vergence[0] <= 0.0:
        raise ValueError(f"{prefix}vergence_range_deg must be wider than 0 degrees, got {vergence_range_deg!r}")
    return pan, vergence


def clamp_eyes(pan_deg: Tensor, pan_range_deg: tuple[float, float], vergence_range_deg: tuple[float, float]) -> Tensor:
    """Eye pans ``[B, 2]`` (left, right; degrees) brought within the oculomotor range.

    The left eye is clamped to ``pan_range_deg``; the right eye to ``pan_range_deg`` and to
    ``left + vergence_range_deg``. With the vergence range holding 0, the result meets both.

    Shape:
        - pan_deg: :math:`(B, 2)`; output: :math:`(B, 2)`, same dtype and device.

    Example:
        >>> clamp_eyes(torch.tensor([[50.0, 30.0], [1.0, -11.0], [0.0, 1.5]]), (-45.0, 45.0), (-2.0, 40.0))
        tensor([[45.0000, 43.0000],
                [ 1.0000, -1.0000],
                [ 0.0000,  1.5000]])
    """
    if pan_deg.dim() != 2 or pan_deg.shape[1] != 2:
        raise ValueError(f"pan_deg must have shape [B, 2], got shape {list(pan_deg.shape)}")
    left = pan_deg[:, 0].clamp(*pan_range_deg)
    low = (left + vergence_range_deg[0]).clamp_min(pan_range_deg[0])
    high = (left + vergence_range_deg[1]).clamp_max(pan_range_deg[1])
    right = torch.minimum(torch.maximum(pan_deg[:, 1], low), high)
    return torch.stack((left, right), dim=-1)
