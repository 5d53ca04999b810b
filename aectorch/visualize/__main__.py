"""``python -m aectorch.visualize``: one trial of a trained learner as a GIF or MP4 (see ``--help``)."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

from omegaconf import MISSING

from aectorch._checks import check_int, check_real
from aectorch.choices import Policy, RendererName
from aectorch.runtime.command import check_checkpoint_file, run

__all__ = ["VisualizeConfig", "main"]


@dataclass
class VisualizeConfig:
    """Watch one frozen trial of a trained learner (a train.py checkpoint): per iteration one frame
    with the left eye's view, the right eye's view, their difference and the pursuit and vergence
    errors so far; the last frame gives the depth estimate against the true distance.

    Args:
        checkpoint: checkpoint.pt of a train.py run.
        out: the animation: a .gif file, or .mp4 when ffmpeg is installed.
        texture: an image file, or an index into the default test bank.
        distance: the object's distance in metres.
        renderer: torch or pyrender (default: the run's).
        policy: greedy (argmax actions) or sampled (actions sampled as in training).
        seed: seeds the environment and sampled actions.
        fps: frames per second.
        every: draw every n-th iteration, for a smaller file.
        dpi: resolution of the frames, 7.2 x 5 inches.
    """

    checkpoint: str = MISSING
    out: str = MISSING
    texture: str = "0"
    distance: float = 2.0
    renderer: Optional[RendererName] = None
    policy: Policy = Policy.greedy
    seed: int = 0
    fps: int = 8
    every: int = 1
    dpi: int = 100

    def __post_init__(self) -> None:
        from aectorch.visualize import check_output

        for key, minimum in (("seed", 0), ("fps", 1), ("every", 1), ("dpi", 10)):
            check_int(getattr(self, key), key, minimum=minimum)
        check_real(self.distance, "distance", above=0.0, unit="metres")
        if not os.path.isfile(self.texture) and not (self.texture.isdigit()):
            raise ValueError(f"texture: no such file {self.texture!r} (an image file, or an index >= 0 into the "
                             "default test bank)")
        try:
            check_output(self.out)
        except ValueError as err:
            raise ValueError(str(err) if str(err).startswith("out") else f"out: {err}") from err
        check_checkpoint_file(self.checkpoint)


def _texture(texture):
    """``(texture [H, W], name)`` of an image file or an index into the default test bank."""
    from aectorch.sim import TextureBank

    if os.path.isfile(texture):
        with tempfile.TemporaryDirectory(prefix="aectorch-texture-") as folder:
            shutil.copyfile(texture, Path(folder) / Path(texture).name)
            try:
                bank = TextureBank.from_folder(folder, progress=False)
            except (ValueError, OSError) as err:
                raise ValueError(f"texture: {str(err).replace(folder, os.path.dirname(texture) or '.')}") from err
        return bank[0], Path(texture).name
    bank, texture = TextureBank.default("test"), int(texture)
    if texture >= len(bank):
        raise ValueError(f"texture: index {texture} is outside the default test bank's [0, {len(bank)})")
    return bank[texture], bank.names[texture]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.visualize checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run(argv, VisualizeConfig, "aectorch.visualize", _visualize)


def _visualize(args: VisualizeConfig) -> int:
    from aectorch.runtime import load_learner
    from aectorch.sim import resolve_protocol
    from aectorch.visualize import animate_trial, frame_steps, record_trial

    try:
        cfg, learner = load_learner(args.checkpoint)
    except ValueError as err:
        raise ValueError(f"checkpoint: {err}") from err
    texture, name = _texture(args.texture)
    try:
        frames = record_trial(learner, texture, float(args.distance),
                              protocol=resolve_protocol(cfg.env.protocol, renderer=args.renderer), policy=args.policy,
                              seed=args.seed, texture_name=name)
    except ValueError as err:
        if str(err).startswith("distance_m: "):  # beyond the background plane
            raise ValueError(f"distance: {str(err)[len('distance_m: '):]}") from err
        raise
    out = animate_trial(frames, args.out, fps=args.fps, every=args.every, dpi=args.dpi)
    print(f"wrote {out} ({len(frame_steps(len(frames), args.every))} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
