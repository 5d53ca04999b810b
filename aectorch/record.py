"""``python -m aectorch.record``: record a trained learner's trials as a LeRobotDataset.

Needs LeRobot (run it with ``.venv-lerobot/bin/python``, see `aectorch.integrations.lerobot`).
"""

from __future__ import annotations

import os
import sys
from typing import Sequence

from aectorch._checks import is_int
from aectorch._cli import UsageError, parse_key_values, run_main

USAGE = """\
usage: python -m aectorch.record checkpoint=<file> out=<folder> [key=value ...]

Record greedy, frozen trials of a trained learner (a train.py checkpoint) as a LeRobotDataset in
<folder> (which must not exist): one episode per fixation, 30 frames each, with both eyes'
images, the eye state, the actions, both cues' rewards and the true distance.

keys:
  checkpoint=<file>      checkpoint.pt of a train.py run (required)
  out=<folder>           the new dataset's folder (required)
  textures=<folder>      images to put on the plane (default: the held-out procedural textures)
  trials=<int>           trials per environment (default: 2)
  envs=<int>             environments simulated (and recorded) at once (default: 1)
  seed=<int>             seeds the environments' textures and distances (default: 0)
  renderer=torch|pyrender  (default: the run's, env.renderer)
  repo_id=<owner/name>   the dataset's name in its metadata (default: aectorch/hoap3-sim)
  progress=true|false    show a progress bar (default: true)

Errors print one "error: ..." line and exit with status 2.
"""

_KEYS = ("checkpoint", "out", "textures", "trials", "envs", "seed", "renderer", "repo_id", "progress")


def _parse(argv: Sequence[str]) -> dict:
    from aectorch.sim import RENDERERS

    args = parse_key_values(argv, _KEYS, required=("checkpoint", "out"), paths=("checkpoint", "out", "textures"))
    for key, default, minimum in (("trials", 2, 1), ("envs", 1, 1), ("seed", 0, 0)):
        value = args.setdefault(key, default)
        if not is_int(value) or value < minimum:
            raise UsageError(f"{key} must be an int >= {minimum}, got {value!r}")
    if args.get("renderer") is not None and args["renderer"] not in RENDERERS:
        raise UsageError(f"renderer must be one of {', '.join(RENDERERS)}, got {args['renderer']!r}")
    if not isinstance(args.setdefault("progress", True), bool):
        raise UsageError(f"progress must be true or false, got {args['progress']!r}")
    args.setdefault("repo_id", "aectorch/hoap3-sim")
    if not os.path.isfile(args["checkpoint"]):
        raise UsageError(f"checkpoint: no such file {args['checkpoint']!r}")
    if os.path.exists(args["out"]):
        raise UsageError(f"out: {args['out']!r} exists already; give a new folder")
    if args.get("textures") is not None and not os.path.isdir(args["textures"]):
        raise UsageError(f"textures: no such folder {args['textures']!r}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.record checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run_main(argv, USAGE, _record)


def _record(argv: list[str]) -> int:
    args = _parse(argv)
    from aectorch.integrations.lerobot import record_trials
    from aectorch.runtime import load_learner, trial_protocol
    from aectorch.sim import ActiveDepthEnv, TextureBank, resolve_protocol

    cfg, learner = load_learner(args["checkpoint"])
    if args.get("textures") is None:
        bank = TextureBank.default("test", dtype=cfg.env.torch_dtype)
    else:
        bank = TextureBank.from_folder(args["textures"], dtype=cfg.env.torch_dtype,
                                       progress=None if args["progress"] else False)
    protocol = resolve_protocol(trial_protocol(cfg), renderer=args.get("renderer"))
    env = ActiveDepthEnv(args["envs"], textures=bank, distances_m=cfg.env.distances_m, **protocol.env_kwargs(),
                         seed=args["seed"], device=cfg.env.device, dtype=cfg.env.torch_dtype)
    root = record_trials(learner, env, args["trials"], args["out"], repo_id=args["repo_id"],
                         progress=args["progress"])
    episodes = 2 * args["trials"] * args["envs"]
    print(f"recorded {episodes} episodes ({episodes * cfg.env.fixation_iterations} frames) into {root}")
    return 0

if __name__ == "__main__":
    sys.exit(main())
