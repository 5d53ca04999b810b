"""What a trained accommodation cue does against defocus: its greedy (mean) focus increment and its
information reward with both eyes at the optimal vergence, focused off the object by each
defocus of a grid (docs/results.md, "Accommodation").

    PYTHONPATH=. .venv/bin/python scripts/accommodation_policy.py runs/acc600_s0/checkpoint.pt
"""

from __future__ import annotations

import argparse

import torch

from aectorch.runtime import load_learner
from aectorch.sim import ActiveDepthEnv, TextureBank

DEFOCUS_D = (-0.8, -0.4, -0.2, 0.0, 0.2, 0.4, 0.8)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--textures", type=int, default=8, help="the first this many test textures")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    _, learner = load_learner(args.checkpoint)
    cue, n = learner.accommodation, args.textures
    env = ActiveDepthEnv(n, textures=TextureBank.default("test"), accommodation_start_D=0.0, seed=0)
    print("distance | " + " | ".join(f"{d:+.1f} D: increment (deg), reward" for d in DEFOCUS_D))
    with torch.no_grad():
        for distance in (1.0, 2.0, 3.0):
            env.set_trial(torch.arange(n), torch.full((n,), distance))
            env.apply_vergence(env.vergence_to_optimum())
            cells = []
            for defocus in DEFOCUS_D:
                env.set_focus(torch.full((n, 2), 1.0 / distance + defocus).clamp_min(0.0))
                observation = env.stereo_observation(cue.encoder.scales)
                out = cue.encoder.encode(observation)
                policy = cue.agent.log_policy(cue._features(out.features)).exp()
                increment = policy @ cue.agent.actions_deg.to(policy.dtype)
                cells.append(f"{float(increment.mean()):+.3f}, {float(cue._information(observation, out).mean()):.3f}")
            print(f"{distance:.1f} m | " + " | ".join(cells))


if __name__ == "__main__":
    main()
