"""How the depth error splits between the eyes and the read-out, on the same eye movements.

The eye movements of greedy, frozen trials do not depend on the depth MLP, so read-outs of one
set of trials' final eye movements ``q`` (q1..q4, the MLP's inputs) compare directly:
fitted read-outs (the MLP, refitted MLPs) given as predictions, and decoders with the head's exact
geometry (`ActiveDepthEnv.ideal_q_deg`) added here:

- ``vergence``, ``pursuit``, ``all four``: the distance on a grid whose perfect ``q`` is nearest
  to the trial's, in the L1 distance weighted by each input's robust error scale (1.4826 x the
  median absolute deviation of ``q - q_ideal(true distance)`` over the trials), from the two
  vergence inputs, the two pursuit inputs, or all four. It ignores the systematic part of the
  eyes' errors, which a fitted read-out can learn;
- ``Gaussian floor``: not a read-out but the mean absolute depth error of the best unbiased one
  if the four inputs' errors were independent, Gaussian, of those robust scales and without bias:
  ``sqrt(2 / pi) / ||(d q_ideal / d distance) / scale||`` at each trial's distance.

:func:`depth_tolerance` is geometry only: the eye error that moves the exact geometry's depth by
0.05 m at each distance.

Example:
    >>> import torch
    >>> from aectorch.sim import ActiveDepthEnv
    >>> env = ActiveDepthEnv(1, textures=torch.rand(1, 32, 32), dtype=torch.float64)
    >>> row = depth_tolerance(env, [1.0])[0]
    >>> 0.1 < row["q2"] < 0.25   # vergence: about 0.17 deg moves 1 m by 5 cm
    True
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import torch
from torch import Tensor

__all__ = ["DECODERS", "decode_depth", "depth_readouts", "depth_tolerance"]

#: The exact-geometry decoders: the columns of ``q`` each reads.
DECODERS = {"vergence": (1, 3), "pursuit": (0, 2), "all four": (0, 1, 2, 3)}


def decode_depth(q: Tensor, grid_m: Tensor, ideal: Tensor, scale: Tensor, inputs: Sequence[int],
                 chunk: int = 64) -> Tensor:
    """The grid distance ``[N]`` whose ideal q (``ideal[G, 4]`` at ``grid_m[G]``) is nearest to each
    ``q[N, 4]`` in the L1 distance over the columns ``inputs``, each divided by ``scale[4]``."""
    cols = list(inputs)
    out = []
    for part in q.split(chunk):
        cost = ((part[:, None, cols] - ideal[None, :, cols]).abs() / scale[cols]).sum(-1)  # [n, G]
        out.append(grid_m[cost.argmin(-1)])
    return torch.cat(out)


def _slope(env, distance_m: Tensor) -> Tensor:
    """d q_ideal / d distance ``[N, 4]``, degrees per metre (central differences)."""
    return (env.ideal_q_deg(distance_m + 1e-4) - env.ideal_q_deg(distance_m - 1e-4)) / 2e-4


def depth_readouts(trials: Mapping[str, Tensor], env, grid_m: Tensor, fitted: Mapping[str, Tensor]) -> dict:
    """Depth MAE (m) of each read-out of the same trials, overall and per distance.

    Args:
        trials: `run_trials`' output (``q_deg [N, 4]``, ``distance_m [N]``).
        env: an `ActiveDepthEnv` of the trials' geometry (its ``ideal_q_deg``), float64.
        grid_m: the candidate distances of the geometric decoders ``[G]`` (metres).
        fitted: a name per fitted read-out, mapped to its depth predictions ``[N]``.

    Returns:
        ``trials``, the inputs' robust error scales and medians (``eye_error_scale_deg``,
        ``eye_error_median_deg``), ``depth_mae_m`` per read-out (the fitted ones, then
        `DECODERS` and ``Gaussian floor``) and ``per_distance`` rows.
    """
    q = trials["q_deg"].double()
    d = trials["distance_m"].double()
    if q.dim() != 2 or q.shape[-1] != 4 or d.shape != q.shape[:1]:
        raise ValueError(f"trials must hold q_deg [N, 4] and distance_m [N], got {tuple(q.shape)} and "
                         f"{tuple(d.shape)}")
    ideal = env.ideal_q_deg(grid_m)
    residual = q - env.ideal_q_deg(d)
    centred = residual - residual.median(0).values
    scale = (1.4826 * centred.abs().median(0).values).clamp_min(1e-4)
    errors = {name: (p.double() - d).abs() for name, p in fitted.items()}
    for name, inputs in DECODERS.items():
        errors[name] = (decode_depth(q, grid_m, ideal, scale, inputs) - d).abs()
    # Least squares over the four inputs with independent Gaussian errors of these scales, and
    # no bias: the depth error's sd is 1 / ||slope / scale||, its mean absolute value sqrt(2/pi) sd.
    errors["Gaussian floor"] = math.sqrt(2 / math.pi) / (_slope(env, d) / scale).norm(dim=-1)
    distances = sorted({round(float(x), 4) for x in d})
    return {
        "trials": int(d.numel()),
        "eye_error_scale_deg": dict(zip(("q1", "q2", "q3", "q4"), scale.tolist())),
        "eye_error_median_deg": dict(zip(("q1", "q2", "q3", "q4"), residual.median(0).values.tolist())),
        "depth_mae_m": {k: float(v.mean()) for k, v in errors.items()},
        "per_distance": [{"distance_m": x, **{k: float(v[(d - x).abs() < 1e-6].mean()) for k, v in errors.items()}}
                         for x in distances],
    }


def depth_tolerance(env, distances_m: Sequence[float], depth_m: float = 0.05) -> list[dict]:
    """Per distance: the error (deg) in one input of q alone (``q1``..``q4``), and in all four alike
    (combined by least squares), that moves the exact geometry's depth by ``depth_m``."""
    if not depth_m > 0:
        raise ValueError(f"depth_m must be > 0 (metres), got {depth_m}")
    d = torch.tensor([float(x) for x in distances_m], dtype=torch.float64)
    slope = _slope(env, d)
    rows = []
    for x, s in zip(d.tolist(), slope):
        row = {"distance_m": x}
        row.update({f"q{j + 1}": depth_m * float(s[j].abs()) for j in range(4)})
        row["all four alike"] = depth_m * float(s.norm())  # least squares over four equal errors
        rows.append(row)
    return rows
