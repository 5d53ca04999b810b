"""Evaluation on rectified stereo photographs: a frozen stereo policy fixates points of real pairs.

The eyes are windows over each pair (`aectorch.sim.pair_world.StereoPairWorld`); the left eye
fixates a point with known ground truth (where the pair has it) and texture
(`aectorch.sim.stereo_pairs.pick_fixations`), and the policy moves the right eye's window for
``steps`` iterations from two kinds of start:

- ``protocol``: the vergence every training fixation starts with (the run's
  ``env.vergence_start_deg`` +- ``env.vergence_start_spread_deg``; 0, parallel eyes, by default);
- ``vergence_test``: the earlier models' vergence test, the optimum +- a uniform offset of at most
  :data:`OFFSET_DEG` (2 degrees).

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

**Pairs without ground truth** (a robot's two cameras: ``pair.disparity`` ``None``) have no
optimum, so no error and no vergence test: only the protocol's start runs, the vergence held in
a search range (:data:`SEARCH_DEG`, within the vergence range), from points whose windows lie
inside both photos over all of it. Each fixation is scored by what
needs no ground truth (:class:`Scoring`; every row has the last two, pairs with ground truth
too):

- ``reward``: the coding reward of the fixation's final observation (``start_reward``: of its
  first), R = -(the sum of the scales' normalised errors), computed by one coder for every
  policy (:func:`coding_reward`: the learner's stereo encoder, so the matcher's end is scored by
  the same code);
- ``agreement_px``: ``|end - the reference policy's end|``, eye pixels, the reference being
  a classical estimate of the match (the matcher);
- ``stability_px``: the standard deviation of the right window's shift (``f tan(vergence)``,
  eye pixels) over the fixation's last :data:`STABILITY_ITERATIONS` iterations (stable at most
  :data:`STABLE_PX`), and ``last_increment_px``, the last iteration's move;
- ``at_limit``: whether the fixation ends at an end of its vergence range (the search range
  without ground truth), where the range, not the policy, holds it still: a match beyond the
  search range is reached by no policy, and policies that agree there agree on the limit.

Their summaries (:func:`fixation_summary`) are the result's ``without_ground_truth.summary``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_int
from aectorch.coding.patches import as_scale
from aectorch.evaluation.trials import placement
from aectorch.sim.camera import PinholeCamera
from aectorch.sim.oculomotor import VERGENCE_RANGE_DEG
from aectorch.sim.pair_world import StereoPairWorld, eye_extent_px
from aectorch.sim.stereo_pairs import MIN_CONTRAST, StereoPair, disparity_roughness, occlusion, pick_fixations

__all__ = ["BEYOND_PX", "EDGE_RESIDUAL_PX", "EDGE_UNKNOWN", "OFFSET_DEG", "PARTS", "SEARCH_DEG", "STABILITY_ITERATIONS", "STABLE_PX",
           "START_KINDS", "Scoring", "WITHIN_PX", "coding_reward", "evaluate_pairs", "fixation_summary",
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
#: The vergence test's largest offset from the optimum, degrees (the earlier models' test).
OFFSET_DEG = 2.0
#: A fixation is stable when the right window's shift varies by at most ``STABLE_PX`` eye pixels
#: (standard deviation) over its last ``STABILITY_ITERATIONS`` iterations.
STABILITY_ITERATIONS, STABLE_PX = 10, 0.5
#: The vergence range searched on a pair without ground truth, degrees (about -9 to +36 eye px):
#: its points' windows must lie inside both photos over all of it.
SEARCH_DEG = (-2.0, 8.0)
#: Why pairs without ground truth run the protocol's start only (the result says it).
NO_VERGENCE_TEST = ("the vergence test starts about the optimum, which a pair without ground truth lacks: "
                    "only the protocol's start runs")


@dataclass(frozen=True)
class Scoring:
    """What scores a fixation without the ground truth (the module's docstring).

    Args:
        reward: ``reward(observation) -> [B]``, the coding reward of an observation
            (:func:`coding_reward`); it scores every policy's start and end alike. ``None``: no reward.
        reference: the policy whose ends the others' are compared with (``agreement_px``), e.g.
            ``"matcher"``; ``None``: no agreement.
        search_deg: ``(low, high)``, the vergence range searched on a pair without ground truth
            (within the evaluation's vergence range), degrees.
    """

    reward: Callable[[dict], Tensor] | None = None
    reference: str | None = None
    search_deg: tuple[float, float] = SEARCH_DEG


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


def coding_reward(learner, cue: str = "stereo") -> Callable[[dict], Tensor]:
    """The coding reward of the learner's ``cue`` for an observation, ``reward(observation) -> [B]``
    (float64, on the CPU): ``learner.cues[cue].encoder.encode(observation).reward``, what the
    learner computes, R = -(the sum of the scales' normalised errors); nothing is learned."""
    if cue not in learner.cues:
        raise ValueError(f"the learner has no cue {cue!r} (its cues: {list(learner.cues)})")
    encoder = learner.cues[cue].encoder
    device, dtype = placement(learner)

    def reward(observation: dict) -> Tensor:
        observation = {name: image.to(device=device, dtype=dtype) for name, image in observation.items()}
        with torch.no_grad():
            return encoder.encode(observation).reward.detach().double().cpu()

    return reward


def _median(values: Tensor) -> float:
    return round(float(values.quantile(0.5)), 6) if values.numel() else math.nan


def _fraction(mask: Tensor) -> float:
    return round(float(mask.double().mean()), 6) if mask.numel() else math.nan


def fixation_summary(rows: Sequence[dict]) -> dict:
    """What needs no ground truth, over ``rows`` (each a fixation's, :func:`evaluate_pairs`): the
    median reward, the median stability and the fraction stable (`STABLE_PX`), the median last
    increment, the median agreement with the reference and the fractions agreeing within
    `WITHIN_PX` and beyond `BEYOND_PX`, and the fraction ending at the vergence range's limit
    (NaN where the rows lack the value).

    Example:
        >>> rows = [{"reward": -1.0, "stability_px": 0.0, "last_increment_px": 0.0, "agreement_px": 0.5,
        ...          "at_limit": False},
        ...         {"reward": -3.0, "stability_px": 2.0, "last_increment_px": 1.0, "agreement_px": 6.0,
        ...          "at_limit": False}]
        >>> fixation_summary(rows)["stable"], fixation_summary(rows)["agree_beyond_5px"]
        (0.5, 0.5)
    """
    def values(key: str) -> Tensor:
        v = torch.tensor([float(r[key]) for r in rows if r.get(key) is not None], dtype=torch.float64)
        return v[torch.isfinite(v)]

    stability, agreement = values("stability_px"), values("agreement_px")
    return {"n": len(rows), "median_reward": _median(values("reward")), "median_stability_px": _median(stability),
            "stable": _fraction(stability <= STABLE_PX), "median_last_increment_px": _median(values("last_increment_px")),
            "median_agreement_px": _median(agreement), "agree_within_1px": _fraction(agreement <= WITHIN_PX),
            "agree_beyond_5px": _fraction(agreement > BEYOND_PX), "at_limit": _fraction(values("at_limit") > 0)}


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


def _fixate(policy: Policy, world: StereoPairWorld, scales, steps: int) -> Tensor:
    """Run ``steps`` iterations; the right window's shift (eye pixels) at the start and after
    each iteration, ``[steps + 1, B]``."""
    shifts = [world.shift_px()]
    for _ in range(steps):
        world.apply_vergence(policy(world.stereo_observation(scales), world))
        shifts.append(world.shift_px())
    return torch.stack(shifts)


def _run(policy: Policy, pair: StereoPair, points: Tensor, start_deg: Tensor, scales, settings: dict,
         bar) -> dict[str, Tensor]:
    """One policy from ``start_deg`` at every point, in batches: each fixation's end, errors,
    stability and rewards ``[N]`` (float64)."""
    batch, scoring = settings["batch_size"], settings["scoring"]
    parts: dict[str, list[Tensor]] = {}
    for first in range(0, len(points), batch):
        chunk = slice(first, first + batch)
        world = StereoPairWorld(pair, points[chunk], pair_scale=settings["pair_scale"],
                                vergence_range_deg=settings["vergence_range_deg"])
        world.set_vergence_deg(start_deg[chunk])
        out = {}
        if scoring.reward is not None:
            out["start_reward"] = scoring.reward(world.stereo_observation(scales))
        shifts = _fixate(policy, world, scales, settings["steps"])
        last = shifts[1:][-STABILITY_ITERATIONS:]
        nan = torch.full((world.num_envs,), math.nan, dtype=torch.float64)
        low, high = settings["vergence_range_deg"]
        end = world.vergence_deg.clone()
        out.update(end_deg=end, at_limit=((end <= low + 1e-9) | (end >= high - 1e-9)).double(),
                   end_shift_px=shifts[-1], error_px=world.vergence_error_px,
                   error_deg=world.vergence_error_deg,
                   stability_px=last.std(0, unbiased=False) if len(last) else nan,
                   last_increment_px=(shifts[-1] - shifts[-2]).abs() if len(last) else nan)
        if scoring.reward is not None:
            out["reward"] = scoring.reward(world.stereo_observation(scales))
        for key, value in out.items():
            parts.setdefault(key, []).append(value.detach().double().cpu().reshape(-1))
        if bar is not None:
            bar.update(world.num_envs)
    return {key: torch.cat(values) for key, values in parts.items()}


def _scores(ends: dict[str, dict[str, Tensor]], name: str, j: int, reference: str | None) -> dict:
    """The fields of policy ``name``'s fixation ``j`` that need no ground truth."""
    end = ends[name]
    row: dict[str, float | None] = {key: round(float(end[key][j]), 6) for key in ("start_reward", "reward")
                                    if key in end}
    row.update(stability_px=round(float(end["stability_px"][j]), 6),
               last_increment_px=round(float(end["last_increment_px"][j]), 6), at_limit=bool(end["at_limit"][j]))
    if reference is not None:
        row["agreement_px"] = None if name == reference else round(
            abs(float(end["end_shift_px"][j]) - float(ends[reference]["end_shift_px"][j])), 6)
    return row


def _search_settings(settings: dict) -> dict:
    """``settings`` for a pair without ground truth: the vergence range the search's, within it."""
    low, high = settings["vergence_range_deg"]
    search = settings["scoring"].search_deg
    inside = (max(low, float(search[0])), min(high, float(search[1])))
    if not inside[0] < inside[1]:
        raise ValueError(f"the search range {list(search)} deg lies outside the vergence range [{low:g}, {high:g}] deg")
    return dict(settings, vergence_range_deg=inside)


def _shift_range_px(settings: dict) -> tuple[float, float]:
    """The right window's shifts (eye pixels) over the vergence range."""
    f = PinholeCamera().focal_px
    low, high = settings["vergence_range_deg"]
    return f * math.tan(math.radians(low)), f * math.tan(math.radians(high))


def _points(pair: StereoPair, scales, settings: dict) -> Tensor:
    ps = settings["pair_scale"]
    low, high = _shift_range_px(settings)
    return pick_fixations(pair, settings["fixations"], half_extent_px=eye_extent_px(scales) * ps,
                          texture_half_px=min(s.crop for s in scales) // 2 * ps,
                          min_contrast=settings["min_contrast"], seed=settings["seed"],
                          shift_range_px=(low * ps, high * ps))


def _pair_rows(pair: StereoPair, policies: dict[str, Policy], scales, settings: dict, bar) -> list[dict]:
    """Every policy from every kind of start on one pair's fixation points (the protocol's only
    without ground truth): a row per fixation."""
    ps, truth, reference = settings["pair_scale"], pair.has_ground_truth, settings["scoring"].reference
    if not truth:
        settings = _search_settings(settings)
    points = _points(pair, scales, settings)
    if truth:
        coarse = max(s.crop for s in scales) // 2 * ps
        rough, unknown = disparity_roughness(pair, points, coarse)
        rough = rough / ps
        edge = (rough > EDGE_RESIDUAL_PX) | (unknown > EDGE_UNKNOWN) | ~torch.isfinite(rough)
        hidden, (x, y) = occlusion(pair), (points[:, 0].long(), points[:, 1].long())
        occluded = hidden[y - 1, x - 1] | hidden[y - 1, x] | hidden[y, x - 1] | hidden[y, x]
    everything = StereoPairWorld(pair, points, pair_scale=ps, vergence_range_deg=settings["vergence_range_deg"])
    rows = []
    for k, kind in enumerate(START_KINDS if truth else START_KINDS[:1]):
        generator = torch.Generator().manual_seed(settings["seed"] * len(START_KINDS) + k)
        everything.set_vergence_deg(_starts(kind, everything, settings["start_vergence_deg"], settings["offset_deg"],
                                            generator))
        start_deg, start_px = everything.vergence_deg.clone(), everything.vergence_error_px.clone()
        start_shift = everything.shift_px()
        ends = {name: _run(policy, pair, points, start_deg, scales, settings, bar) for name, policy in policies.items()}
        for name, end in ends.items():
            for j in range(len(points)):
                row = {"pair": pair.name, "policy": name, "start": kind, "x": int(points[j, 0]), "y": int(points[j, 1])}
                if truth:
                    row.update({
                        "ground_truth_px": round(float(everything.ground_truth_px[j]), 6),
                        "start_vergence_deg": round(float(start_deg[j]), 6),
                        "end_vergence_deg": round(float(end["end_deg"][j]), 6),
                        "start_error_px": round(float(start_px[j]), 6),
                        "vergence_error_px": round(float(end["error_px"][j]), 6),
                        "vergence_error_deg": round(float(end["error_deg"][j]), 6),
                        "plane_residual_px": round(float(rough[j]), 4), "unknown_fraction": round(float(unknown[j]), 4),
                        "window": "edge" if bool(edge[j]) else "smooth", "occluded": bool(occluded[j])})
                else:
                    row.update(start_vergence_deg=round(float(start_deg[j]), 6),
                               end_vergence_deg=round(float(end["end_deg"][j]), 6))
                row.update(ground_truth=truth, start_shift_px=round(float(start_shift[j]), 6),
                           end_shift_px=round(float(end["end_shift_px"][j]), 6), **_scores(ends, name, j, reference))
                rows.append(row)
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
    vergence_range_deg: Sequence[float] = VERGENCE_RANGE_DEG,
    scoring: Scoring | None = None,
    batch_size: int = 256,
    progress: bool = False,
) -> dict:
    """Each policy fixates points of each pair from both kinds of start (`START_KINDS`; the
    protocol's only on a pair without ground truth).

    Args:
        policies: ``{name: policy}``, each ``policy(observation, world) -> increments_deg [B]``.
        pairs: the stereo pairs (`aectorch.sim.stereo_pairs.read_pairs`), with ground truth or without.
        scales: the foveal scales the eyes see (the policies' encoders' scales).
        pair_scale: photo pixels per eye pixel.
        fixations: fixation points per pair (fewer where fewer qualify).
        steps: iterations per fixation (the protocol's fixation length, 30).
        seed: seeds the points and the starts.
        start_vergence_deg: the protocol's start vergence, a value or a ``(low, high)`` range.
        vergence_range_deg: the vergence's range, degrees (on a pair without ground truth, the
            part of it within ``scoring.search_deg``).
        scoring: what scores each fixation beside the ground truth and the search range without
            it (:class:`Scoring`: the coding reward, the reference policy, ``search_deg``);
            default ``Scoring()`` (the stability alone, `SEARCH_DEG`).
        batch_size: fixations at once.
        progress: show a progress bar.

    Returns:
        ``summary`` (:func:`_summaries`: per policy, per start kind, over all, smooth and edge
        windows and visible points, and ``no_movement``: the starts' errors; over the pairs with
        ground truth, empty when none has), ``per_pair`` (the same over all windows of each pair; a pair without
        ground truth: :func:`fixation_summary` per policy), ``per_fixation`` (one row per
        policy, start and point; ``ground_truth`` says whether its pair has it), the settings,
        and where some pair has no ground truth ``without_ground_truth``: those pairs, why
        the vergence test is absent, and ``summary``, :func:`fixation_summary` per policy over
        them (``no_movement``: the starts' reward).

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
    start = (float(start_vergence_deg),) * 2 if isinstance(start_vergence_deg, (int, float)) \
        else tuple(float(v) for v in start_vergence_deg)
    if not policies or not pairs:
        raise ValueError("evaluate_pairs needs at least one policy and one pair")
    scoring = Scoring() if scoring is None else scoring
    if scoring.reference is not None and scoring.reference not in policies:
        raise ValueError(f"scoring.reference {scoring.reference!r} is none of the policies {list(policies)}")
    settings = dict(pair_scale=pair_scale, fixations=fixations, steps=steps, seed=seed, start_vergence_deg=start,
                    offset_deg=OFFSET_DEG, vergence_range_deg=tuple(vergence_range_deg), min_contrast=MIN_CONTRAST,
                    batch_size=batch_size, scoring=scoring)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        kinds = sum(len(START_KINDS) if p.has_ground_truth else 1 for p in pairs)
        bar = tqdm(total=kinds * fixations * len(policies), desc="pairs", unit="fixation")
    rows = []
    for pair in pairs:
        rows += _pair_rows(pair, policies, scales, settings, bar)
    if bar is not None:
        bar.close()
    result = {"summary": _summaries([r for r in rows if r["ground_truth"]]) if any(p.has_ground_truth for p in pairs)
              else {},
              "per_pair": {pair.name: _pair_summary(pair, [r for r in rows if r["pair"] == pair.name])
                           for pair in pairs},
              "pairs": [{"name": p.name, "height": int(p.left.shape[0]), "width": int(p.left.shape[1]),
                         "fixations": sum(1 for r in rows if r["pair"] == p.name and r["start"] == START_KINDS[0]
                                          and r["policy"] == rows[0]["policy"]),
                         "ground_truth": p.has_ground_truth} for p in pairs],
              "scales": [s.name for s in scales], "steps": steps,
              "start_kinds": {"protocol": {"vergence_deg": list(start)}, "vergence_test": {"offset_deg": OFFSET_DEG}},
              "within_px": WITHIN_PX, "beyond_px": BEYOND_PX, "edge_residual_px": EDGE_RESIDUAL_PX,
              "edge_unknown_fraction": EDGE_UNKNOWN, **{k: settings[k] for k in ("pair_scale", "seed", "min_contrast")},
              "vergence_range_deg": list(vergence_range_deg), "per_fixation": rows}
    if not all(p.has_ground_truth for p in pairs):
        result["without_ground_truth"] = _without_truth(pairs, rows, settings)
    return result


def _pair_summary(pair: StereoPair, rows: list[dict]) -> dict:
    """One pair's summary: the errors' over all windows, or without ground truth `fixation_summary`."""
    if pair.has_ground_truth:
        return {name: {kind: summary["all"] for kind, summary in kinds.items()} for name, kinds in _summaries(rows).items()}
    return _truthless_summary(rows)


def _truthless_summary(rows: list[dict]) -> dict:
    """``{policy: {"protocol": fixation_summary}, "no_movement": {"protocol": {n, median_reward}}}``."""
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    out: dict = {name: {START_KINDS[0]: fixation_summary([r for r in rows if r["policy"] == name])} for name in policies}
    starts = [r for r in rows if policies and r["policy"] == policies[0]]
    out["no_movement"] = {START_KINDS[0]: {"n": len(starts), "median_reward": fixation_summary(
        [{"reward": r.get("start_reward")} for r in starts])["median_reward"]}}
    return out


def _without_truth(pairs: Sequence[StereoPair], rows: list[dict], settings: dict) -> dict:
    """The result's part on the pairs without ground truth."""
    settings = _search_settings(settings)
    low, high = _shift_range_px(settings)
    return {"pairs": [p.name for p in pairs if not p.has_ground_truth], "start_kinds": [START_KINDS[0]],
            "note": NO_VERGENCE_TEST, "stability_iterations": STABILITY_ITERATIONS, "stable_px": STABLE_PX,
            "reward": settings["scoring"].reward is not None, "reference": settings["scoring"].reference,
            "search_deg": list(settings["vergence_range_deg"]), "shift_range_px": [round(low, 4), round(high, 4)],
            "summary": _truthless_summary([r for r in rows if not r["ground_truth"]])}
