"""Depth read-outs of a checkpoint's eye movements and the eye precision depth needs
(``python -m aectorch.report depth-readout``, ``depth-tolerance``)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import torch

from aectorch.evaluation import depth_readouts, depth_tolerance, run_trials
from aectorch.sim import DEFAULT_DISTANCES_M, DEFAULT_PROTOCOL, ActiveDepthEnv, TrialProtocol

__all__ = ["depth_readout", "readout_lines", "tolerance_lines", "tolerance_table"]

#: The geometric decoders' candidate distances (metres): 0.5 mm steps.
GRID_M = (0.5, 5.0, 0.0005)


def _geometry(shift_m: float) -> ActiveDepthEnv:
    """An environment for the head's geometry alone (``ideal_q_deg``), float64; nothing is rendered."""
    return ActiveDepthEnv(1, protocol=TrialProtocol(shift_m=shift_m), textures=torch.zeros(1, 8, 8,
                                                                                           dtype=torch.float64),
                          dtype=torch.float64)


def tolerance_table(distances_m: Sequence[float] = DEFAULT_DISTANCES_M[::5], *, depth_m: float = 0.05,
                    shift_m: float = DEFAULT_PROTOCOL.shift_m) -> list[dict]:
    """How precise the eyes must be for a depth error of ``depth_m``: geometry only, no checkpoint.

    Per distance, the error (deg) in one input of q (q1, q3: the left pan after the leftward and
    the rightward shift; q2, q4: the vergences) that moves the exact geometry's depth
    (`ActiveDepthEnv.ideal_q_deg`) by ``depth_m``, and in all four alike combined by least squares
    (`aectorch.evaluation.depth_tolerance`).
    """
    return depth_tolerance(_geometry(shift_m), distances_m, depth_m)


def _markdown(rows: list[dict], keys: list[str], first: str, digits: int) -> list[str]:
    lines = ["| " + " | ".join([first, *keys]) + " |", "|" + "---|" * (len(keys) + 1)]
    for row in rows:
        lines.append("| " + " | ".join([str(row[first])] + [f"{row[k]:.{digits}f}" for k in keys]) + " |")
    return lines


def tolerance_lines(rows: list[dict], depth_m: float = 0.05) -> list[str]:
    """`tolerance_table` as markdown."""
    return [f"eye error (deg) that moves the exact geometry's depth by {depth_m:g} m",
            *_markdown(rows, ["q1", "q2", "q3", "q4", "all four alike"], "distance_m", 3)]


def _trials(learner, cfg, sets, calibration: int, cache: str | None, key: str) -> dict:
    """The greedy trials of every set (and the calibration trials), from ``cache`` when it has them."""
    from aectorch.runtime import build_textures, calibration_conditions, trial_options

    if cache and Path(cache).exists():
        stored = torch.load(cache, weights_only=True)  # tensors and plain containers: never runs code
        if stored["checkpoint"] == key and set(stored["sets"]) >= {n for n, *_ in sets} \
                and stored["calibration"] >= calibration:
            return stored["sets"]
    common = trial_options(cfg)
    out = {name: run_trials(learner, bank, distances_m=distances, progress=name, **common)
           for name, bank, distances in sets}
    if calibration:
        train = build_textures(cfg.env.textures, "train", cfg)
        distances = [float(x) for x in cfg.env.distances_m]
        conditions = calibration_conditions(calibration, len(train), distances)
        out["calibration"] = run_trials(learner, train, distances_m=distances, seed=cfg.seed,
                                        conditions=conditions, progress="calibration", **common)
    if cache:
        torch.save({"checkpoint": key, "sets": out, "calibration": calibration}, cache)
    return out


def _fitted(learner, cfg, trials: dict, names: list[str], calibration: Sequence[int]) -> dict:
    """Each set's predictions of the MLP and of the MLP refitted on the first N calibration trials
    (alone, and with the run's stored training trials); the learner is left as it was."""
    fitted = {name: {"MLP": learner.predict_depth(trials[name]["q_deg"]).cpu()} for name in names}
    original = {k: v.clone() for k, v in learner.depth.state_dict().items()}
    trained = learner.depth_trained.clone()
    for count in calibration:
        q, d = trials["calibration"]["q_deg"][:count], trials["calibration"]["distance_m"][:count]
        both = (torch.cat((learner.depth_inputs.cpu().double(), q.double())),
                torch.cat((learner.depth_targets.cpu().double(), d.double())))
        for label, data in ((f"calibrated {count}", (q, d)), (f"calibrated {count} + training", both)):
            learner.calibrate_depth(*data, seed=cfg.seed)
            for name in names:
                fitted[name][label] = learner.predict_depth(trials[name]["q_deg"]).cpu()
            learner.depth.load_state_dict(original)
            learner.depth_trained.copy_(trained)
    return fitted


def depth_readout(checkpoint: str | Path, photos: str | Path | None = None, calibration: Sequence[int] = (),
                  cache: str | Path | None = None) -> dict:
    """How a checkpoint's depth error splits between the eyes and the read-out, on the same eye movements.

    Runs the greedy, frozen trials once: the checkpoint's evaluation (the run's ``eval.textures``
    at ``eval.distances_m``), with ``--photos`` a folder of photographs at 1.0-3.0 m in 0.1 m steps
    (as ``python -m aectorch.evaluate``), and the largest ``--calibration`` count of greedy trials on
    the training textures (``train.depth_calibration_trials``' design: the first N are its N).
    ``--cache`` keeps them in a file and reuses it. Then compares the depth MAE (m) of read-outs of
    the same final eye movements: ``MLP`` (the checkpoint's, as evaluated); ``calibrated N`` (refitted
    on the first N calibration trials, what ``train.depth_calibration_trials=N`` gives) and
    ``calibrated N + training`` (on them and the run's stored training trials); the exact geometry's
    decoders and the Gaussian floor (`aectorch.evaluation.depth_readouts`). Also the eye error
    that moves the geometry's depth by 0.05 m at the evaluation's distances (`tolerance_table`).
    """
    from aectorch.runtime import build_textures, load_learner

    if any(n < 10 for n in calibration):
        raise ValueError(f"--calibration counts must be at least 10 (a fit needs 10), got {list(calibration)}")
    cfg, learner = load_learner(checkpoint)
    sets = [("textures", build_textures(cfg.eval.textures, "test", cfg), [float(x) for x in cfg.eval.distances_m])]
    if photos:
        sets.append(("photos", build_textures(str(photos), "test", cfg), list(DEFAULT_DISTANCES_M)))
    # What the cached trials depend on besides the calibration count: the checkpoint and the photographs.
    key = f"{os.path.abspath(checkpoint)}|{os.path.abspath(photos) if photos else ''}"
    trials = _trials(learner, cfg, sets, max(calibration, default=0), None if cache is None else str(cache), key)
    names = [name for name, *_ in sets]
    fitted = _fitted(learner, cfg, trials, names, calibration)
    env = _geometry(cfg.env.shift_m)
    grid_m = torch.arange(GRID_M[0], GRID_M[1] + 1e-9, GRID_M[2], dtype=torch.float64)
    result: dict[str, Any] = {"checkpoint": str(checkpoint)}
    for name in names:
        result[name] = depth_readouts(trials[name], env, grid_m, fitted[name])
    result["tolerance_deg_for_0.05_m"] = depth_tolerance(env, sets[0][2])
    return result


def readout_lines(result: dict) -> list[str]:
    """`depth_readout`'s result as markdown: a table per set, then the tolerance."""
    lines = []
    for name, value in result.items():
        if not isinstance(value, dict) or "depth_mae_m" not in value:
            continue
        keys = list(value["depth_mae_m"])
        lines += ["", f"{name}: depth MAE (m) of each read-out of the same final eye movements, {value['trials']} trials",
                  *_markdown([{"distance_m": "all", **value["depth_mae_m"]}, *value["per_distance"]], keys,
                             "distance_m", 3)]
    return [*lines[1:], "", *tolerance_lines(result["tolerance_deg_for_0.05_m"])]
