"""``python -m aectorch.evaluate``: evaluate a checkpoint written by ``train.py`` (see ``--help``).

A command line, beside ``python -m aectorch.record`` and ``python -m aectorch.visualize``: it sits
above the runtime (it reads checkpoints through it); the library it runs, `aectorch.evaluation`,
sits below the runtime, which runs it at the end of training.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Sequence

from aectorch._checks import is_int, is_real
from aectorch._cli import UsageError, parse_key_values, run_main
from aectorch.choices import Policy, Readout
from aectorch.evaluation import BEYOND_DEG, EVAL_BATCH_SIZE, WITHIN_DEG, evaluate
from aectorch.figures import plot_evaluation
from aectorch.runtime.builders import trial_protocol
from aectorch.runtime.checkpoint import load_checkpoint, load_learner
from aectorch.sim import DEFAULT_DISTANCES_M, RENDERERS, TextureBank, resolve_protocol

__all__ = ["main"]

USAGE = f"""usage: python -m aectorch.evaluate checkpoint=<file> out=<file.json> [key=value ...]

Evaluate a trained checkpoint (train.py's checkpoint.pt) frozen and greedy: every texture at
every distance runs one trial, then the earlier models' vergence test.

keys:
  checkpoint=<file>      the checkpoint (required)
  out=<file.json>        where to write the result (required)
  textures=<folder>      held-out images (default: the default test bank, 40 procedural
                         textures disjoint from the default training set)
  renderer=torch|pyrender                    (default: the run's, env.renderer)
  depths=[1.0,2.0,3.0]   distances in metres (default: 1.0 to 3.0 in 0.1 m steps)
  batch_size=<int>       environments at once (default: {EVAL_BATCH_SIZE})
  seed=<int>             seeds the vergence test's offsets (default: 0)
  figure=<file.png>      also draw the evaluation figure
  progress=true|false    show a progress bar (default: true)
  policy=greedy|sampled  argmax actions (the protocol; default) or actions sampled from the
                         policies as in training, to see what greediness costs
  readout=argmax|mean    the greedy increment of every cue: the most probable action's, or
                         the policy's mean increment (default: the run's, learner.cues.<cue>.readout)

Errors print one "error: ..." line and exit with status 2.
"""

_KEYS = ("checkpoint", "out", "textures", "renderer", "depths", "batch_size", "seed", "figure", "progress",
         "policy", "readout")


def _parse(argv: Sequence[str]) -> dict:

    args = parse_key_values(argv, _KEYS, required=("checkpoint", "out"),
                            paths=("checkpoint", "out", "textures", "figure"))
    renderer = args.get("renderer")  # default: the run's, once the checkpoint is read
    if renderer is not None and renderer not in RENDERERS:
        raise UsageError(f"renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    depths = args.setdefault("depths", list(DEFAULT_DISTANCES_M))
    if is_real(depths):
        depths = args["depths"] = [depths]
    if (not isinstance(depths, list) or not depths
            or any(not is_real(d) or d <= 0 for d in depths)):
        raise UsageError(f"depths must be a list of distances > 0 in metres such as [1.0,2.0], got {depths!r}")
    for key, default, minimum in (("batch_size", EVAL_BATCH_SIZE, 1), ("seed", 0, 0)):
        value = args.setdefault(key, default)
        if not is_int(value) or value < minimum:
            raise UsageError(f"{key} must be an int >= {minimum}, got {value!r}")
    policy = args.setdefault("policy", "greedy")
    if policy not in Policy.values():
        raise UsageError(f"policy must be one of {', '.join(Policy.values())}, got {policy!r}")
    readout = args.get("readout")
    if readout is not None and readout not in Readout.values():
        raise UsageError(f"readout must be one of {', '.join(Readout.values())}, got {readout!r}")
    progress = args.setdefault("progress", True)
    if not isinstance(progress, bool):
        raise UsageError(f"progress must be true or false, got {progress!r}")
    textures = args.get("textures")
    if textures is not None and not os.path.isdir(textures):
        raise UsageError(f"textures: no such folder {textures!r}")
    if not os.path.isfile(args["checkpoint"]):
        raise UsageError(f"checkpoint: no such file {args['checkpoint']!r}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.evaluate checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run_main(argv, USAGE, _evaluate)


def _evaluate(argv: list[str]) -> int:
    args = _parse(argv)
    payload = load_checkpoint(args["checkpoint"])
    cfg, learner = load_learner(args["checkpoint"], payload=payload)
    iteration = int(payload["iteration"])
    if args.get("readout") is not None:
        for cue in learner.cues.values():
            cue.config.readout = Readout(args["readout"])
    if args.get("textures") is None:
        bank, textures = TextureBank.default("test"), "default test bank"
    else:
        try:
            bank = TextureBank.from_folder(args["textures"], progress=None if args["progress"] else False)
        except (ValueError, OSError) as err:
            raise UsageError(f"textures: {err}") from err
        textures = args["textures"]
    protocol = resolve_protocol(trial_protocol(cfg), renderer=args.get("renderer"))
    result = evaluate(learner, bank, distances_m=args["depths"], protocol=protocol, batch_size=args["batch_size"],
                      seed=args["seed"], progress=args["progress"], policy=args["policy"])
    result.update(checkpoint=args["checkpoint"], textures=textures, renderer=str(protocol.renderer),
                  iteration=iteration)
    with open(args["out"], "w") as f:
        json.dump(result, f, indent=2)
        f.write("\n")
    if args.get("figure"):
        plot_evaluation(result, args["figure"])
    keys = [k for k in result if k.endswith("_mae_deg")] + ["depth_mae_m"]  # every eye movement's, then depth
    rows = [f"{'distance_m':>10} " + " ".join(f"{k:>{len(k) + 1}}" for k in keys)]
    for row in result["per_distance"] + [dict(result, distance_m="all")]:
        d = row["distance_m"]
        rows.append(f"{d if isinstance(d, str) else f'{d:.2f}':>10} "
                    + " ".join(f"{row[k]:>{len(k) + 1}.4f}" for k in keys))
    both = result["fractions"]["both"]
    rows.append(f"fixation ends with every eye movement within {WITHIN_DEG} deg: {both['within']:.1%}; "
                f"either beyond {BEYOND_DEG} deg: {both['beyond']:.1%}")
    last = result["last5"]
    rows.append("mean of each fixation's last 5 iterations: "
                + ", ".join(f"{k} {v:.4f}" for k, v in last.items() if k.endswith("_mae_deg"))
                + f"; every eye movement within {WITHIN_DEG} deg: {last['fractions']['both']['within']:.1%}")
    if "vergence_test" in result:
        deg = result["vergence_test"]["degrees"]
        rows.append(f"vergence test: RMSE {deg['rmse']:.4f} deg, median {deg['median']:.4f} deg, n {deg['n']}")
    rows.append(f"{result['trials']} trials, checkpoint iteration {iteration}; written to {args['out']}")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
