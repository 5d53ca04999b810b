"""The classical matcher (`aectorch.baselines.Matcher`) through the learner's trials: the accuracy anchor.

    .venv/bin/python scripts/matcher_eval.py --textures data/choose-photos --out runs/matcher/choose.json
    .venv/bin/python scripts/matcher_eval.py --depths 1.0 1.5 2.0 2.5 3.0 --out runs/matcher/textures.json

Runs `aectorch.evaluation.evaluate` (same trials, protocol and per-trial rows as
``python -m aectorch.evaluate``) for the matcher restricted to the learner's default action set
and, with ``--free``, for the unconstrained one (any increment); writes one JSON per variant
(``<out>`` and ``<out stem>_free.json``) and prints a line each.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import torch  # noqa: E402

from aectorch.baselines import Matcher  # noqa: E402
from aectorch.evaluation import evaluate  # noqa: E402
from aectorch.sim import DEFAULT_DISTANCES_M, TextureBank  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--textures", help="folder of images (default: the 40 test textures)")
    parser.add_argument("--depths", type=float, nargs="+", default=list(DEFAULT_DISTANCES_M))
    parser.add_argument("--renderer", default="torch")
    parser.add_argument("--free", action="store_true", help="also the unconstrained matcher")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    bank = TextureBank.default("test") if args.textures is None else TextureBank.from_folder(args.textures)
    variants = {args.out: Matcher()}
    if args.free:
        variants[args.out.with_name(args.out.stem + "_free.json")] = Matcher(actions_deg=None)
    for out, matcher in variants.items():
        result = evaluate(matcher, bank, distances_m=args.depths, renderer=args.renderer, progress=True)
        result.update(textures=args.textures or "default test bank", renderer=args.renderer,
                      controller="matcher" if matcher.constrained else "matcher (unconstrained)")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")
        both = result["fractions"]["both"]
        print(f"{result['controller']}: pursuit {result['pursuit_mae_deg']:.4f} deg, vergence "
              f"{result['vergence_mae_deg']:.4f} deg, both within 0.22 deg {both['within']:.1%}, "
              f"beyond 2 deg {both['beyond']:.1%}; {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
