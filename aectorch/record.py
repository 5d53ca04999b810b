"""``python -m aectorch.record``: record a trained learner's trials as a LeRobotDataset.

Needs LeRobot (run it with ``.venv-lerobot/bin/python``, see `aectorch.integrations.lerobot`).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from typing import Optional, Sequence

from omegaconf import MISSING

from aectorch._checks import check_int
from aectorch.choices import RendererName
from aectorch.runtime.command import check_checkpoint_file, run

__all__ = ["RecordConfig", "main"]


@dataclass
class RecordConfig:
    """Record greedy, frozen trials of a trained learner (a train.py checkpoint) as a LeRobotDataset
    in a new folder: one episode per fixation, 30 frames each, with both eyes' images, the eye
    state, the actions, both cues' rewards and the true distance.

    Args:
        checkpoint: checkpoint.pt of a train.py run.
        out: the new dataset's folder (it must not exist).
        textures: a folder of images to put on the plane (default: the held-out procedural textures).
        trials: trials per environment.
        envs: environments simulated (and recorded) at once.
        seed: seeds the environments' textures and distances.
        renderer: torch or pyrender (default: the run's, env.renderer).
        repo_id: the dataset's name in its metadata, owner/name.
        progress: show a progress bar.
    """

    checkpoint: str = MISSING
    out: str = MISSING
    textures: Optional[str] = None
    trials: int = 2
    envs: int = 1
    seed: int = 0
    renderer: Optional[RendererName] = None
    repo_id: str = "aectorch/hoap3-sim"
    progress: bool = True

    def __post_init__(self) -> None:
        check_int(self.trials, "trials", minimum=1)
        check_int(self.envs, "envs", minimum=1)
        check_int(self.seed, "seed", minimum=0)
        check_checkpoint_file(self.checkpoint)
        if os.path.exists(self.out):
            raise ValueError(f"out: {self.out!r} exists already; give a new folder")
        if self.textures is not None and not os.path.isdir(self.textures):
            raise ValueError(f"textures: no such folder {self.textures!r}")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.record checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run(argv, RecordConfig, "aectorch.record", _record)


def _record(args: RecordConfig) -> int:
    from aectorch.integrations.lerobot import record_trials
    from aectorch.runtime import load_learner
    from aectorch.sim import ActiveDepthEnv, TextureBank, resolve_protocol

    cfg, learner = load_learner(args.checkpoint)
    if args.textures is None:
        bank = TextureBank.default("test", dtype=cfg.env.torch_dtype)
    else:
        bank = TextureBank.from_folder(args.textures, dtype=cfg.env.torch_dtype,
                                       progress=None if args.progress else False)
    protocol = resolve_protocol(cfg.env.protocol, renderer=args.renderer)
    env = ActiveDepthEnv(args.envs, protocol=protocol, textures=bank, distances_m=cfg.env.distances_m, seed=args.seed,
                         device=cfg.env.device, dtype=cfg.env.torch_dtype)
    root = record_trials(learner, env, args.trials, args.out, repo_id=args.repo_id,
                         progress=args.progress)
    episodes = 2 * args.trials * args.envs
    print(f"recorded {episodes} episodes ({episodes * cfg.env.fixation_iterations} frames) into {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
