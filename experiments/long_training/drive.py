"""Which scale of the code drives a linear PPO policy's step at each offset from the optimum.

For the cue's views at each offset (`aectorch.evaluation.offset_sweep`: the body at the end of its
shift, the eye moved off its optimum), the policy's preference for its largest step one way over
its largest step the other way, ``logit(+max) - logit(-max)``, is a sum over the z-scored features
(PPO's policy is linear by default), so it splits exactly into each scale's share and the bias.
A positive drive at a negative offset steps back toward the optimum; at a positive offset, away.

    python experiments/long_training/drive.py "2,400=runs/llpe2_s0/ckpt_2400.pt" \\
        "9,600=runs/llpe2_s0/ckpt_9600.pt" --textures train

``--textures train``: the first 20 training textures; else a folder of photographs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from aectorch.evaluation import offset_sweep
from aectorch.runtime import load_learner
from aectorch.sim import TextureBank

OFFSETS = (-12.0, -8.0, -4.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 12.0)


def drive_table(checkpoint: Path, textures: str, cue: str, distances: tuple[float, ...]) -> list[dict]:
    """One row per offset: the mean drive, each scale's share and the bias's (over the views)."""
    _, learner = load_learner(checkpoint)
    cue_learner = learner.cues[cue]
    agent = cue_learner.agent
    if not hasattr(agent, "normalize") or not isinstance(getattr(agent, "policy", None), torch.nn.Linear):
        raise SystemExit(f"{checkpoint}: the {cue} cue's agent is not a linear PPO policy (agent=ppo, ppo.hidden=0)")
    bank = TextureBank(TextureBank.default("train").textures[:20]) if textures == "train" else \
        TextureBank.from_folder(textures)
    sweep = offset_sweep(learner, bank, cue=cue, offsets_deg=OFFSETS, distances_m=distances, features=True)
    actions = agent.actions_deg
    up, down = int(actions.argmax()), int(actions.argmin())
    weight = (agent.policy.weight[up] - agent.policy.weight[down]).detach().double()
    bias = float((agent.policy.bias[up] - agent.policy.bias[down]).detach())
    x = agent.normalize(sweep["features"].to(agent.feature_mean.dtype)).double()  # [N, K, F]
    groups, start = [], 0
    for scale in cue_learner.encoder.scales:
        size = cue_learner.encoder.dictionaries[scale.name].num_atoms
        groups.append((scale.name, slice(start, start + size)))
        start += size
    if start < x.shape[-1]:
        groups.append(("proprioception", slice(start, x.shape[-1])))
    rows = []
    for k, offset in enumerate(sweep["offsets_deg"].tolist()):
        shares = {name: float((x[:, k, part] * weight[part]).sum(-1).mean()) for name, part in groups}
        rows.append({"offset_deg": offset, "drive": sum(shares.values()) + bias, **shares, "bias": bias,
                     "mean_step_deg": float(sweep["expected_increment_deg"][:, k].mean())})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="LABEL=CHECKPOINT")
    parser.add_argument("--textures", default="train", help="'train' or a folder of photographs")
    parser.add_argument("--cue", default="parallax")
    parser.add_argument("--distances", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    for item in args.checkpoints:
        label, _, path = item.rpartition("=")
        rows = drive_table(Path(path), args.textures, args.cue, tuple(args.distances))
        names = [k for k in rows[0] if k not in ("offset_deg", "drive", "mean_step_deg")]
        print(f"\n{label or path} ({args.cue}, {args.textures}): logit(+max) - logit(-max) at each offset\n")
        print("| offset (deg) | drive | " + " | ".join(names) + " | mean step (deg) |")
        print("|---" * (len(names) + 3) + "|")
        for r in rows:
            print(f"| {r['offset_deg']:+.1f} | {r['drive']:+.2f} | " + " | ".join(f"{r[n]:+.2f}" for n in names)
                  + f" | {r['mean_step_deg']:+.2f} |")


if __name__ == "__main__":
    main()
