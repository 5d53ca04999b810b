"""Where a trained learner loses its precision: each cue's reward and greedy increment against the
eye's offset from its optimum (`aectorch.evaluation.offset_sweep`), summarised and plotted.

    .venv/bin/python scripts/offset_diagnostic.py runs/NAME/checkpoint.pt [--textures FOLDER] \
        [--readout mean] --json out.json --plot out.png

Prints, per cue: the mean |offset| of each trial's reward peak (and the share within 1 px), the
reward's mean drop 0.1 deg off the optimum, the policy's mean-increment zero crossing, the share
of trials whose greedy increment at the optimum is 0, and where the greedy map settles (the mean
|offset| of its limit cycle; with ``--readout mean``, of the mean increment's).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import torch  # noqa: E402

from aectorch.evaluation.offsets import limit_cycle, offset_summary, offset_sweep  # noqa: E402
from aectorch.figures import plot_offsets  # noqa: E402
from aectorch.runtime.checkpoint import load_learner  # noqa: E402
from aectorch.sim import TextureBank  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--textures", help="folder of images (default: the 40 test textures)")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    _, learner = load_learner(args.checkpoint)
    bank = TextureBank.default("test") if args.textures is None else TextureBank.from_folder(args.textures)
    sweeps, summaries = {}, {}
    for cue in learner.cues:
        sweeps[cue] = offset_sweep(learner, bank, cue=cue, progress=True)
        summary = offset_summary(sweeps[cue])
        summary["mean_readout_limit_cycle_abs_deg"] = float(
            limit_cycle(sweeps[cue]["offsets_deg"], sweeps[cue]["expected_increment_deg"]).mean())
        summaries[cue] = summary
        print(cue, json.dumps({k: round(v, 4) for k, v in summary.items()}))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"checkpoint": args.checkpoint, "textures": args.textures or "test textures",
                                         "cues": summaries}, indent=1) + "\n")
    if args.plot:
        plot_offsets(sweeps, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
