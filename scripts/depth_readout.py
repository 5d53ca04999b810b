"""How the depth error splits between the eyes and the read-out, on the same eye movements.

    .venv/bin/python scripts/depth_readout.py <run>/best.pt [--photos data/heldout-photos]
        [--calibration 210 420 840] [--cache trials.pt] [--json out.json]

The eye movements of greedy, frozen trials do not depend on the depth MLP, so this runs them
once and then compares read-outs of the same final eye movements ``q`` (q1..q4, the MLP's
inputs). Trials: the checkpoint's evaluation (``train.py``'s: the run's ``eval.textures`` at
``eval.distances_m``), with ``--photos`` a folder of photographs at 1.0-3.0 m in 0.1 m steps (as
``python -m aectorch.evaluate``), and the largest ``--calibration`` count of greedy trials on the
training textures (``train.depth_calibration_trials``'s spread design, whose first N trials are
the design for N). ``--cache`` keeps them in a file and reuses it. Read-outs:

- ``MLP``: the checkpoint's depth MLP, as evaluated;
- ``calibrated N``: that MLP refitted on the first N calibration trials
  (``JointLearner.calibrate_depth``, as ``train.depth_calibration_trials=N`` does);
- ``calibrated N + training``: refitted on them and the run's stored training trials together;
- ``vergence``, ``pursuit``, ``all four``: the head's exact geometry
  (`ActiveDepthEnv.ideal_q_deg`) instead of an MLP: the distance on a 0.5 mm grid whose perfect
  ``q`` is nearest to the trial's, in the L1 distance weighted by each input's robust error
  scale (1.4826 x the median absolute deviation of ``q - q_ideal(true distance)`` over the
  evaluated trials), from the two vergence inputs, the two pursuit inputs, or all four. It
  ignores the systematic part of the eyes' errors, which a fitted read-out can learn;
- ``Gaussian floor``: not a read-out but the mean absolute depth error of the best unbiased one
  if the four inputs' errors were independent, Gaussian, of those robust scales and without
  bias: ``sqrt(2 / pi) / ||(d q_ideal / d distance) / scale||`` at each trial's distance (the
  eyes' heavier tails and biases make real read-outs worse; an MLP fitted to the same trials'
  distribution can learn part of the bias).

Also prints, per distance, the eye error (degrees, in one input alone; and in all four alike,
combined by least squares) that moves the exact geometry's depth by 0.05 m.
"""

from __future__ import annotations

import argparse
import json
import math
import os

import torch

DECODERS = {"vergence": (1, 3), "pursuit": (0, 2), "all four": (0, 1, 2, 3)}


def decode(q: torch.Tensor, grid_m: torch.Tensor, ideal: torch.Tensor, scale: torch.Tensor,
           inputs: tuple[int, ...], chunk: int = 64) -> torch.Tensor:
    """The grid distance whose ideal q (``ideal[G, 4]``) is nearest to each ``q[N, 4]`` (weighted L1)."""
    cols = list(inputs)
    out = []
    for part in q.split(chunk):
        cost = ((part[:, None, cols] - ideal[None, :, cols]).abs() / scale[cols]).sum(-1)  # [n, G]
        out.append(grid_m[cost.argmin(-1)])
    return torch.cat(out)


def _slope(env, distance_m: torch.Tensor) -> torch.Tensor:
    """d q_ideal / d distance ``[N, 4]``, degrees per metre (central differences)."""
    return (env.ideal_q_deg(distance_m + 1e-4) - env.ideal_q_deg(distance_m - 1e-4)) / 2e-4


def readouts(trials: dict, env, grid_m: torch.Tensor, fitted: dict[str, torch.Tensor]) -> dict:
    """Depth MAE (m) of each read-out, overall and per distance.

    ``fitted`` maps a name to the depth predictions ``[N]`` of a fitted read-out; the exact-geometry
    decoders are added here.
    """
    q = trials["q_deg"].double()
    d = trials["distance_m"].double()
    ideal = env.ideal_q_deg(grid_m)
    residual = q - env.ideal_q_deg(d)
    centred = residual - residual.median(0).values
    scale = (1.4826 * centred.abs().median(0).values).clamp_min(1e-4)
    errors = {name: (p.double() - d).abs() for name, p in fitted.items()}
    for name, inputs in DECODERS.items():
        errors[name] = (decode(q, grid_m, ideal, scale, inputs) - d).abs()
    # Least squares over the four inputs with independent Gaussian errors of these scales, and
    # no bias: the depth error's sd is 1 / ||slope / scale||, its mean absolute value sqrt(2/pi) sd.
    slope = _slope(env, d)
    errors["Gaussian floor"] = math.sqrt(2 / math.pi) / (slope / scale).norm(dim=-1)
    distances = sorted({round(float(x), 4) for x in d})
    return {
        "trials": int(d.numel()),
        "eye_error_scale_deg": dict(zip(("q1", "q2", "q3", "q4"), scale.tolist())),
        "eye_error_median_deg": dict(zip(("q1", "q2", "q3", "q4"), residual.median(0).values.tolist())),
        "depth_mae_m": {k: float(v.mean()) for k, v in errors.items()},
        "per_distance": [{"distance_m": x, **{k: float(v[(d - x).abs() < 1e-6].mean()) for k, v in errors.items()}}
                         for x in distances],
    }


def tolerance(env, distances: list[float], depth_m: float = 0.05) -> list[dict]:
    """Per distance: the eye error (deg) that moves the geometry's depth by ``depth_m``."""
    d = torch.tensor(distances, dtype=torch.float64)
    slope = _slope(env, d)
    rows = []
    for x, s in zip(distances, slope):
        row = {"distance_m": x}
        row.update({f"q{j + 1}": depth_m * float(s[j].abs()) for j in range(4)})
        row["all four alike"] = depth_m * float(s.norm())  # least squares over four equal errors
        rows.append(row)
    return rows


def _table(rows: list[dict], keys: list[str], first: str, digits: int) -> str:
    lines = ["| " + " | ".join([first, *keys]) + " |", "|" + "---|" * (len(keys) + 1)]
    for row in rows:
        lines.append("| " + " | ".join([str(row[first])] + [f"{row[k]:.{digits}f}" for k in keys]) + " |")
    return "\n".join(lines)


def _trials(learner, cfg, sets, calibration: int, cache: str | None, key: str) -> dict:
    """The greedy trials of every set (and the calibration trials), from ``cache`` when it has them."""
    from pathlib import Path

    from aectorch.evaluation import run_trials
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--photos", default=None, help="also run on this folder of images")
    parser.add_argument("--calibration", type=int, nargs="*", default=[],
                        help="calibration trial counts to compare (each >= 10)")
    parser.add_argument("--cache", default=None, help="keep the trials in this file (and reuse it)")
    parser.add_argument("--json", default=None, help="write the result here too")
    args = parser.parse_args(argv)
    if any(n < 10 for n in args.calibration):
        parser.error(f"--calibration counts must be at least 10 (a fit needs 10), got {args.calibration}")

    from aectorch.runtime import build_textures, load_learner
    from aectorch.sim import DEFAULT_DISTANCES_M, ActiveDepthEnv

    torch.set_num_threads(1)
    cfg, learner = load_learner(args.checkpoint)
    test = build_textures(cfg.eval.textures, "test", cfg)
    sets = [("textures", test, [float(x) for x in cfg.eval.distances_m])]
    if args.photos:
        sets.append(("photos", build_textures(args.photos, "test", cfg), list(DEFAULT_DISTANCES_M)))
    # What the cached trials depend on besides the calibration count: the checkpoint and the photographs.
    key = f"{os.path.abspath(args.checkpoint)}|{os.path.abspath(args.photos) if args.photos else ''}"
    trials = _trials(learner, cfg, sets, max(args.calibration, default=0), args.cache, key)

    names = [name for name, *_ in sets]
    fitted = {name: {"MLP": learner.predict_depth(trials[name]["q_deg"]).cpu()} for name in names}
    original = {k: v.clone() for k, v in learner.depth.state_dict().items()}
    trained = learner.depth_trained.clone()
    for count in args.calibration:
        q, d = trials["calibration"]["q_deg"][:count], trials["calibration"]["distance_m"][:count]
        both = (torch.cat((learner.depth_inputs.cpu().double(), q.double())),
                torch.cat((learner.depth_targets.cpu().double(), d.double())))
        for label, data in ((f"calibrated {count}", (q, d)), (f"calibrated {count} + training", both)):
            learner.calibrate_depth(*data, seed=cfg.seed)
            for name in names:
                fitted[name][label] = learner.predict_depth(trials[name]["q_deg"]).cpu()
            learner.depth.load_state_dict(original)
            learner.depth_trained.copy_(trained)

    env = ActiveDepthEnv(1, textures=test, shift_m=cfg.env.shift_m, dtype=torch.float64)
    grid_m = torch.arange(0.5, 5.0 + 1e-9, 0.0005, dtype=torch.float64)
    result = {"checkpoint": args.checkpoint}
    for name in names:
        result[name] = readouts(trials[name], env, grid_m, fitted[name])
        keys = list(result[name]["depth_mae_m"])
        print(f"\n{name}: depth MAE (m) of each read-out of the same final eye movements, "
              f"{result[name]['trials']} trials")
        print(_table([{"distance_m": "all", **result[name]["depth_mae_m"]}, *result[name]["per_distance"]],
                     keys, "distance_m", 3))
    result["tolerance_deg_for_0.05_m"] = tolerance(env, sets[0][2])
    print("\neye error (deg) that moves the exact geometry's depth by 0.05 m")
    print(_table(result["tolerance_deg_for_0.05_m"], ["q1", "q2", "q3", "q4", "all four alike"], "distance_m", 3))
    line = json.dumps(result)
    print(line)
    if args.json:
        with open(args.json, "w") as f:
            f.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
