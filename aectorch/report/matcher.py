"""The classical matcher through the learner's trials (``python -m aectorch.report matcher``)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from aectorch.baselines import Matcher
from aectorch.evaluation import evaluate
from aectorch.evaluation.summary import BEYOND_DEG, WITHIN_DEG
from aectorch.sim import TextureBank, resolve_protocol

__all__ = ["matcher_rows", "matcher_table"]


def matcher_table(textures: str | Path | None, distances_m: Sequence[float], *, free: bool = True,
                  renderer: str = "torch", progress: bool = False) -> dict[str, dict]:
    """The classical matcher (`aectorch.baselines.Matcher`) through the paper's test: the accuracy anchor.

    Runs `aectorch.evaluation.evaluate` (the trials, protocol and per-trial rows of
    ``python -m aectorch.evaluate``) for the matcher restricted to the learner's default actions
    and, with ``free``, for the unconstrained one (any increment), on ``textures`` (a folder of
    images; None: the 40 test textures) at ``distances_m``. Returns ``{controller: evaluation}``,
    the JSON ``--json`` writes; `matcher_rows` prints it.
    """
    bank = TextureBank.default("test") if textures is None else TextureBank.from_folder(textures)
    variants = {"matcher, the learner's actions": Matcher()}
    if free:
        variants["matcher, unconstrained"] = Matcher(actions_deg=None)
    out = {}
    for name, matcher in variants.items():
        result = evaluate(matcher, bank, distances_m=distances_m, protocol=resolve_protocol(renderer=renderer),
                          progress=progress)
        result.update(textures=str(textures) if textures is not None else "test textures", renderer=renderer)
        out[name] = result
    return out


def matcher_rows(results: dict[str, dict]) -> list[str]:
    """`matcher_table`'s evaluations as markdown, one row per controller."""
    head = (f"| controller | trials | pursuit MAE (deg) | vergence MAE (deg) | both within {WITHIN_DEG} deg | "
            f"either beyond {BEYOND_DEG:g} deg | last 5: pursuit / vergence (deg) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for name, r in results.items():
        both, last = r["fractions"]["both"], r["last5"]
        lines.append(f"| {name} | {r['trials']} | {r['pursuit_mae_deg']:.3f} | {r['vergence_mae_deg']:.3f} | "
                     f"{both['within']:.1%} | {both['beyond']:.1%} | "
                     f"{last['pursuit_mae_deg']:.3f} / {last['vergence_mae_deg']:.3f} |")
    return lines
