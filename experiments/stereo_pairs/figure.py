"""The stereo pairs' figure: a pair, its fixation points, the error map and the errors against the
ground truth's roughness.

    .venv/bin/python experiments/stereo_pairs/figure.py data/stereo-pairs/motorcycle \
        runs/pairs_default_s0/pairs_ps1.json experiments/stereo_pairs/motorcycle.png

Four panels: the left photograph with the fixation points (circles: smooth windows, crosses:
windows across a depth edge); the ground-truth disparity (photo pixels; white: unknown); the error
map, each point coloured by the learner's final |error| from the protocol's start (eye pixels); and
the learner's and the matcher's final |error| against the roughness of the ground truth in the
coarse window (its distance from a plane, `aectorch.sim.stereo_pairs.disparity_roughness`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.ticker import NullFormatter
from matplotlib.figure import Figure

from aectorch.sim.stereo_pairs import read_pair


def draw(pair_folder: Path, evaluation: Path, out: Path, start: str = "protocol") -> None:
    pair = read_pair(pair_folder)
    result = json.loads(evaluation.read_text())
    rows = [r for r in result["per_fixation"] if r["pair"] == pair.name and r["start"] == start]
    learner = [r for r in rows if r["policy"] == "learner"]
    fig = Figure(figsize=(12, 8), layout="constrained")
    axes = fig.subplots(2, 2).reshape(-1)
    x, y = np.array([r["x"] for r in learner]), np.array([r["y"] for r in learner])
    edge = np.array([r["window"] == "edge" for r in learner])
    axes[0].imshow(pair.left.numpy(), cmap="gray", vmin=0, vmax=1)
    axes[0].scatter(x[~edge], y[~edge], s=14, facecolors="none", edgecolors="lime", label="smooth window")
    axes[0].scatter(x[edge], y[edge], s=14, marker="x", color="orange", label="across a depth edge")
    axes[0].legend(loc="lower left", fontsize=7)
    axes[0].set_title(f"{pair.name}: left photograph, {len(learner)} fixation points", fontsize=10)
    shown = axes[1].imshow(pair.disparity.numpy(), cmap="viridis")
    fig.colorbar(shown, ax=axes[1], shrink=0.8, label="disparity (photo px)")
    axes[1].set_title("ground-truth disparity (white: unknown)", fontsize=10)
    error = np.array([abs(r["vergence_error_px"]) for r in learner])
    axes[2].imshow(pair.left.numpy(), cmap="gray", vmin=0, vmax=1, alpha=0.5)
    dots = axes[2].scatter(x, y, c=np.clip(error, 0.05, 50), s=18, cmap="magma_r", norm=LogNorm(0.05, 50))
    fig.colorbar(dots, ax=axes[2], shrink=0.8, label="final |error| (eye px)")
    axes[2].set_title(f"learner's final |error| ({start.replace('_', ' ')} start, pair scale {result['pair_scale']})",
                      fontsize=10)
    for name, colour in (("learner", "C0"), ("matcher", "C1")):
        chosen = [r for r in rows if r["policy"] == name]
        axes[3].scatter([r["plane_residual_px"] for r in chosen],
                        [max(abs(r["vergence_error_px"]), 0.01) for r in chosen], s=8, color=colour, label=name,
                        alpha=0.6)
    axes[3].axvline(result["edge_residual_px"], color="grey", linestyle=":", label="edge threshold")
    axes[3].axhline(1.0, color="grey", linewidth=0.5)
    axes[3].set(xscale="log", yscale="log", xlabel="ground truth's distance from a plane in the coarse window (eye px)",
                ylabel="final |error| (eye px)")
    axes[3].set_title(f"final |error| against depth structure ({start.replace('_', ' ')} start)", fontsize=10)
    axes[3].xaxis.set_minor_formatter(NullFormatter())
    axes[3].legend(fontsize=7)
    for ax in axes[:3]:
        ax.set_axis_off()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pair", type=Path, help="the pair's folder (either layout)")
    parser.add_argument("evaluation", type=Path, help="python -m aectorch.evaluate pairs=...'s JSON")
    parser.add_argument("out", type=Path, help="the figure, a .png")
    parser.add_argument("--start", default="protocol", choices=("protocol", "vergence_test"))
    args = parser.parse_args(argv)
    draw(args.pair, args.evaluation, args.out, args.start)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
