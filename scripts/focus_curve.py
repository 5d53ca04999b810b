"""The rewards against defocus: which way the coding reward, the input's energy and the focus
reward go when both eyes are focused off the object (issue 53; docs/results.md, "Accommodation").

A stereo coder (the default cue's scales and dictionaries) first learns for ``--steps`` steps on
the training textures, each pair seen with both eyes at the optimal vergence and a focus drawn
uniformly within +-``--spread`` D of the object (what an eye that learns to focus sees); it then
codes the test textures and a folder of photographs at each defocus of the grid, at 1.0, 1.5, ...,
3.0 m, and writes the mean of each measure per defocus (JSON) and a figure.

    PYTHONPATH=. .venv/bin/python scripts/focus_curve.py --photos data/choose-photos \\
        --out docs/figures/focus_curve.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from aectorch.coding.focus import focus_reward, input_energy
from aectorch.figures import plot_focus_curve
from aectorch.framework import CueConfig, CueLearner
from aectorch.sim import ActiveDepthEnv, TextureBank

DISTANCES_M = (1.0, 1.5, 2.0, 2.5, 3.0)


def measures(encoder, observation) -> dict[str, torch.Tensor]:
    """Per environment ``[B]``: the coding reward -sum e, the input energy term sum 1/2 log E and
    the focus reward sum 1/2 log(E (1 - e))."""
    out = encoder.encode(observation)
    energy = [input_energy(observation[s.name], s) for s in encoder.scales]
    errors = [code.error for code in out.codes]
    return {"coding": out.reward,
            "energy": torch.stack([(E + 1e-12).log().mean(-1) / 2 for E in energy], -1).sum(-1),
            "focus": focus_reward(energy, errors)}


def train_coder(steps: int, spread: float, aperture_m: float, batch: int, seed: int):
    config = CueConfig()
    encoder = CueLearner.build_encoder(config, generator=torch.Generator().manual_seed(seed))
    env = ActiveDepthEnv(batch, aperture_m=aperture_m, seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    for _ in range(steps):
        index = torch.randint(len(env.textures), (batch,), generator=g)
        distance = 1.0 + 2.0 * torch.rand(batch, generator=g)
        env.set_trial(index, distance)
        env.apply_vergence(env.vergence_to_optimum())
        focus = (1.0 / distance + spread * (2 * torch.rand(batch, generator=g) - 1)).clamp_min(0.0)
        env.set_focus(focus[:, None].expand(batch, 2))
        encoder.learn_(encoder.encode(env.stereo_observation(encoder.scales)))
    return encoder


def curve(encoder, textures: TextureBank, grid: list[float], aperture_m: float) -> dict[str, list[float]]:
    n = len(textures)
    index = torch.arange(n).repeat_interleave(len(DISTANCES_M))
    distance = torch.tensor(DISTANCES_M).repeat(n)
    env = ActiveDepthEnv(len(index), textures=textures, aperture_m=aperture_m, distances_m=DISTANCES_M, seed=0)
    env.set_trial(index, distance)
    env.apply_vergence(env.vergence_to_optimum())
    rows = {"defocus_D": grid, "coding": [], "energy": [], "focus": []}
    with torch.no_grad():
        for d in grid:
            env.set_focus((1.0 / distance + d).clamp_min(0.0)[:, None].expand(len(index), 2))
            for name, value in measures(encoder, env.stereo_observation(encoder.scales)).items():
                rows[name].append(float(value.mean()))
    env.close()
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", required=True, help="a folder of photographs (the choosing photographs)")
    parser.add_argument("--out", default="docs/figures/focus_curve.png")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--spread", type=float, default=1.0, help="dioptres of defocus the coder learns on")
    parser.add_argument("--aperture-m", type=float, default=0.016)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    encoder = train_coder(args.steps, args.spread, args.aperture_m, args.batch, args.seed)
    grid = [round(-1.0 + 0.1 * i, 1) for i in range(21)]
    result = {"aperture_m": args.aperture_m, "steps": args.steps, "spread_D": args.spread, "seed": args.seed,
              "textures": curve(encoder, TextureBank.default("test"), grid, args.aperture_m),
              "photographs": curve(encoder, TextureBank.from_folder(args.photos, progress=False), grid,
                                   args.aperture_m)}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    plot_focus_curve(result, out)
    for name in ("textures", "photographs"):
        rows = result[name]
        for measure in ("coding", "energy", "focus"):
            values = rows[measure]
            peak = [d for d, v in zip(rows["defocus_D"], values) if v >= max(values) - 1e-9]
            print(f"{name:12s} {measure:7s} peaks at {min(peak):+.1f}..{max(peak):+.1f} D  (at 0: {values[10]:.4f}, "
                  f"at -1: {values[0]:.4f}, at +1: {values[-1]:.4f})")


if __name__ == "__main__":
    main()
