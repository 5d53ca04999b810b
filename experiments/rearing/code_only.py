"""The stereo code of a squint without a world or a policy: which textures let it turn monocular?

    PYTHONPATH=. .venv/bin/python experiments/rearing/code_only.py --json experiments/rearing/code_only.json

Each step draws 32 texture crops (160 x 160 px) for the left eye and the same crops shifted
``--shift`` px to the right for the right eye (30 px: the 6.6-8.8 deg of disparity that the
lineage's strabismus leaves at the fine and full scales' 0.225 deg per px), codes them with a
`BinocularEncoder` of the fine and full scales (288 atoms, 10 coefficients, the rearing rate 16, no
decay and no critical period) and takes one dictionary-learning step. It does so for the default
textures (Gaussian 1/f noise) and for dead-leaves textures (`TextureBank.dead_leaves`, the
rearing suite's), and reports the mean absolute binocularity index and the shares of the atoms
dominated by each eye (|index| > 3/7) as learning goes on. ``--shift 0`` is normal rearing's
aligned pair.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from aectorch.coding import BinocularEncoder  # noqa: E402
from aectorch.coding.readouts import binocularity_index  # noqa: E402
from report import DOMINANCE  # noqa: E402  (this folder's report.py)
from aectorch.sim.textures.bank import TextureBank  # noqa: E402

SIDE = 160
BATCH = 32


def crops(textures: torch.Tensor, shift: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``BATCH`` left crops and the right crops ``shift`` px to their right, ``[BATCH, SIDE, SIDE]`` each."""
    index = torch.randint(len(textures), (BATCH,), generator=generator)
    height, width = textures.shape[-2:]
    ys = torch.randint(0, height - SIDE + 1, (BATCH,), generator=generator)
    xs = torch.randint(0, width - SIDE - shift + 1, (BATCH,), generator=generator)
    left = torch.stack([textures[i, y:y + SIDE, x:x + SIDE] for i, y, x in zip(index, ys, xs)])
    right = torch.stack([textures[i, y:y + SIDE, x + shift:x + shift + SIDE] for i, y, x in zip(index, ys, xs)])
    return left, right


def learn(textures: torch.Tensor, shift: int, steps: int, lr: float, every: int, seed: int) -> list[dict]:
    """The read-outs every ``every`` steps of a code learned on ``textures``' shifted crop pairs."""
    encoder = BinocularEncoder(scales=("fine", "full"), generator=torch.Generator().manual_seed(seed), lr=lr,
                               decay=None)
    generator = torch.Generator().manual_seed(seed + 1)
    rows = []
    for step in range(steps + 1):
        if step % every == 0:
            row = {"step": step}
            for name, dictionary in encoder.dictionaries.items():
                index = binocularity_index(dictionary.atoms)
                row[name] = {"mean_abs_index": round(float(index.abs().mean()), 3),
                             "left": round(float((index < -DOMINANCE).float().mean()), 3),
                             "right": round(float((index > DOMINANCE).float().mean()), 3)}
            rows.append(row)
        if step < steps:
            with torch.no_grad():
                encoder.learn_(encoder(*crops(textures, shift, generator)))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shift", type=int, default=30, help="the right crop's shift, px (default 30)")
    parser.add_argument("--steps", type=int, default=600, help="learning steps (default 600)")
    parser.add_argument("--lr", type=float, default=16.0, help="the dictionaries' rate (default: the suite's 16)")
    parser.add_argument("--every", type=int, default=100, help="read the code out every this many steps")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-textures", type=int, default=None,
                        help="the first this many textures of each set (default: the sets' 100)")
    parser.add_argument("--json", type=Path, default=None, help="also write the read-outs here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    banks = {"1/f noise (the default textures)": TextureBank.default("train", num=args.num_textures).textures,
             "dead leaves (the rearing suite's)": TextureBank.from_spec("dead-leaves", num=args.num_textures).textures}
    results = {}
    print("| textures | step | dictionary | mean abs. index | left-dominated % | right-dominated % |")
    print("|---|---|---|---|---|---|")
    for label, textures in banks.items():
        results[label] = learn(textures, args.shift, args.steps, args.lr, args.every, args.seed)
        for row in results[label]:
            for name in ("fine", "full"):
                r = row[name]
                print(f"| {label} | {row['step']} | {name} | {r['mean_abs_index']:.3f} | {100 * r['left']:.0f} | "
                      f"{100 * r['right']:.0f} |")
    if args.json is not None:
        args.json.write_text(json.dumps({"settings": vars(args) | {"json": str(args.json)}, "results": results},
                                        indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
