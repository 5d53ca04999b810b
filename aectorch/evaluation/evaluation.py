"""``evaluate``: the paper's test and the earlier models' vergence test, as a JSON-ready report."""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from aectorch.choices import Policy
from aectorch.evaluation.summary import (
    BEYOND_DEG, LAST_SUFFIX, WITHIN_DEG, fractions, movements, per_trial_rows, summarise,
)
from aectorch.evaluation.trials import (
    EVAL_BATCH_SIZE, _all_conditions, _check_trial_arguments, _paper_trials, _trial_session, frozen_iterations,
    placement,
)
from aectorch.sim import DEFAULT_DISTANCES_M, PinholeCamera, TextureBank, TrialProtocol, resolve_protocol

__all__ = ["accommodation_report", "evaluate"]


def evaluate(
    learner,
    textures: TextureBank | Tensor,
    *,
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    protocol: TrialProtocol | None = None,
    batch_size: int = EVAL_BATCH_SIZE,
    vergence_test: bool = True,
    offset_deg: float = 2.0,
    steps: int = 20,
    seed: int = 0,
    progress: bool = False,
    policy: str = "greedy",
) -> dict:
    """Evaluate ``learner`` greedily with all learning frozen; returns a JSON-ready dict.

    Args:
        learner: a :class:`~aectorch.framework.JointLearner`; its weights, statistics and generator
            are not modified (it runs with ``learn=False``); its pending transitions are dropped.
        textures: the evaluation textures (e.g. ``TextureBank.from_folder(...)`` of photographs
            it never trained on).
        distances_m: object distances; every texture is tested at every distance.
        protocol: the trial protocol (`aectorch.sim.TrialProtocol`; default its defaults, the
            training's); a learner is evaluated under the protocol it trained in.
        batch_size: environments simulated at once.
        vergence_test: also run the earlier models' vergence test.
        offset_deg, steps: its initial vergence offsets (uniform in +-offset_deg) and step count.
        seed: seeds the vergence test's offsets.
        progress: show a progress bar.
        policy: ``"greedy"`` (the argmax action; the evaluation protocol) or ``"sampled"``
            (actions drawn from the softmax policies, as in training, from the learner's own
            generator), to measure what greediness costs.

    Returns:
        ``pursuit_mae_deg``, ``vergence_mae_deg``, ``depth_mae_m`` and full summaries
        (:func:`summarise`) under ``pursuit``, ``vergence``, ``depth``; ``fractions`` (of the
        fixation ends within ``WITHIN_DEG`` and beyond ``BEYOND_DEG``, :func:`fractions`);
        ``last5``: the same MAEs and fractions for the mean of each fixation's last 5 iterations;
        per-distance and per-texture breakdowns (``per_distance``, ``per_texture``); one row per
        trial (``per_trial``, :func:`per_trial_rows`); ``trials``; and ``vergence_test`` when asked.
    """
    distances, policy = _check_trial_arguments(distances_m, batch_size, policy)
    protocol = resolve_protocol(protocol)
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    index, distance = _all_conditions(len(bank), distances)
    greedy = policy == Policy.greedy
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=index.numel() * (2 if vergence_test else 1), desc="evaluate", unit="trial")
    # Sampled actions come from the learner's generator: the session seeds it from ``seed`` for
    # the evaluation and gives the learner its own state back afterwards.
    with _trial_session(learner, bank, distances, protocol, seed, bar) as env_for:
        paper = _paper_trials(learner, index, distance, env_for, batch_size, protocol.fixation_iterations, greedy, bar)
        result = _report(paper, bank.names, distances)
        if "accommodation" in movements(paper):
            result["accommodation_focus"] = accommodation_report(paper["accommodation_deg"], protocol.aperture_m)
            for row in result["per_trial"]:
                row["accommodation_errors_D"] = [e / math.degrees(protocol.aperture_m)
                                                 for e in row["accommodation_errors_deg"]]
        if vergence_test:
            final, per_pixel = _vergence_test(learner, index, distance, env_for, batch_size, offset_deg, steps,
                                              seed, greedy, bar)
            deg = summarise(final)
            ends = final.detach().double().reshape(-1).abs()
            result["vergence_test"] = {
                "offset_deg": offset_deg,
                "steps": steps,
                "degrees": deg,
                "pixels": {k: (v / per_pixel if k != "n" else v) for k, v in deg.items()},
                "max_abs_deg": float(ends.max()) if ends.numel() else math.nan,
                "beyond_1deg": float((ends > 1.0).double().mean()) if ends.numel() else math.nan,
            }
    result["policy"] = str(policy)
    return result


def accommodation_report(errors_deg: Tensor, aperture_m: float) -> dict:
    """The accommodation error at the fixation ends ``errors_deg`` (the blur disc's signed
    diameter, degrees) in dioptres (``aperture_m``'s degrees per dioptre) and in pixels of the
    finest scale (the camera's, 0.22 deg): the mean |error| in each, and the fractions of fixation
    ends whose blur is within 0.25 and 0.5 px (the accommodation targets: docs/results.md)."""
    e = errors_deg.detach().double().reshape(-1).cpu().abs()
    e = e[torch.isfinite(e)]
    px = e / PinholeCamera().degrees_per_pixel
    return {"mae_D": float(e.mean() / math.degrees(aperture_m)), "mae_px": float(px.mean()),
            "within_0.25px": float((px <= 0.25).double().mean()), "within_0.5px": float((px <= 0.5).double().mean()),
            "aperture_m": aperture_m, "n": int(e.numel())}


def _report(paper: dict[str, Tensor], names: Sequence[str], distances: list[float]) -> dict:
    """The paper's test's summaries: overall, per distance, per texture and per trial."""
    index, distance = paper["texture_index"], paper["distance_m"]
    eyes = {m: paper[f"{m}_deg"] for m in movements(paper)}
    errors = {**{f"{m}_mae_deg": e for m, e in eyes.items()}, "depth_mae_m": paper["depth_error_m"]}

    def maes(mask: Tensor) -> dict:
        """The MAEs of the trials in ``mask`` (both fixations of each), and the fractions of their
        fixation ends on target and failed."""
        return {**{key: summarise(x[mask])["mae"] for key, x in errors.items()},
                "fractions": fractions({m: e[mask] for m, e in eyes.items()})}

    summaries = {key: summarise(x) for key, x in errors.items()}
    lasts = {m: paper[f"{m}{LAST_SUFFIX}"] for m in eyes if f"{m}{LAST_SUFFIX}" in paper}
    return {
        "last5": {**{f"{m}_mae_deg": summarise(e)["mae"] for m, e in lasts.items()}, "fractions": fractions(lasts)},
        **{key: summary["mae"] for key, summary in summaries.items()},
        **{key.split("_mae_")[0]: summary for key, summary in summaries.items()},
        "trials": index.numel(),
        "textures": len(names),
        "distances_m": distances,
        "per_distance": [{"distance_m": d, **maes((distance - d).abs() < 1e-9)} for d in distances],
        "per_texture": [{"texture": name, **maes(index == i)} for i, name in enumerate(names)],
        "fractions": fractions(eyes),
        "within_deg": WITHIN_DEG,
        "beyond_deg": BEYOND_DEG,
        "per_trial": per_trial_rows(paper, names),
    }


def _vergence_test(learner, index: Tensor, distance: Tensor, env_for, batch_size: int, offset_deg: float,
                   steps: int, seed: int, greedy: bool, bar) -> tuple[Tensor, float]:
    """The earlier models' vergence test: the left eye at its optimal pan, the right one off by a
    uniform offset in +-``offset_deg``, then ``steps`` frozen iterations. Returns the final
    vergence errors and the camera's degrees per pixel."""
    device, dtype = placement(learner)
    total = index.numel()
    generator = torch.Generator().manual_seed(seed)
    finals = []
    for start in range(0, total, batch_size):
        stop = min(start + batch_size, total)
        env = env_for(stop - start, steps, instant=True)
        env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
        left = env.optimal_left_pan_deg()
        offsets = (torch.rand(stop - start, generator=generator, dtype=torch.float64) * 2 - 1) * offset_deg
        right = env.optimal_right_pan_deg(left) + offsets.to(device=device, dtype=dtype)
        env.set_pan_deg(torch.stack((left, right), -1))
        for record in frozen_iterations(learner, env, greedy=greedy, iterations=steps):
            pass
        finals.append(record.errors_deg["vergence"].cpu())
        if bar is not None:
            bar.update(stop - start)
    return torch.cat(finals), env.camera.degrees_per_pixel
