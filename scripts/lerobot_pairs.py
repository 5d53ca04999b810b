"""Write a LeRobot dataset's two cameras as stereo pairs without ground truth, in the plain layout.

Each chosen frame of a LeRobotDataset, read with `aectorch.integrations.lerobot.StereoFrames` (grey
in [0, 1], the mean of the colour channels), becomes ``OUT/frame_<index>/left.png`` and
``right.png`` (8-bit grey; ``<index>`` the frame's index in the dataset, six digits), with no
``disparity.npy``: ``python -m aectorch.evaluate pairs=OUT`` reads each as a pair without ground
truth and scores the fixations by the coding reward, their stability and their agreement with the
classical matcher. LeRobot needs its own virtual environment (``scripts/setup_lerobot.sh``):

    .venv-lerobot/bin/python scripts/lerobot_pairs.py ROOT OUT [--left KEY --right KEY] [--every N] [--frames N]
    .venv/bin/python -m aectorch.evaluate checkpoint=CHECKPOINT pairs=OUT out=pairs.json

The evaluation treats the two images as a rectified pair (a match lies on the same row), and the
eyes' windows need room: 160 eye pixels square (the wide scale's) plus the searched vergence's
shifts (``search_deg``, -9 to +36 eye px by default), so frames of at least 160 rows and about
210 columns. Without ``--left``/``--right`` the dataset's first two camera keys in sorted order
are the left and the right camera.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", help="the LeRobotDataset's folder")
    parser.add_argument("out", help="the folder of pairs to write (new, or empty)")
    parser.add_argument("--left", help="the left camera's key (e.g. observation.images.left)")
    parser.add_argument("--right", help="the right camera's key")
    parser.add_argument("--every", type=int, default=1, help="write every N-th frame (default 1: all)")
    parser.add_argument("--frames", type=int, default=None, help="write at most N frames (default: all chosen)")
    return parser


def _save(path: Path, image) -> None:
    from PIL import Image

    grey = (image.detach().float().clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
    Image.fromarray(grey).save(path)


def write_pairs(root: str | Path, out: str | Path, *, left: str | None = None, right: str | None = None,
                every: int = 1, frames: int | None = None) -> list[Path]:
    """Write the chosen frames of the dataset at ``root`` as pair folders under ``out`` (the
    module's docstring); returns the folders written."""
    from aectorch.integrations.lerobot import StereoFrames

    if every < 1:
        raise ValueError(f"--every must be an integer >= 1, got {every}")
    if frames is not None and frames < 1:
        raise ValueError(f"--frames must be an integer >= 1, got {frames}")
    if (left is None) != (right is None):
        raise ValueError("give --left and --right together, or neither (the dataset's first two cameras)")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"OUT {str(out)!r} exists and is not an empty folder; give a new one")
    if not Path(root).is_dir():
        raise ValueError(f"ROOT: no such folder {str(root)!r} (a LeRobotDataset's folder)")
    stereo = StereoFrames(root, left, right)
    chosen = list(range(0, len(stereo), every))[:frames]
    written = []
    for index in chosen:
        first, second = stereo[index]
        folder = out / f"frame_{index:06d}"
        folder.mkdir(parents=True)
        _save(folder / "left.png", first)
        _save(folder / "right.png", second)
        written.append(folder)
    return written


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        written = write_pairs(args.root, args.out, left=args.left, right=args.right, every=args.every,
                              frames=args.frames)
    except (ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if not written:
        print(f"error: the dataset at {args.root!r} has no frame", file=sys.stderr)
        return 2
    from PIL import Image

    with Image.open(written[0] / "left.png") as image:
        width, height = image.size
    print(f"wrote {len(written)} pairs of {width} x {height} px to {args.out} (plain layout, no disparity.npy)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
