"""Which part of a run carries what training changed: one cue's policy or code taken from another state.

    .venv/bin/python experiments/long_training/swap.py runs/ll_s0/ckpt_9600.pt runs/ll_s0/ckpt_2400.pt \
        --cue parallax --part agent runs/ll_s0/swap_parallax_agent_2400.pt
    python -m aectorch.evaluate checkpoint=runs/ll_s0/swap_parallax_agent_2400.pt textures=data/choose-photos \
        out=runs/ll_s0/choose_swap_parallax_agent_2400.json

Writes a copy of BASE whose cue ``--cue`` has its ``--part`` from DONOR: ``agent`` (the policy and
critic with their feature statistics: what the cue does with its code) or ``encoder`` (its
dictionaries: the code). Everything else is BASE's. Evaluating the copy, frozen and greedy, beside
BASE and DONOR says whether a change between two states of a run lies in the policy or in the code.
Both checkpoints must be of the same configuration (the part's tensors must have the same shapes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

PARTS = ("agent", "encoder")


def swap(base: dict, donor: dict, cue: str, part: str) -> tuple[dict, int]:
    """``base`` with the ``cues.<cue>.<part>.`` entries of ``donor``'s learner; the count swapped."""
    prefix = f"cues.{cue}.{part}."
    theirs = {k: v for k, v in donor["learner"].items() if k.startswith(prefix)}
    ours = {k for k in base["learner"] if k.startswith(prefix)}
    if not theirs or set(theirs) != ours:
        cues = sorted({k.split(".")[1] for k in base["learner"] if k.startswith("cues.")})
        raise ValueError(f"--cue {cue} --part {part}: the checkpoints' {prefix}* entries differ or are missing "
                         f"(the cues: {', '.join(cues)})")
    for key, value in theirs.items():
        mine = base["learner"][key]
        if hasattr(mine, "shape") and getattr(value, "shape", None) != mine.shape:
            raise ValueError(f"{key}: shape {tuple(value.shape)} in DONOR, {tuple(mine.shape)} in BASE")
    out = dict(base)
    out["learner"] = {**base["learner"], **theirs}
    return out, len(theirs)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", type=Path, help="the checkpoint to copy")
    parser.add_argument("donor", type=Path, help="the checkpoint the part comes from")
    parser.add_argument("out", type=Path, help="the new checkpoint (must not exist)")
    parser.add_argument("--cue", required=True, help="the cue: parallax, stereo, ...")
    parser.add_argument("--part", required=True, choices=PARTS)
    args = parser.parse_intermixed_args(argv)
    if args.out.exists():
        parser.error(f"{args.out} exists: give a new file")
    try:
        base, donor = (torch.load(p, map_location="cpu", weights_only=False) for p in (args.base, args.donor))
        state, count = swap(base, donor, args.cue, args.part)
    except (OSError, RuntimeError, KeyError, ValueError) as err:
        sys.exit(f"error: {err}")
    tmp = args.out.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(args.out)
    print(f"{args.out}: {args.base.name} with {count} {args.cue}.{args.part} tensors of {args.donor.name}")


if __name__ == "__main__":
    main()
