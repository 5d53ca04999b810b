"""``python -m aectorch.visualize``: one trial of a trained learner as a GIF or MP4 (see ``--help``)."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Sequence

from aectorch._checks import is_int, is_real
from aectorch._cli import UsageError, parse_key_values, run_main

USAGE = """\
usage: python -m aectorch.visualize checkpoint=<file> out=<file.gif|file.mp4> [key=value ...]

Watch one frozen trial of a trained learner (a train.py checkpoint): per iteration one frame with
the left eye's view, the right eye's view, their difference and the pursuit and vergence errors
so far; the last frame gives the depth estimate against the true distance.

keys:
  checkpoint=<file>      checkpoint.pt of a train.py run (required)
  out=<file>             the animation: .gif, or .mp4 when ffmpeg is installed (required)
  texture=<file|int>     an image file, or an index into the default test bank (default: 0)
  distance=<metres>      the object's distance (default: 2.0)
  renderer=torch|pyrender  (default: the run's)
  policy=greedy|sampled  argmax actions (default) or actions sampled as in training
  seed=<int>             seeds the environment and sampled actions (default: 0)
  fps=<int>              frames per second (default: 8)
  every=<int>            draw every n-th iteration, for a smaller file (default: 1)
  dpi=<int>              resolution of the frames, 7.2 x 5 inches (default: 100)

Errors print one "error: ..." line and exit with status 2.
"""

_KEYS = ("checkpoint", "out", "texture", "distance", "renderer", "policy", "seed", "fps", "every", "dpi")


def _parse(argv: Sequence[str]) -> dict:
    from aectorch.sim import RENDERERS
    from aectorch.choices import Policy
    from aectorch.visualize import check_output

    args = parse_key_values(argv, _KEYS, required=("checkpoint", "out"), paths=("checkpoint", "out"))
    for key, default, minimum in (("seed", 0, 0), ("fps", 8, 1), ("every", 1, 1), ("dpi", 100, 10)):
        if not is_int(args.setdefault(key, default)) or args[key] < minimum:
            raise UsageError(f"{key} must be an int >= {minimum}, got {args[key]!r}")
    distance = args.setdefault("distance", 2.0)
    if not (is_real(distance) and distance > 0):
        raise UsageError(f"distance must be a distance > 0 in metres, got {distance!r}")
    if args.get("renderer") is not None and args["renderer"] not in RENDERERS:
        raise UsageError(f"renderer must be one of {', '.join(RENDERERS)}, got {args['renderer']!r}")
    if args.setdefault("policy", "greedy") not in Policy.values():
        raise UsageError(f"policy must be one of {', '.join(Policy.values())}, got {args['policy']!r}")
    texture = args.setdefault("texture", 0)
    if isinstance(texture, str):
        if not os.path.isfile(texture):
            raise UsageError(f"texture: no such file {texture!r}")
    elif not is_int(texture) or texture < 0:
        raise UsageError(f"texture must be an image file or an index >= 0 into the default test bank, "
                         f"got {texture!r}")
    try:
        check_output(args["out"])
    except ValueError as err:
        raise UsageError(str(err) if str(err).startswith("out") else f"out: {err}") from err
    if not os.path.isfile(args["checkpoint"]):
        raise UsageError(f"checkpoint: no such file {args['checkpoint']!r}")
    return args


def _texture(texture):
    """``(texture [H, W], name)`` of an image file or an index into the default test bank."""
    from aectorch.sim import TextureBank

    if isinstance(texture, str):
        with tempfile.TemporaryDirectory(prefix="aectorch-texture-") as folder:
            shutil.copyfile(texture, Path(folder) / Path(texture).name)
            try:
                bank = TextureBank.from_folder(folder, progress=False)
            except (ValueError, OSError) as err:
                raise UsageError(f"texture: {str(err).replace(folder, os.path.dirname(texture) or '.')}") from err
        return bank[0], Path(texture).name
    bank = TextureBank.default("test")
    if texture >= len(bank):
        raise UsageError(f"texture: index {texture} is outside the default test bank's [0, {len(bank)})")
    return bank[texture], bank.names[texture]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.visualize checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run_main(argv, USAGE, _visualize)


def _visualize(argv: list[str]) -> int:
    args = _parse(argv)
    from aectorch.runtime import load_learner, trial_protocol
    from aectorch.visualize import animate_trial, frame_steps, record_trial

    try:
        cfg, learner = load_learner(args["checkpoint"])
    except ValueError as err:
        raise UsageError(f"checkpoint: {err}") from err
    texture, name = _texture(args["texture"])
    try:
        frames = record_trial(learner, texture, float(args["distance"]), protocol=trial_protocol(cfg),
                              renderer=args.get("renderer") or cfg.env.renderer, policy=args["policy"],
                              seed=args["seed"], texture_name=name)
    except ValueError as err:
        if str(err).startswith("distance_m: "):  # beyond the background plane
            raise UsageError(f"distance: {str(err)[len('distance_m: '):]}") from err
        raise
    out = animate_trial(frames, args["out"], fps=args["fps"], every=args["every"], dpi=args["dpi"])
    print(f"wrote {out} ({len(frame_steps(len(frames), args['every']))} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
