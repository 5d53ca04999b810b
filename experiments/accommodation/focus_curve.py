"""The rewards against defocus, as a figure and its numbers: the accommodation study's focus curve.

    .venv/bin/python experiments/accommodation/focus_curve.py --photos data/choose-photos \
        [--out experiments/accommodation/focus_curve.png] [--steps 300] [--batch 16] [--spread 1]

A stereo coder learns on the training textures with both eyes at the optimal vergence and focused
within +-``spread`` D of the object, then codes the test textures and the photographs at each
defocus; README.md here says what the curve shows. A bad argument or an output it cannot write
prints one ``error:`` line and exits with status 2 (`aectorch.report.command.run_command`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from aectorch.coding.focus import focus_reward, input_energy  # noqa: E402
from aectorch.figures import COLORS, EVENT_STYLE, save_figure  # noqa: E402
from aectorch.framework import CueConfig, CueLearner  # noqa: E402
from aectorch.report.command import run_command, study_parser  # noqa: E402
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol  # noqa: E402

__all__ = ["DISTANCES_M", "focus_curve", "focus_measures", "main", "parser", "plot_focus_curve", "train_focus_coder"]

#: The distances the focus curve codes each image at (m).
DISTANCES_M = (1.0, 1.5, 2.0, 2.5, 3.0)
HERE = Path(__file__).resolve().parent


def focus_measures(encoder, observation) -> dict[str, torch.Tensor]:
    """Per environment ``[B]``: the coding reward -sum e, the input-energy term sum 1/2 log E and
    the focus reward sum 1/2 log(E (1 - e)) (`aectorch.coding.focus`)."""
    out = encoder.encode(observation)
    energy = [input_energy(observation[s.name], s) for s in encoder.scales]
    errors = [code.error for code in out.codes]
    return {"coding": out.reward,
            "energy": torch.stack([(E + 1e-12).log().mean(-1) / 2 for E in energy], -1).sum(-1),
            "focus": focus_reward(energy, errors)}


def train_focus_coder(steps: int, spread: float, aperture_m: float, batch: int, seed: int):
    """A stereo coder (the default cue's scales) that learned for ``steps`` steps on the training
    textures, both eyes at the optimal vergence and focused uniformly within +-``spread`` D of the
    object (what an eye that learns to focus sees)."""
    encoder = CueLearner.build_encoder(CueConfig(), generator=torch.Generator().manual_seed(seed))
    env = ActiveDepthEnv(batch, protocol=TrialProtocol(aperture_m=aperture_m), seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    for _ in range(steps):
        index = torch.randint(len(env.textures), (batch,), generator=g)
        distance = 1.0 + 2.0 * torch.rand(batch, generator=g)
        env.set_trial(index, distance)
        env.hold("stereo")
        focus = (1.0 / distance + spread * (2 * torch.rand(batch, generator=g) - 1)).clamp_min(0.0)
        env.set_focus(focus[:, None].expand(batch, 2))
        encoder.learn_(encoder.encode(env.stereo_observation(encoder.scales)))
    env.close()
    return encoder


def _curve(encoder, textures: TextureBank, grid: Sequence[float], aperture_m: float) -> dict[str, list[float]]:
    n = len(textures)
    index = torch.arange(n).repeat_interleave(len(DISTANCES_M))
    distance = torch.tensor(DISTANCES_M).repeat(n)
    env = ActiveDepthEnv(len(index), protocol=TrialProtocol(aperture_m=aperture_m), textures=textures,
                         distances_m=DISTANCES_M, seed=0)
    env.set_trial(index, distance)
    env.hold("stereo")
    rows: dict[str, list[float]] = {"defocus_D": list(grid), "coding": [], "energy": [], "focus": []}
    with torch.no_grad():
        for d in grid:
            env.set_focus((1.0 / distance + d).clamp_min(0.0)[:, None].expand(len(index), 2))
            for name, value in focus_measures(encoder, env.stereo_observation(encoder.scales)).items():
                rows[name].append(float(value.mean()))
    env.close()
    return rows


def plot_focus_curve(result: Mapping, path: str | os.PathLike) -> Path:
    """The rewards against defocus: one panel per image set (``result``'s entries with
    ``defocus_D`` and the measures ``coding``, ``energy``, ``focus``), each measure shifted to 0 at
    zero defocus, so that where each peaks reads at a glance.

    Example:
        >>> import tempfile
        >>> rows = {"defocus_D": [-1, 0, 1], "coding": [-1, -2, -1], "energy": [0, 1, 0], "focus": [0, 1, 0]}
        >>> plot_focus_curve({"textures": rows}, Path(tempfile.mkdtemp()) / "focus.png").exists()
        True
    """
    from matplotlib.figure import Figure  # Agg renders it on savefig; pyplot is never used

    sets = {name: rows for name, rows in result.items() if isinstance(rows, Mapping) and "defocus_D" in rows}
    if not sets:
        raise ValueError(f"result has no image set with 'defocus_D' (has {sorted(result)})")
    fig = Figure(figsize=(4.5 * len(sets), 3.6))
    axes = fig.subplots(1, len(sets), squeeze=False)[0]
    labels = {"coding": "coding reward -sum e", "energy": "input energy 1/2 log E", "focus": "focus reward 1/2 log E(1-e)"}
    for ax, (name, rows) in zip(axes, sets.items()):
        defocus = [float(d) for d in rows["defocus_D"]]
        zero = min(range(len(defocus)), key=lambda i: abs(defocus[i]))
        for i, (key, label) in enumerate(labels.items()):
            if key in rows:
                values = [float(v) - float(rows[key][zero]) for v in rows[key]]
                ax.plot(defocus, values, marker="o", markersize=3, color=COLORS[i % len(COLORS)], label=label)
        ax.axvline(0.0, **EVENT_STYLE)
        ax.set_xlabel("defocus (D)")
        ax.set_ylabel("change from zero defocus")
        ax.set_title(name, loc="left", fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Rewards against defocus (both eyes, optimal vergence)", fontsize=11)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.45 / fig.get_figheight()))
    return save_figure(fig, path)


def focus_curve(photos: str | os.PathLike, out: str | os.PathLike, steps: int = 300, batch: int = 16,
                spread: float = 1.0, aperture_m: float = 0.016, seed: int = 0, textures: int | None = None) -> list[str]:
    """The rewards against defocus (-1 to +1 D): a coder trained as `train_focus_coder` codes the
    test textures (the first ``textures`` of them; default all 40) and the photographs of
    ``photos`` at each defocus, at 1.0-3.0 m; the mean of each measure per defocus goes to ``out``
    (a figure) and beside it as JSON; one line per set and measure says where it peaks."""
    test = TextureBank.default("test")
    if textures is not None:
        if not 1 <= textures <= len(test):
            raise ValueError(f"--textures must be 1 to {len(test)}, got {textures}")
        test = test.subset(list(range(textures)))
    encoder = train_focus_coder(steps, spread, aperture_m, batch, seed)
    grid = [round(-1.0 + 0.1 * i, 1) for i in range(21)]
    result: dict[str, Any] = {
        "aperture_m": aperture_m, "steps": steps, "spread_D": spread, "seed": seed,
        "textures": _curve(encoder, test, grid, aperture_m),
        "photographs": _curve(encoder, TextureBank.from_folder(photos, progress=False), grid, aperture_m)}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    plot_focus_curve(result, out)
    lines = []
    for name in ("textures", "photographs"):
        rows = result[name]
        for measure in ("coding", "energy", "focus"):
            values = rows[measure]
            peak = [d for d, v in zip(rows["defocus_D"], values) if v >= max(values) - 1e-9]
            lines.append(f"{name:12s} {measure:7s} peaks at {min(peak):+.1f}..{max(peak):+.1f} D  (at 0: "
                         f"{values[10]:.4f}, at -1: {values[0]:.4f}, at +1: {values[-1]:.4f})")
    return lines + [f"wrote {out}"]


def _report(args) -> list[str]:
    return focus_curve(args.photos, args.out, args.steps, args.batch, args.spread, args.aperture_m, args.seed,
                       args.textures)


def parser() -> argparse.ArgumentParser:
    """The command line: its help is `focus_curve`'s docstring."""
    out = study_parser("experiments/accommodation/focus_curve.py", focus_curve, _report)
    out.add_argument("--photos", required=True, help="a folder of photographs (the choosing photographs)")
    out.add_argument("--out", type=Path, default=HERE / "focus_curve.png", help="the figure (PNG; default: here)")
    out.add_argument("--steps", type=int, default=300, help="steps the coder learns for")
    out.add_argument("--batch", type=int, default=16, help="environments per step")
    out.add_argument("--spread", type=float, default=1.0, help="dioptres of defocus the coder learns on")
    out.add_argument("--aperture-m", type=float, default=0.016, help="the pupil's diameter (m)")
    out.add_argument("--seed", type=int, default=0)
    out.add_argument("--textures", type=int, default=None, help="only the first this many test textures (default: all)")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Draw the curve and print where each measure peaks; 0, or 2 after one ``error:`` line."""
    return run_command(parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
