"""Refit a checkpoint's depth MLP on greedy trials of the training textures; evaluate the depth.

    .venv/bin/python scripts/depth_calibration.py <run>/best.pt --trials 210 [--design spread|grid]
        [--data greedy|both] [--photos data/heldout-photos] [--json out.json]

The experiment behind ``train.depth_calibration_trials`` (docs/results.md, "Depth calibration").
``--design spread`` (what ``train.py`` does): trial i shows training texture i mod T at distance
i mod the number of ``env.distances_m``. ``--design grid``: the first ``trials / len(distances)``
textures, each at every distance. ``--data greedy`` refits the MLP on the calibration trials alone
(what ``train.py`` does), ``both`` on the run's stored training trials and them together. Then the
depth MAE, before and after, of the greedy evaluation of ``train.py`` (the run's ``eval.textures``
at ``eval.distances_m``) and, with ``--photos``, on a folder of photographs at 1.0-3.0 m in
0.1 m steps (as ``python -m aectorch.evaluate`` with its defaults).
The eye movements are the same before and after: only the MLP changes.
"""

from __future__ import annotations

import argparse
import json
import sys

import torch


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--trials", type=int, default=210, help="calibration trials (default 210)")
    parser.add_argument("--design", choices=("spread", "grid"), default="spread")
    parser.add_argument("--data", choices=("greedy", "both"), default="greedy")
    parser.add_argument("--photos", default=None, help="also evaluate on this folder of images")
    parser.add_argument("--json", default=None, help="write the result here too")
    args = parser.parse_args(argv)
    if args.trials < 10:
        parser.error(f"--trials must be at least 10 (a fit needs 10), got {args.trials}")

    from aectorch.evaluation import evaluate, run_trials
    from aectorch.runtime import build_textures, calibration_conditions, load_learner, trial_options
    from aectorch.sim import DEFAULT_DISTANCES_M

    torch.set_num_threads(1)
    cfg, learner = load_learner(args.checkpoint)
    train = build_textures(cfg.env.textures, "train", cfg)
    distances = [float(d) for d in cfg.env.distances_m]
    try:
        conditions = calibration_conditions(args.trials, len(train), distances, design=args.design)
    except ValueError as err:
        parser.error(str(err))
    common = trial_options(cfg)
    sets = [("textures", build_textures(cfg.eval.textures, "test", cfg), list(cfg.eval.distances_m))]
    if args.photos:
        sets.append(("photos", build_textures(args.photos, "test", cfg), list(DEFAULT_DISTANCES_M)))

    def depth_maes() -> dict:
        return {name: evaluate(learner, bank, distances_m=d, vergence_test=False, **common)["depth_mae_m"]
                for name, bank, d in sets}

    result = {"checkpoint": args.checkpoint, "trials": args.trials, "design": args.design, "data": args.data,
              "before": depth_maes()}
    trials = run_trials(learner, train, distances_m=distances, seed=cfg.seed, conditions=conditions, **common)
    q, d = trials["q_deg"], trials["distance_m"]
    if args.data == "both":
        q = torch.cat((learner.depth_inputs.cpu().double(), q.double()))
        d = torch.cat((learner.depth_targets.cpu().double(), d))
    learner.calibrate_depth(q, d, seed=cfg.seed)
    result["after"] = depth_maes()
    text = json.dumps(result)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
