"""Where a learner loses its precision: its coding reward and its greedy increment against the
offset of an eye from its optimum.

For every trial condition (texture x distance) and every offset, the body is put at the end of its
shift, every eye movement at its optimum, then the one movement a cue drives is moved ``offset``
degrees off it; the cue's observation is encoded (its reward R = -(e^C + e^F)) and its greedy
policy read (the increment it would take). A code that can tell a small offset from none has its
reward peak at 0; a policy that can stop at the target answers 0 there and steps back toward it
on both sides. :func:`limit_cycle` iterates each trial's greedy map from the optimum to find where
a frozen fixation settles.

    sweep = offset_sweep(learner, TextureBank.default("test"), cue="stereo")
    offset_summary(sweep)   # the reward's peak, its drop 0.1 deg off, the map's zero crossing, the cycle
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from aectorch._checks import check_int
from aectorch.evaluation.trials import EVAL_BATCH_SIZE, placement, _all_conditions, _check_trial_arguments, _trial_session
from aectorch.sim import TextureBank, TrialProtocol, resolve_protocol

__all__ = ["AWAY_MIN_DEG", "CAPTURE_AWAY", "CAPTURE_FROM_DEG", "DEFAULT_OFFSETS_DEG", "capture_range", "limit_cycle",
           "offset_summary", "offset_sweep"]

#: -1 to +1 degree in 0.02 degree steps (about a tenth of a pixel).
DEFAULT_OFFSETS_DEG = tuple(round(-1.0 + 0.02 * i, 2) for i in range(101))
#: `offset_summary` counts a mean increment of at least this many degrees (the default actions'
#: smallest step) that points away from the optimum as a step away.
AWAY_MIN_DEG = 0.05
#: `capture_range` looks from this distance from the optimum outward (degrees): closer in, the mean
#: read-out's small steps about the optimum are its precision, not its reach.
CAPTURE_FROM_DEG = 0.5
#: `capture_range`: an offset is within the capture range while at most this share of the trials
#: steps away from the optimum there.
CAPTURE_AWAY = 0.1


def _pans_at(env, movement: str, offset: Tensor) -> Tensor:
    """Both eyes' pans ``[b, 2]``: every movement at its optimum, ``movement`` ``offset`` off it."""
    left = env.optimal_left_pan_deg()
    if movement == "pursuit":
        left = left + offset  # the right eye at its optimum for this left pan
        return torch.stack((left, env.optimal_right_pan_deg(left)), -1)
    if movement == "vergence":
        return torch.stack((left, env.optimal_right_pan_deg(left) + offset), -1)
    raise ValueError(f"offset_sweep knows the movements 'pursuit' and 'vergence', got {movement!r}")


def offset_sweep(
    learner,
    textures: TextureBank | Tensor,
    *,
    cue: str,
    offsets_deg: Sequence[float] = DEFAULT_OFFSETS_DEG,
    distances_m: Sequence[float] = (1.0, 1.5, 2.0, 2.5, 3.0),
    protocol: TrialProtocol | None = None,
    batch_size: int = EVAL_BATCH_SIZE,
    progress: bool = False,
    features: bool = False,
) -> dict[str, Tensor]:
    """The cue's reward and greedy increment at each offset of its eye movement from the optimum.

    Args:
        learner: a `JointLearner` that learns ``cue`` (frozen here: nothing is learned).
        textures: the conditions' textures; every texture is tried at every distance.
        cue: the cue whose movement is offset (``"parallax"``: pursuit; ``"stereo"``: vergence).
        offsets_deg: the offsets, degrees.
        distances_m, protocol, batch_size: as for `aectorch.evaluation.run_trials`; the body is at
            the end of the protocol's shift.
        progress: show a progress bar.
        features: also return ``features`` ``[N, K, F]``, what the cue's agent is given at each
            view (before its own normalisation): to take a policy's choice apart by feature.

    Returns:
        CPU tensors: ``offsets_deg`` ``[K]``; over the N = textures x distances conditions
        ``reward`` and ``increment_deg`` (the greedy action's increment) ``[N, K]``, and
        ``expected_increment_deg`` (the policy's mean increment) ``[N, K]``; ``texture_index`` and
        ``distance_m`` ``[N]``.
    """
    distances, _ = _check_trial_arguments(distances_m, batch_size, "greedy")
    if cue not in learner.cues:
        raise ValueError(f"cue must be one the learner learns, {list(learner.cues)}, got {cue!r}")
    offsets = torch.as_tensor(list(offsets_deg), dtype=torch.float64)
    if offsets.dim() != 1 or offsets.numel() == 0 or not bool(torch.isfinite(offsets).all()):
        raise ValueError(f"offsets_deg must be a non-empty list of finite degrees, got {list(offsets_deg)!r}")
    protocol = resolve_protocol(protocol)
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    index, distance = _all_conditions(len(bank), distances)
    cue_learner = learner.cues[cue]
    device, dtype = placement(learner)
    out: dict[str, list[Tensor]] = {"reward": [], "increment_deg": [], "expected_increment_deg": []}
    if features:  # the flag; the loop's views' features are `seen`
        out["features"] = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=index.numel() * offsets.numel(), desc=f"{cue} offsets", unit="view")
    actions = cue_learner.agent.actions_deg
    scales = cue_learner.encoder.scales if learner.config.render_scales else None
    with _trial_session(learner, bank, distances, protocol, 0, bar) as env_for, torch.no_grad():
        for start in range(0, index.numel(), batch_size):
            stop = min(start + batch_size, index.numel())
            env = env_for(stop - start, protocol.fixation_iterations, instant=True)
            movement = env.cue(cue).name
            rows: dict[str, list[Tensor]] = {key: [] for key in out}
            keep = "features" in out
            for offset in offsets.tolist():
                env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
                shifted = torch.full((stop - start,), offset, dtype=dtype, device=device)
                env.set_pan_deg(_pans_at(env, movement, shifted))
                coded = cue_learner.encoder.encode(env.observe(cue, scales))
                sensed = env.proprioception(cue_learner.config.proprioception) \
                    if cue_learner.config.proprioception else None
                seen = cue_learner.features(coded.features, sensed)
                greedy = cue_learner.agent.act(seen, greedy=True, generator=learner.generator)
                probabilities = cue_learner.agent.log_policy(seen).exp()
                rows["reward"].append(coded.reward)
                rows["increment_deg"].append(greedy.increments_deg)
                rows["expected_increment_deg"].append(probabilities @ actions.to(probabilities.dtype))
                if keep:
                    rows["features"].append(seen)
                if bar is not None:
                    bar.update(stop - start)
            for key, values in rows.items():
                out[key].append(torch.stack(values, 1).double().cpu())
    result = {key: torch.cat(values) for key, values in out.items()}
    result.update(offsets_deg=offsets, texture_index=index, distance_m=distance)
    return result


def limit_cycle(offsets_deg: Tensor, increment_deg: Tensor, *, steps: int = 30, last: int = 10) -> Tensor:
    """Where each trial's greedy map settles: from the optimum (offset 0), ``steps`` times
    ``offset += increment(offset)`` (the map interpolated linearly between the sweep's offsets,
    held at its ends); returns each trial's mean |offset| over the last ``last`` steps ``[N]``."""
    check_int(steps, "steps", 1)
    check_int(last, "last", 1)
    x = offsets_deg.double()
    n = increment_deg.shape[0]
    position = torch.zeros(n, dtype=torch.float64)
    seen = []
    for _ in range(steps):
        clamped = position.clamp(float(x[0]), float(x[-1]))
        hi = torch.searchsorted(x, clamped).clamp(1, x.numel() - 1)
        lo = hi - 1
        w = ((clamped - x[lo]) / (x[hi] - x[lo])).clamp(0, 1)
        rows = torch.arange(n)
        step = (1 - w) * increment_deg[rows, lo] + w * increment_deg[rows, hi]
        position = position + step
        seen.append(position.abs())
    return torch.stack(seen[-last:], 1).mean(1)


def capture_range(offsets_deg: Tensor, away: Tensor, *, start_deg: float = CAPTURE_FROM_DEG,
                  share: float = CAPTURE_AWAY) -> tuple[float, float]:
    """How far from the optimum a policy still steps back toward it, below and above it.

    Args:
        offsets_deg: the sweep's offsets ``[K]``.
        away: ``[N, K]``, True where trial n's step at offset k points away from the optimum.
        start_deg: offsets closer to the optimum than this are left out (the policy's precision).
        share: an offset is captured while at most this share of the trials steps away there.

    Returns:
        ``(below, above)``: on each side the largest ``|offset|`` up to which every swept offset
        from ``start_deg`` outward is captured; 0 where the first one already is not; NaN where the
        sweep reaches no offset ``start_deg`` or more on that side.

    Example:
        >>> x = torch.tensor([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])
        >>> away = torch.tensor([[True, False, False, False, False, True, False]])
        >>> capture_range(x, away)
        (2.0, 1.0)
    """
    share_away = away.double().mean(0)
    out = []
    for side in (-1.0, 1.0):
        mask = (torch.sign(offsets_deg) == side) & (offsets_deg.abs() >= start_deg)
        if not bool(mask.any()):
            out.append(float("nan"))
            continue
        distance, order = offsets_deg[mask].abs().sort()
        failed = share_away[mask][order] > share
        reach = 0.0
        for d, bad in zip(distance.tolist(), failed.tolist()):
            if bad:
                break
            reach = d
        out.append(reach)
    return out[0], out[1]


def offset_summary(sweep: dict[str, Tensor], *, probe_deg: float = 0.1, pixel_deg: float = 0.22,
                   far_deg: float = 1.0) -> dict:
    """The sweep's numbers: where the reward peaks (mean |offset| of each trial's peak, and the
    fraction within ``pixel_deg``), how much lower it is ``probe_deg`` off the optimum (mean of
    both sides' drop, per trial, averaged), the greedy map's mean zero crossing, the share of
    trials whose greedy increment at the optimum is 0, the limit cycle's mean |offset| of the
    greedy map and (``mean_readout_limit_cycle_abs_deg``) of the mean read-out's map, and, of the
    offsets more than ``far_deg`` below (``away_far_below``) and above (``away_far_above``) the
    optimum, the share of trials x offsets where the mean read-out steps away from it (by at least
    `AWAY_MIN_DEG`; NaN where the sweep reaches no such offset), and the policy's
    `capture_range` on each side (``capture_below_deg``, ``capture_above_deg``; NaN where the
    sweep reaches no offset beyond ``far_deg`` on that side)."""
    x, reward, increment = sweep["offsets_deg"], sweep["reward"], sweep["increment_deg"]
    expected = sweep["expected_increment_deg"]
    away = (torch.sign(expected) == torch.sign(x)) & (expected.abs() >= AWAY_MIN_DEG)
    far = {side: away[:, mask].double().mean() if bool(mask.any()) else torch.tensor(float("nan"))
           for side, mask in (("below", x < -far_deg), ("above", x > far_deg))}
    # The capture range where the sweep reaches beyond ``far_deg`` on that side (NaN otherwise).
    capture = [reach if bool(mask.any()) else float("nan")
               for reach, mask in zip(capture_range(x, away), (x < -far_deg, x > far_deg))]
    peak = x[reward.argmax(1)]
    zero = int((x.abs()).argmin())
    sides = [int((x - s).abs().argmin()) for s in (-probe_deg, probe_deg)]
    drop = reward[:, zero] - reward[:, sides].mean(1)
    mean_map = sweep["expected_increment_deg"].mean(0)
    sign = torch.sign(mean_map)
    crossing = float("nan")
    for i in range(x.numel() - 1):  # the mean expected map's first + to - crossing
        if sign[i] > 0 and sign[i + 1] <= 0:
            crossing = float(x[i] + (x[i + 1] - x[i]) * mean_map[i] / (mean_map[i] - mean_map[i + 1]))
            break
    return {
        "reward_peak_abs_deg": float(peak.abs().mean()),
        "reward_peak_within_px": float((peak.abs() <= pixel_deg).double().mean()),
        f"reward_drop_at_{probe_deg}_deg": float(drop.mean()),
        "expected_map_zero_crossing_deg": crossing,
        "greedy_zero_at_optimum": float((increment[:, zero] == 0).double().mean()),
        "limit_cycle_abs_deg": float(limit_cycle(x, increment).mean()),
        "mean_readout_limit_cycle_abs_deg": float(limit_cycle(x, expected).mean()),
        "away_far_below": float(far["below"]),
        "away_far_above": float(far["above"]),
        "capture_below_deg": capture[0],
        "capture_above_deg": capture[1],
        "trials": int(reward.shape[0]),
    }
