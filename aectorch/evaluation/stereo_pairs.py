"""Evaluation on rectified stereo photographs: a frozen stereo policy fixates points of real pairs.

The eyes are windows over each pair (`aectorch.sim.pair_world.StereoPairWorld`); the left eye
fixates a point with known ground truth and texture (`aectorch.sim.stereo_pairs.pick_fixations`),
and the policy moves the right eye's window for ``steps`` iterations from two kinds of start:

- ``protocol``: the vergence every training fixation starts with (the run's
  ``env.vergence_start_deg`` +- ``env.vergence_start_spread_deg``; 0, parallel eyes, by default);
- ``vergence_test``: the earlier models' vergence test, the optimum +- a uniform offset of at most
  ``offset_deg`` (2 degrees).

A policy is a callable ``policy(observation, world) -> increments_deg [B]``: the learner's stereo
cue run frozen and greedy (:func:`stereo_policy`) or any other, such as the classical matcher's
``increment_deg`` (`aectorch.baselines.Matcher`, which the command line runs beside the learner).
The result holds each fixation's final signed error in eye pixels (``vergence_error_px``: the
right window's offset from the fixation point's match, positive past it) and, per policy and
start kind, the median |error|, the fraction within 1 px and the fraction beyond 5 px, over all
fixations, separately over smooth windows and windows that span a depth edge
(:data:`EDGE_RESIDUAL_PX`, :data:`EDGE_UNKNOWN`), and over the **visible** fixation points: those
none of whose four pixels the right photograph hides (`aectorch.sim.stereo_pairs.occlusion`; an
occluded point's surface is seen by the left eye alone, so no vergence brings the right eye onto it,
and Middlebury's benchmark reports its non-occluded pixels apart for the same reason).
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_int, check_real
from aectorch.coding.patches import as_scale
from aectorch.evaluation.trials import placement
from aectorch.sim.oculomotor import VERGENCE_RANGE_DEG
from aectorch.sim.pair_world import StereoPairWorld, eye_extent_px
from aectorch.sim.stereo_pairs import MIN_CONTRAST, StereoPair, disparity_roughness, occlusion, pick_fixations

__all__ = ["BEYOND_PX", "EDGE_RESIDUAL_PX", "EDGE_UNKNOWN", "PARTS", "START_KINDS", "WITHIN_PX", "evaluate_pairs",
           "pair_summary", "stereo_policy"]

Policy = Callable[[dict, StereoPairWorld], Tensor]

#: The parts of the fixations each summary covers: all of them, smooth and edge windows, visible points.
PARTS = ("all", "smooth", "edge", "visible")
#: The kinds of start: the training protocol's vergence, and the vergence test's offsets about the optimum.
START_KINDS = ("protocol", "vergence_test")
#: A fixation ends on target within this many eye pixels, and has failed beyond ``BEYOND_PX``.
WITHIN_PX, BEYOND_PX = 1.0, 5.0
#: A window spans a depth edge when more than a tenth of the known ground truth in its coarse
#: window (the largest crop of the scales, 128 eye px by default) lies farther than this many eye
#: pixels from its least-squares plane (`disparity_roughness`: a slanted surface is smooth) ...
EDGE_RESIDUAL_PX = 2.0
#: ... or more than this fraction of it is unknown (unknown disparity marks occlusions, which lie
#: at depth edges). Other windows are smooth.
EDGE_UNKNOWN = 0.1


def stereo_policy(learner, cue: str = "stereo") -> Policy:
    """The learner's ``cue`` run frozen and greedy (its readout: ``learner.cues.<cue>.readout``):
    each observation encoded, the greedy increment returned; nothing is learned."""
    if cue not in learner.cues:
        raise ValueError(f"the learner has no cue {cue!r} (its cues: {list(learner.cues)})")
    learner_cue = learner.cues[cue]
    device, dtype = placement(learner)

    def policy(observation: dict, world: StereoPairWorld) -> Tensor:
        sensed = None
        if learner_cue.config.proprioception:
            sensed = world.proprioception(learner_cue.config.proprioception).to(device=device, dtype=dtype)
        observation = {name: image.to(device=device, dtype=dtype) for name, image in observation.items()}
        learner_cue.forget()
        with torch.no_grad():
            record = learner_cue.step(observation, learn=False, greedy=True, proprioception=sensed)
        return record.increments_deg

    return policy


def pair_summary(errors_px: Tensor) -> dict:
    """The median |error| (eye pixels), the fractions within `WITHIN_PX` and beyond `BEYOND_PX`,
    the mean |error| and the count of ``errors_px``.

    Example:
        >>> pair_summary(torch.tensor([0.5, -2.0, 7.0, 0.1]))
        {'n': 4, 'median_abs_px': 1.25, 'within_1px': 0.5, 'beyond_5px': 0.25, 'mean_abs_px': 2.4}
    """
    e = errors_px.detach().double().reshape(-1).abs()
    e = e[torch.isfinite(e)]
    if e.numel() == 0:
        return {"n": 0, "median_abs_px": math.nan, "within_1px": math.nan, "beyond_5px": math.nan,
                "mean_abs_px": math.nan}
    return {"n": int(e.numel()), "median_abs_px": round(float(e.quantile(0.5)), 6),
            "within_1px": round(float((e <= WITHIN_PX).double().mean()), 6),
            "beyond_5px": round(float((e > BEYOND_PX).double().mean()), 6),
            "mean_abs_px": round(float(e.mean()), 6)}


def _starts(kind: str, world: StereoPairWorld, start_vergence_deg: tuple[float, float], offset_deg: float,
            generator: torch.Generator) -> Tensor:
    u = torch.rand(world.num_envs, generator=generator, dtype=torch.float64)
    if kind == "protocol":
        low, high = start_vergence_deg
        return low + (high - low) * u
    return world.optimal_vergence_deg + (2 * u - 1) * offset_deg


def _fixate(policy: Policy, world: StereoPairWorld, scales, steps: int) -> None:
    for _ in range(steps):
        world.apply_vergence(policy(world.stereo_observation(scales), world))


def _pair_rows(pair: StereoPair, policies: dict[str, Policy], scales, settings: dict, bar) -> list[dict]:
    """Every policy from every kind of start on one pair's fixation points: a row per fixation."""
    ps, batch = settings["pair_scale"], settings["batch_size"]
    points = pick_fixations(pair, settings["fixations"], half_extent_px=eye_extent_px(scales) * ps,
                            texture_half_px=min(s.crop for s in scales) // 2 * ps,
                            min_contrast=settings["min_contrast"], seed=settings["seed"])
    coarse = max(s.crop for s in scales) // 2 * ps
    rough, unknown = disparity_roughness(pair, points, coarse)
    rough = rough / ps
    edge = (rough > EDGE_RESIDUAL_PX) | (unknown > EDGE_UNKNOWN) | ~torch.isfinite(rough)
    hidden = occlusion(pair)
    x, y = points[:, 0].long(), points[:, 1].long()
    occluded = hidden[y - 1, x - 1] | hidden[y - 1, x] | hidden[y, x - 1] | hidden[y, x]
    everything = StereoPairWorld(pair, points, pair_scale=ps, vergence_range_deg=settings["vergence_range_deg"])
    rows = []
    for k, kind in enumerate(START_KINDS):
        generator = torch.Generator().manual_seed(settings["seed"] * len(START_KINDS) + k)
        everything.set_vergence_deg(_starts(kind, everything, settings["start_vergence_deg"], settings["offset_deg"],
                                            generator))
        start_deg, start_px = everything.vergence_deg.clone(), everything.vergence_error_px.clone()
        for name, policy in policies.items():
            for first in range(0, len(points), batch):
                chunk = slice(first, first + batch)
                world = StereoPairWorld(pair, points[chunk], pair_scale=ps,
                                        vergence_range_deg=settings["vergence_range_deg"])
                world.set_vergence_deg(start_deg[chunk])
                _fixate(policy, world, scales, settings["steps"])
                for i, (end, error_px, error_deg) in enumerate(zip(world.vergence_deg.tolist(),
                                                                   world.vergence_error_px.tolist(),
                                                                   world.vergence_error_deg.tolist())):
                    j = first + i
                    rows.append({
                        "pair": pair.name, "policy": name, "start": kind,
                        "x": int(points[j, 0]), "y": int(points[j, 1]),
                        "ground_truth_px": round(float(everything.ground_truth_px[j]), 6),
                        "start_vergence_deg": round(float(start_deg[j]), 6), "end_vergence_deg": round(end, 6),
                        "start_error_px": round(float(start_px[j]), 6), "vergence_error_px": round(error_px, 6),
                        "vergence_error_deg": round(error_deg, 6),
                        "plane_residual_px": round(float(rough[j]), 4), "unknown_fraction": round(float(unknown[j]), 4),
                        "window": "edge" if bool(edge[j]) else "smooth", "occluded": bool(occluded[j])})
                if bar is not None:
                    bar.update(world.num_envs)
    return rows


def _summaries(rows: list[dict]) -> dict:
    """``{policy: {start kind: {"all"|"smooth"|"edge"|"visible": pair_summary}}}`` and ``no_movement`` from
    the starts (``visible``: the fixation points the right photograph does not hide)."""
    out: dict = {}
    policies = list(dict.fromkeys(row["policy"] for row in rows))
    first = policies[0] if policies else None
    for name in policies + ["no_movement"]:
        out[name] = {}
        for kind in START_KINDS:
            chosen = [r for r in rows if r["policy"] == (first if name == "no_movement" else name) and r["start"] == kind]
            key = "start_error_px" if name == "no_movement" else "vergence_error_px"
            out[name][kind] = {
                part: pair_summary(torch.tensor([r[key] for r in chosen if _part(r, part)], dtype=torch.float64))
                for part in PARTS}
    return out


def _part(row: dict, part: str) -> bool:
    """Whether a fixation's row belongs to a summary's part (`PARTS`)."""
    if part == "visible":
        return not row["occluded"]
    return part == "all" or row["window"] == part


def evaluate_pairs(
    policies: dict[str, Policy],
    pairs: Sequence[StereoPair],
    *,
    scales: Sequence = ("wide", "coarse", "fine", "full"),
    pair_scale: int = 1,
    fixations: int = 300,
    steps: int = 30,
    seed: int = 0,
    start_vergence_deg: float | tuple[float, float] = 0.0,
    offset_deg: float = 2.0,
    vergence_range_deg: Sequence[float] = VERGENCE_RANGE_DEG,
    batch_size: int = 256,
    progress: bool = False,
) -> dict:
    """Each policy fixates points of each pair from both kinds of start (`START_KINDS`).

    Args:
        policies: ``{name: policy}``, each ``policy(observation, world) -> increments_deg [B]``.
        pairs: the stereo pairs (`aectorch.sim.stereo_pairs.read_pairs`).
        scales: the foveal scales the eyes see (the policies' encoders' scales).
        pair_scale: photo pixels per eye pixel.
        fixations: fixation points per pair (fewer where fewer qualify).
        steps: iterations per fixation (the protocol's fixation length, 30).
        seed: seeds the points and the starts.
        start_vergence_deg: the protocol's start vergence, a value or a ``(low, high)`` range.
        offset_deg: the vergence test's largest offset from the optimum.
        vergence_range_deg: the vergence's range, degrees.
        batch_size: fixations at once.
        progress: show a progress bar.

    Returns:
        ``summary`` (:func:`_summaries`: per policy, per start kind, over all, smooth and edge
        windows and visible points, and ``no_movement``: the starts' errors), ``per_pair`` (the same over all windows
        of each pair), ``per_fixation`` (one row per policy, start and point) and the settings.

    Example:
        >>> photo = torch.nn.functional.avg_pool2d(torch.rand(1, 1, 260, 400), 3, 1, 1)[0, 0]
        >>> shifted = torch.cat((photo[:, 5:], photo[:, -1:].expand(-1, 5)), 1)  # disparity 5 px
        >>> pair = StereoPair("shifted", photo, shifted, torch.full((260, 400), 5.0))
        >>> still = lambda observation, world: torch.zeros(world.num_envs)
        >>> out = evaluate_pairs({"still": still}, [pair], fixations=4, steps=1)
        >>> out["summary"]["still"]["protocol"]["all"]["median_abs_px"]
        5.0
    """
    scales = [as_scale(s) for s in scales]
    check_int(pair_scale, "pair_scale", 1)
    check_int(fixations, "fixations", 1)
    check_int(steps, "steps", 0)
    check_int(batch_size, "batch_size", 1)
    check_int(seed, "seed", 0)
    check_real(offset_deg, "offset_deg", minimum=0.0)
    start = (float(start_vergence_deg),) * 2 if isinstance(start_vergence_deg, (int, float)) \
        else tuple(float(v) for v in start_vergence_deg)
    if not policies or not pairs:
        raise ValueError("evaluate_pairs needs at least one policy and one pair")
    settings = dict(pair_scale=pair_scale, fixations=fixations, steps=steps, seed=seed, start_vergence_deg=start,
                    offset_deg=offset_deg, vergence_range_deg=tuple(vergence_range_deg), min_contrast=MIN_CONTRAST,
                    batch_size=batch_size)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(pairs) * fixations * len(START_KINDS) * len(policies), desc="pairs", unit="fixation")
    rows = []
    for pair in pairs:
        rows += _pair_rows(pair, policies, scales, settings, bar)
    if bar is not None:
        bar.close()
    per_pair = {pair.name: {name: {kind: summary["all"] for kind, summary in kinds.items()}
                            for name, kinds in _summaries([r for r in rows if r["pair"] == pair.name]).items()}
                for pair in pairs}
    return {"summary": _summaries(rows), "per_pair": per_pair,
            "pairs": [{"name": p.name, "height": int(p.left.shape[0]), "width": int(p.left.shape[1]),
                       "fixations": sum(1 for r in rows if r["pair"] == p.name and r["start"] == START_KINDS[0]
                                        and r["policy"] == rows[0]["policy"])} for p in pairs],
            "scales": [s.name for s in scales], "steps": steps,
            "start_kinds": {"protocol": {"vergence_deg": list(start)}, "vergence_test": {"offset_deg": offset_deg}},
            "within_px": WITHIN_PX, "beyond_px": BEYOND_PX, "edge_residual_px": EDGE_RESIDUAL_PX,
            "edge_unknown_fraction": EDGE_UNKNOWN, **{k: settings[k] for k in ("pair_scale", "seed", "min_contrast")},
            "vergence_range_deg": list(vergence_range_deg), "per_fixation": rows}
