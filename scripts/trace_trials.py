"""Print the greedy eye errors of a checkpoint, iteration by iteration, for a few trials.

    .venv/bin/python scripts/trace_trials.py <run>/checkpoint.pt [--distance 1.0] [--textures N]
        [--folder photos/] [--every 3]

Each environment shows one texture (the first N of the default test bank, or of ``--folder``)
at ``--distance`` metres; learning is frozen and both policies are greedy, as in
``python -m aectorch.evaluate``. Columns are environments; P is the pursuit error and V the
vergence error (degrees, actual - optimal) after the iteration.
"""

from __future__ import annotations

import argparse
import sys

import torch


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--distance", type=float, default=1.0, help="metres (default 1.0)")
    parser.add_argument("--textures", type=int, default=8, help="how many textures (default 8)")
    parser.add_argument("--folder", default=None, help="a folder of images (default: the test bank)")
    parser.add_argument("--every", type=int, default=3, help="print every this many iterations")
    args = parser.parse_args(argv)

    from aectorch.runtime import load_learner
    from aectorch.sim import ActiveDepthEnv, TextureBank

    cfg, learner = load_learner(args.checkpoint)
    bank = TextureBank.from_folder(args.folder) if args.folder else TextureBank.default("test")
    n = min(args.textures, len(bank))
    env = ActiveDepthEnv(n, protocol=cfg.env.protocol, textures=bank, seed=0)
    env.set_trial(torch.arange(n), torch.full((n,), args.distance))
    learner.forget_transitions()
    with torch.no_grad():
        for i in range(2 * cfg.env.fixation_iterations):
            record = learner.iteration(env, learn=False, greedy=True)
            if i % args.every == args.every - 1 or record.fixation_end:
                p = " ".join(f"{x:7.2f}" for x in record.pursuit_error_deg.tolist())
                v = " ".join(f"{x:7.2f}" for x in record.vergence_error_deg.tolist())
                print(f"{i:3d} P {p} | V {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
