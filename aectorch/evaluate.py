"""Evaluation of a trained :class:`~aectorch.framework.JointLearner`, separate from training.

Learning is frozen and both policies are greedy. Two tests:

- **the paper's test**: every texture x distance runs one full trial (a leftward and a rightward
  fixation of ``h`` iterations) from the standard start state; the pursuit and vergence errors
  at the last iteration of each fixation (eq. 9) and the depth MLP's error on the trial's ``q``
  are collected;
- **the earlier models' vergence test**: the left eye is put at its optimal pan and the right
  eye at a random vergence offset (uniform in ``+-offset_deg``), then ``steps`` greedy
  iterations run; the vergence error at the last step is summarised as RMSE, median and 4 x IQR
  in degrees and in pixels (at the camera's degrees per pixel).
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from aectorch.sim import DEFAULT_DISTANCES_M, ActiveDepthEnv, TextureBank

__all__ = ["evaluate", "summarise"]


def summarise(errors: Tensor) -> dict:
    """Mean absolute error, median absolute error, RMSE, median, 4 x IQR and count of ``errors``."""
    e = errors.detach().double().reshape(-1).cpu()
    e = e[torch.isfinite(e)]
    if e.numel() == 0:
        return {"mae": math.nan, "median_abs": math.nan, "rmse": math.nan, "median": math.nan,
                "iqr4": math.nan, "n": 0}
    q1, q3 = torch.quantile(e, torch.tensor([0.25, 0.75], dtype=torch.float64)).tolist()
    return {
        "mae": float(e.abs().mean()),
        "median_abs": float(e.abs().median()),
        "rmse": float(e.square().mean().sqrt()),
        "median": float(e.median()),
        "iqr4": 4.0 * (q3 - q1),
        "n": int(e.numel()),
    }


def _conditions(num_textures: int, distances: Sequence[float]) -> tuple[Tensor, Tensor]:
    index = torch.arange(num_textures).repeat_interleave(len(distances))
    distance = torch.tensor(list(distances), dtype=torch.float64).repeat(num_textures)
    return index, distance


def evaluate(
    learner,
    textures: TextureBank | Tensor,
    *,
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    renderer: str = "torch",
    batch_size: int = 256,
    fixation_iterations: int = 30,
    shift_m: float = 0.1,
    vergence_test: bool = True,
    offset_deg: float = 2.0,
    steps: int = 20,
    seed: int = 0,
    progress: bool = False,
) -> dict:
    """Evaluate ``learner`` greedily with all learning frozen; returns a JSON-ready dict.

    Args:
        learner: a :class:`~aectorch.framework.JointLearner`; its weights and statistics are not
            modified (it runs with ``learn=False``).
        textures: the evaluation textures (e.g. ``TextureBank.from_folder(...)`` of photographs
            it never trained on).
        distances_m: object distances; every texture is tested at every distance.
        renderer: ``"torch"`` or ``"pyrender"``.
        batch_size: environments simulated at once.
        fixation_iterations, shift_m: the trial protocol (paper: 30, 0.1 m).
        vergence_test: also run the earlier models' vergence test.
        offset_deg, steps: its initial vergence offsets (uniform in +-offset_deg) and step count.
        seed: seeds the vergence test's offsets.
        progress: show a progress bar.

    Returns:
        ``pursuit_mae_deg``, ``vergence_mae_deg``, ``depth_mae_m`` and full summaries
        (:func:`summarise`) under ``pursuit``, ``vergence``, ``depth``; a per-distance
        breakdown; ``trials``; and ``vergence_test`` when asked.
    """
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    distances = [float(d) for d in distances_m]
    if not distances or any(not math.isfinite(d) or d <= 0 for d in distances):
        raise ValueError(f"distances_m must be distances > 0 (metres), got {distances_m!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be an int >= 1, got {batch_size!r}")
    parameter = next(learner.parameters())
    device, dtype = parameter.device, parameter.dtype
    index, distance = _conditions(len(bank), distances)
    total = index.numel()
    chunks = [(start, min(start + batch_size, total)) for start in range(0, total, batch_size)]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total * (2 if vergence_test else 1), desc="evaluate", unit="trial")

    envs: dict[tuple[int, int], ActiveDepthEnv] = {}

    def env_for(size: int, h: int) -> ActiveDepthEnv:
        key = (size, h)
        if key not in envs:
            envs[key] = ActiveDepthEnv(
                size, textures=bank, renderer=renderer, distances_m=distances,
                fixation_iterations=h, shift_m=shift_m, seed=seed, device=device, dtype=dtype,
            )
        return envs[key]

    pursuit, vergence, depth_error = [], [], []
    with torch.no_grad():
        for start, stop in chunks:
            env = env_for(stop - start, fixation_iterations)
            env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
            learner.forget_transitions()
            finals_p, finals_v = [], []
            while True:
                record = learner.iteration(env, learn=False, greedy=True)
                if record.fixation_end:
                    finals_p.append(record.pursuit_error_deg)
                    finals_v.append(record.vergence_error_deg)
                if record.trial_end:
                    break
            pursuit.append(torch.stack(finals_p, 1))  # [b, 2 fixations]
            vergence.append(torch.stack(finals_v, 1))
            depth_error.append(record.depth_prediction_m - record.distance_m)
            if bar is not None:
                bar.update(stop - start)
    pursuit, vergence = torch.cat(pursuit).cpu(), torch.cat(vergence).cpu()
    depth_error = torch.cat(depth_error).cpu()
    result = {
        "pursuit_mae_deg": summarise(pursuit)["mae"],
        "vergence_mae_deg": summarise(vergence)["mae"],
        "depth_mae_m": summarise(depth_error)["mae"],
        "pursuit": summarise(pursuit),
        "vergence": summarise(vergence),
        "depth": summarise(depth_error),
        "trials": total,
        "textures": len(bank),
        "distances_m": distances,
        "per_distance": [],
    }
    for d in distances:
        mask = (distance - d).abs() < 1e-9
        result["per_distance"].append({
            "distance_m": d,
            "pursuit_mae_deg": summarise(pursuit[mask])["mae"],
            "vergence_mae_deg": summarise(vergence[mask])["mae"],
            "depth_mae_m": summarise(depth_error[mask])["mae"],
        })

    if vergence_test:
        generator = torch.Generator().manual_seed(seed)
        finals = []
        with torch.no_grad():
            for start, stop in chunks:
                env = env_for(stop - start, steps)
                env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
                left = env.optimal_left_pan_deg()
                offsets = (torch.rand(stop - start, generator=generator, dtype=torch.float64) * 2 - 1) * offset_deg
                right = env.optimal_right_pan_deg(left) + offsets.to(device=device, dtype=dtype)
                env.set_pan_deg(torch.stack((left, right), -1))
                learner.forget_transitions()
                for _ in range(steps):
                    record = learner.iteration(env, learn=False, greedy=True)
                finals.append(record.vergence_error_deg.cpu())
                if bar is not None:
                    bar.update(stop - start)
        final = torch.cat(finals)
        per_pixel = env.camera.degrees_per_pixel
        deg = summarise(final)
        result["vergence_test"] = {
            "offset_deg": offset_deg,
            "steps": steps,
            "degrees": deg,
            "pixels": {k: (v / per_pixel if k != "n" else v) for k, v in deg.items()},
        }
    if bar is not None:
        bar.close()
    for env in envs.values():
        close = getattr(env.renderer, "close", None)
        if close is not None:
            close()
    return result
