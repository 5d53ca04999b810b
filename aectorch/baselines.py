"""A classical matcher: the accuracy anchor every learner's result is read against.

`Matcher` drives the same environment, protocol and trial loop as a `JointLearner`
(`aectorch.evaluation.evaluate` and `run_trials` take it in the learner's place), but it learns
nothing: at every step it estimates, for each cue, the horizontal displacement between the two
images of the cue's pair by normalised cross-correlation (NCC), searched coarse-to-fine over the
same foveal scales the coder reads (each scale's search centred on the coarser scale's estimate),
with a parabola through the finest scale's peak for the sub-pixel part. The increment that
cancels the displacement is then taken as it is (``actions_deg=None``: any increment) or rounded
to the nearest action of the learner's action set (the same choices the policy has).

Motion parallax (left eye before and after the body shift) gives the pursuit error, stereo (left
and right eye) the vergence error. The matcher has no depth read-out: its trials' depth errors are
NaN.

Example:
    >>> import torch
    >>> from aectorch.evaluation import run_trials
    >>> from aectorch.sim import TrialProtocol
    >>> matcher = Matcher()
    >>> out = run_trials(matcher, torch.rand(2, 64, 64), distances_m=[1.0],
    ...                  protocol=TrialProtocol(fixation_iterations=3))
    >>> sorted(out)[:3], out["vergence_deg"].shape
    (['depth_error_m', 'distance_m', 'pursuit_deg'], torch.Size([2, 2]))
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor, nn

from aectorch.coding.patches import DEFAULT_SCALES, as_scale
from aectorch.control import DEFAULT_ACTIONS_DEG
from aectorch.framework.joint import IterationRecord
from aectorch.sim.camera import PinholeCamera

__all__ = ["Matcher", "ncc_displacement_px"]

#: Each scale's search radius in its own pixels around the coarser scale's estimate (the
#: coarsest searches around 0).
SEARCH_RADIUS_PX = 3


def _ncc(a: Tensor, b: Tensor, shift: int) -> Tensor:
    """NCC of ``a[..., x]`` with ``b[..., x + shift]`` over their overlap, ``[B, H, W]`` -> ``[B]``."""
    width = a.shape[-1]
    if shift >= 0:
        a, b = a[..., : width - shift], b[..., shift:]
    else:
        a, b = a[..., -shift:], b[..., : width + shift]
    a = a.flatten(1) - a.flatten(1).mean(1, keepdim=True)
    b = b.flatten(1) - b.flatten(1).mean(1, keepdim=True)
    return (a * b).sum(1) / (a.norm(dim=1) * b.norm(dim=1)).clamp_min(1e-12)


def ncc_displacement_px(first: Tensor, second: Tensor, *, center_px: Tensor | None = None,
                        radius_px: int = SEARCH_RADIUS_PX, subpixel: bool = True) -> Tensor:
    """The horizontal displacement ``d`` (pixels) with ``second[x + d] ~ first[x]``, per image.

    Integer shifts within ``radius_px`` of ``center_px`` (rounded; default 0) are scored by NCC
    over the images' overlap (at least half their width); with ``subpixel`` a parabola through
    the best score and its two neighbours refines it.

    Args:
        first, second: ``[B, H, W]`` images.
        center_px: ``[B]`` the search's centre, pixels.
        radius_px: the search's half width, pixels (>= 1).

    Example:
        >>> x = torch.arange(32.0)
        >>> img = torch.sin(x[None, :] * 0.7 + x[:, None] * 0.3)[None]
        >>> round(float(ncc_displacement_px(img[..., :-2], img[..., 2:])[0]), 3)
        -2.0
    """
    if first.shape != second.shape or first.dim() != 3:
        raise ValueError(f"first and second must be [B, H, W] of one shape, got {tuple(first.shape)} "
                         f"and {tuple(second.shape)}")
    b, _, width = first.shape
    center = torch.zeros(b, dtype=torch.long, device=first.device) if center_px is None else \
        center_px.round().long().clamp(-(width // 2), width // 2)
    offsets = torch.arange(-radius_px, radius_px + 1, device=first.device)
    shifts = center[:, None] + offsets  # [B, S]
    scores = torch.full(shifts.shape, -2.0, dtype=first.dtype, device=first.device)
    for shift in torch.unique(shifts).tolist():
        if abs(shift) > width // 2:
            continue
        rows = shifts == shift  # [B, S]
        which = rows.any(1)
        score = _ncc(first[which], second[which], int(shift))
        scores[which] = torch.where(rows[which], score[:, None], scores[which])
    best = scores.argmax(1)
    estimate = shifts.gather(1, best[:, None]).squeeze(1).to(first.dtype)
    if subpixel:
        inner = (best > 0) & (best < shifts.shape[1] - 1)
        i = best.clamp(1, shifts.shape[1] - 2)
        left, mid, right = (scores.gather(1, (i + k)[:, None]).squeeze(1) for k in (-1, 0, 1))
        curvature = left - 2 * mid + right
        ok = inner & (curvature < 0) & (left > -2) & (right > -2)
        step = torch.where(ok, 0.5 * (left - right) / torch.where(ok, curvature, -1.0), 0.0)
        estimate = estimate + step.clamp(-0.5, 0.5)
    return estimate


class Matcher(nn.Module):
    """The classical matcher, driving an `ActiveDepthEnv` as a frozen `JointLearner` would.

    Args:
        actions_deg: the increments it may take (each step the one nearest the estimate), or
            ``None``: the estimate itself (unconstrained). Default: the learner's default action set.
        scales: the foveal scales it searches, coarsest first (default the coder's,
            ``("wide", "coarse", "fine")``).
        cues: the cues it fixates with; the environment holds the others at their optimum.
        camera: the environment's camera (its degrees per pixel).
        dtype, device: of its buffers.
    """

    actions_deg: Tensor  # a buffer

    def __init__(self, actions_deg: Sequence[float] | None = DEFAULT_ACTIONS_DEG,
                 scales: Sequence[str] = DEFAULT_SCALES, *, cues: Sequence[str] = ("parallax", "stereo"),
                 camera: PinholeCamera | None = None, dtype: torch.dtype = torch.float32,
                 device: torch.device | str | None = None) -> None:
        super().__init__()
        self.scales = sorted((as_scale(s) for s in scales), key=lambda s: -s.downsample)
        if not self.scales:
            raise ValueError("scales must name at least one scale")
        self.cue_names = list(cues)
        actions = None if actions_deg is None else torch.tensor([float(a) for a in actions_deg], dtype=dtype,
                                                                 device=device)
        if actions is not None and actions.numel() == 0:
            raise ValueError("actions_deg must be a non-empty list of degrees, or None (unconstrained)")
        self.register_buffer("actions_deg", actions if actions is not None else torch.zeros(0, dtype=dtype,
                                                                                            device=device))
        self.constrained = actions is not None
        self.degrees_per_pixel = (camera or PinholeCamera()).degrees_per_pixel
        self.generator = torch.Generator().manual_seed(0)  # the trial loop seeds and restores it

    def displacement_deg(self, observation: dict[str, Tensor]) -> Tensor:
        """The second image's displacement against the first ``[B]``, degrees, coarse to fine."""
        estimate_deg: Tensor | None = None
        for scale in self.scales:
            pair = observation[scale.name]
            deg_per_px = self.degrees_per_pixel * scale.downsample
            center = None if estimate_deg is None else estimate_deg / deg_per_px
            px = ncc_displacement_px(pair[:, 0], pair[:, 1], center_px=center,
                                     subpixel=scale is self.scales[-1])
            estimate_deg = px * deg_per_px
        return estimate_deg  # type: ignore[return-value]  # not None: there is at least one scale

    def increment_deg(self, observation: dict[str, Tensor]) -> Tensor:
        """The increment that cancels the pair's displacement, or the action nearest it."""
        # An eye d degrees past its optimum sees its image displaced by d degrees against the
        # pair's other image (both cues, measured in tests/test_baselines.py): turn it back by d.
        wanted = -self.displacement_deg(observation)
        if not self.constrained:
            return wanted
        nearest = (wanted[:, None] - self.actions_deg).abs().argmin(1)
        return self.actions_deg[nearest]

    # -- what the trial loop calls ---------------------------------------------------------------
    def iteration(self, env, *, learn: bool = False, greedy: bool = True, watch=None) -> IterationRecord:
        """One iteration of every environment: each cue's pair observed, its increment applied."""
        for name in env.CUES:
            if name not in self.cue_names:
                env.hold(name)
                continue
            observation = env.observe(name, self.scales, window=watch is not None)
            if watch is not None:
                watch(name, observation)
            env.act(name, self.increment_deg(observation).to(env.dtype))
        info = env.end_iteration()
        prediction = None
        if info.trial_end:
            prediction = torch.full_like(info.distance_m, float("nan"))
        return IterationRecord(cues={}, errors_deg=info.errors_deg, fixation_end=info.fixation_end,
                               trial_end=info.trial_end, q_deg=info.q_deg, distance_m=info.distance_m,
                               depth_prediction_m=prediction, depth_retrained=False)

    def forget_transitions(self) -> None:
        """Nothing is pending: the matcher learns nothing."""
