"""The accommodation experiment's read-outs (docs/results.md, "Accommodation"): the rewards against
defocus (``python -m aectorch.report focus-curve``), what a trained accommodation cue does against
defocus (``accommodation-policy``) and the accommodation runs against plain ones (``accommodation``).
"""

from __future__ import annotations

import json
import os
import statistics
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch

from aectorch.coding.focus import focus_reward, input_energy
from aectorch.framework import CueConfig, CueLearner
from aectorch.report.compare import _mean_sd
from aectorch.runs import EVALUATION, Run
from aectorch.sim import ActiveDepthEnv, PinholeCamera, TextureBank, TrialProtocol

__all__ = ["DEFOCUS_D", "DISTANCES_M", "accommodation_table", "distance_table", "focus_curve", "focus_measures", "policy_table",
           "train_focus_coder"]

#: The distances the focus curve codes each image at (m).
DISTANCES_M = (1.0, 1.5, 2.0, 2.5, 3.0)
#: The defocus grid of `policy_table` (dioptres, positive: focused nearer than the object).
DEFOCUS_D = (-0.8, -0.4, -0.2, 0.0, 0.2, 0.4, 0.8)
_KEYS = (("vergence MAE (deg)", lambda e: e["vergence_mae_deg"]),
         ("pursuit MAE (deg)", lambda e: e["pursuit_mae_deg"]),
         ("depth MAE (m)", lambda e: e["depth_mae_m"]),
         ("accommodation MAE (deg of blur)", lambda e: e.get("accommodation_mae_deg")),
         ("accommodation MAE (D)", lambda e: e.get("accommodation_focus", {}).get("mae_D")),
         ("accommodation MAE (px, full scale)", lambda e: e.get("accommodation_focus", {}).get("mae_px")),
         ("fixation ends within 0.25 px", lambda e: e.get("accommodation_focus", {}).get("within_0.25px")),
         ("fixation ends within 0.5 px", lambda e: e.get("accommodation_focus", {}).get("within_0.5px")))


def accommodation_table(groups: Mapping[str, Sequence[Run]], evaluation: str = EVALUATION,
                        per_distance: bool = False) -> list[str]:
    """Groups of runs side by side (e.g. with the accommodation cue and plain): the mean +- sd over
    each group's runs of the final state's vergence, pursuit and depth MAE and accommodation error
    (blur-disc degrees, dioptres, full-scale pixels, fractions within 0.25 and 0.5 px); with
    ``per_distance``, then per distance and group the accommodation error at the fixation ends in
    pixels: the mean |error| and the signed mean (negative: focused beyond the object), over the
    runs' trials (`distance_table`)."""
    evals = {name: [run.evaluation(evaluation) for run in runs] for name, runs in groups.items()}
    lines = ["| | " + " | ".join(f"{name} ({len(e)} seeds)" for name, e in evals.items()) + " |",
             "|---" * (len(evals) + 1) + "|"]
    for label, read in _KEYS:
        cells = []
        for results in evals.values():
            mean, sd = _mean_sd([read(result) for result in results])
            cells.append("-" if mean is None else f"{mean:.3f} +- {sd:.3f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + (["", *distance_table(evals)] if per_distance else [])


def distance_table(evals: Mapping[str, Sequence[Mapping]]) -> list[str]:
    """Per distance (rows) and group (columns): the accommodation error of the per-trial rows'
    fixation ends (``accommodation_errors_deg``) in full-scale pixels, mean |error| / signed mean
    over all the group's trials; groups without the error get ``-``."""
    per_px = PinholeCamera().degrees_per_pixel
    errors: dict[str, dict[float, list[float]]] = {}
    for name, results in evals.items():
        for result in results:
            for row in result.get("per_trial", []):
                if row.get("accommodation_errors_deg") is not None:
                    errors.setdefault(name, {}).setdefault(float(row["distance_m"]), []).extend(
                        e / per_px for e in row["accommodation_errors_deg"])
    if not errors:
        raise KeyError("no per-trial accommodation errors in these evaluations (a run with the accommodation cue)")
    distances = sorted({d for rows in errors.values() for d in rows})
    lines = ["| distance (m) | " + " | ".join(f"{name}: px, mean abs. / signed" for name in evals) + " |",
             "|---" * (len(evals) + 1) + "|"]
    for d in distances:
        cells = [f"{statistics.fmean(abs(e) for e in errors[n][d]):.2f} / {statistics.fmean(errors[n][d]):+.2f}"
                 if d in errors.get(n, {}) else "-" for n in evals]
        lines.append(f"| {d:g} | " + " | ".join(cells) + " |")
    return lines


def focus_measures(encoder, observation) -> dict[str, torch.Tensor]:
    """Per environment ``[B]``: the coding reward -sum e, the input-energy term sum 1/2 log E and
    the focus reward sum 1/2 log(E (1 - e)) (`aectorch.coding.focus`)."""
    out = encoder.encode(observation)
    energy = [input_energy(observation[s.name], s) for s in encoder.scales]
    errors = [code.error for code in out.codes]
    return {"coding": out.reward,
            "energy": torch.stack([(E + 1e-12).log().mean(-1) / 2 for E in energy], -1).sum(-1),
            "focus": focus_reward(energy, errors)}


def train_focus_coder(steps: int, spread: float, aperture_m: float, batch: int, seed: int):
    """A stereo coder (the default cue's scales) that learned for ``steps`` steps on the training
    textures, both eyes at the optimal vergence and focused uniformly within +-``spread`` D of the
    object (what an eye that learns to focus sees)."""
    encoder = CueLearner.build_encoder(CueConfig(), generator=torch.Generator().manual_seed(seed))
    env = ActiveDepthEnv(batch, protocol=TrialProtocol(aperture_m=aperture_m), seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    for _ in range(steps):
        index = torch.randint(len(env.textures), (batch,), generator=g)
        distance = 1.0 + 2.0 * torch.rand(batch, generator=g)
        env.set_trial(index, distance)
        env.hold("stereo")
        focus = (1.0 / distance + spread * (2 * torch.rand(batch, generator=g) - 1)).clamp_min(0.0)
        env.set_focus(focus[:, None].expand(batch, 2))
        encoder.learn_(encoder.encode(env.stereo_observation(encoder.scales)))
    env.close()
    return encoder


def _curve(encoder, textures: TextureBank, grid: Sequence[float], aperture_m: float) -> dict[str, list[float]]:
    n = len(textures)
    index = torch.arange(n).repeat_interleave(len(DISTANCES_M))
    distance = torch.tensor(DISTANCES_M).repeat(n)
    env = ActiveDepthEnv(len(index), protocol=TrialProtocol(aperture_m=aperture_m), textures=textures,
                         distances_m=DISTANCES_M, seed=0)
    env.set_trial(index, distance)
    env.hold("stereo")
    rows: dict[str, list[float]] = {"defocus_D": list(grid), "coding": [], "energy": [], "focus": []}
    with torch.no_grad():
        for d in grid:
            env.set_focus((1.0 / distance + d).clamp_min(0.0)[:, None].expand(len(index), 2))
            for name, value in focus_measures(encoder, env.stereo_observation(encoder.scales)).items():
                rows[name].append(float(value.mean()))
    env.close()
    return rows


def focus_curve(photos: str | os.PathLike, out: str | os.PathLike, steps: int = 300, batch: int = 16,
                spread: float = 1.0, aperture_m: float = 0.016, seed: int = 0) -> list[str]:
    """The rewards against defocus (-1 to +1 D): a coder trained as `train_focus_coder` codes the
    test textures and the photographs of ``photos`` at each defocus, at 1.0-3.0 m; the mean of
    each measure per defocus goes to ``out`` (a figure) and beside it as JSON; one line per set
    and measure says where it peaks."""
    from aectorch.figures import plot_focus_curve

    encoder = train_focus_coder(steps, spread, aperture_m, batch, seed)
    grid = [round(-1.0 + 0.1 * i, 1) for i in range(21)]
    result: dict[str, Any] = {
        "aperture_m": aperture_m, "steps": steps, "spread_D": spread, "seed": seed,
        "textures": _curve(encoder, TextureBank.default("test"), grid, aperture_m),
        "photographs": _curve(encoder, TextureBank.from_folder(photos, progress=False), grid, aperture_m)}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    plot_focus_curve(result, out)
    lines = []
    for name in ("textures", "photographs"):
        rows = result[name]
        for measure in ("coding", "energy", "focus"):
            values = rows[measure]
            peak = [d for d, v in zip(rows["defocus_D"], values) if v >= max(values) - 1e-9]
            lines.append(f"{name:12s} {measure:7s} peaks at {min(peak):+.1f}..{max(peak):+.1f} D  (at 0: "
                         f"{values[10]:.4f}, at -1: {values[0]:.4f}, at +1: {values[-1]:.4f})")
    return lines + [f"wrote {out}"]


def policy_table(learner, textures: int = 8) -> list[str]:
    """What a trained accommodation cue does against defocus: its greedy (mean) focus increment
    (degrees of blur disc) and its information reward, both eyes at the optimal vergence and
    focused off the object by each defocus of `DEFOCUS_D`, on the first ``textures`` test textures
    at 1, 2 and 3 m."""
    cue, n = learner.accommodation, textures
    env = ActiveDepthEnv(n, protocol=TrialProtocol(accommodation_start_D=0.0), textures=TextureBank.default("test"),
                         seed=0)
    lines = ["distance | " + " | ".join(f"{d:+.1f} D: increment (deg), reward" for d in DEFOCUS_D)]
    with torch.no_grad():
        for distance in (1.0, 2.0, 3.0):
            env.set_trial(torch.arange(n), torch.full((n,), distance))
            env.hold("stereo")
            cells = []
            for defocus in DEFOCUS_D:
                env.set_focus(torch.full((n, 2), 1.0 / distance + defocus).clamp_min(0.0))
                observation = env.stereo_observation(cue.encoder.scales)
                out = cue.encoder.encode(observation)
                sensed = env.proprioception(cue.config.proprioception) if cue.config.proprioception else None
                policy = cue.agent.log_policy(cue.features(out.features, sensed)).exp()
                increment = policy @ cue.agent.actions_deg.to(policy.dtype)
                cells.append(f"{float(increment.mean()):+.3f}, {float(cue._information(observation, out).mean()):.3f}")
            lines.append(f"{distance:.1f} m | " + " | ".join(cells))
    env.close()
    return lines
