"""What a trained accommodation cue does against defocus: the accommodation study's policy table.

    .venv/bin/python experiments/accommodation/policy.py runs/acc_s0/checkpoint.pt [--textures 8]

README.md here says what the runs learned. A missing or damaged checkpoint, one without the
accommodation cue, or a bad argument prints one ``error:`` line and exits with status 2
(`aectorch.report.command.run_command`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol  # noqa: E402

__all__ = ["DEFOCUS_D", "main", "parser", "policy_table"]

#: The defocus grid of `policy_table` (dioptres, positive: focused nearer than the object).
DEFOCUS_D = (-0.8, -0.4, -0.2, 0.0, 0.2, 0.4, 0.8)


def policy_table(learner, textures: int = 8) -> list[str]:
    """What a trained accommodation cue does against defocus: its greedy (mean) focus increment
    (degrees of blur disc) and its information reward, both eyes at the optimal vergence and
    focused off the object by each defocus of `DEFOCUS_D`, on the first ``textures`` test textures
    at 1, 2 and 3 m."""
    cue = getattr(learner, "accommodation", None)
    if cue is None:
        raise ValueError("the checkpoint's learner has no accommodation cue (train it with +experiment=accommodation)")
    n = textures
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


def _report(args) -> list[str]:
    from aectorch.runtime import load_learner

    if args.textures < 1:
        raise ValueError(f"--textures must be >= 1, got {args.textures}")
    return policy_table(load_learner(args.checkpoint)[1], args.textures)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `policy_table`'s docstring."""
    out = study_parser("experiments/accommodation/policy.py", policy_table, _report)
    out.add_argument("checkpoint", type=Path, help="a run's checkpoint.pt trained with the accommodation cue")
    out.add_argument("--textures", type=int, default=8, help="the first this many test textures")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
