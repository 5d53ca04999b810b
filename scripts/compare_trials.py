"""Compare two evaluations of the same trials trial by trial (e.g. the torch renderer and pyrender).

    .venv/bin/python -m aectorch.evaluate checkpoint=<run>/checkpoint.pt textures=photos/ out=torch.json
    .venv/bin/python -m aectorch.evaluate checkpoint=<run>/checkpoint.pt textures=photos/ renderer=pyrender out=pyrender.json
    .venv/bin/python scripts/compare_trials.py torch.json pyrender.json [--tolerance 0.05] [--json out.json]

Both files must hold the same trials (``per_trial`` rows of `aectorch.evaluation`, matched by texture
and distance). For pursuit and vergence, at the end of each fixation, it prints the fraction of
fixation ends whose errors agree within ``--tolerance`` degrees, the largest difference, and the
trials that differ most.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _rows(path: Path) -> dict[tuple[str, float], dict]:
    result = json.loads(path.read_text())
    if "per_trial" not in result:
        raise KeyError(f"{path} has no per_trial rows (written by an older aectorch.evaluation?)")
    return {(r["texture"], round(r["distance_m"], 6)): r for r in result["per_trial"]}


def compare(a: dict, b: dict, tolerance: float) -> dict:
    """Agreement of two ``per_trial`` row sets keyed by (texture, distance)."""
    if set(a) != set(b):
        raise ValueError(f"the two evaluations hold different trials ({len(a)} and {len(b)}, "
                         f"{len(set(a) ^ set(b))} not in both)")
    out = {"trials": len(a), "tolerance_deg": tolerance}
    for cue in ("pursuit", "vergence"):
        diffs = sorted(((abs(x - y), key) for key in a
                        for x, y in zip(a[key][f"{cue}_errors_deg"], b[key][f"{cue}_errors_deg"])), reverse=True)
        out[cue] = {
            "agree": sum(d <= tolerance for d, _ in diffs) / len(diffs),
            "max_difference_deg": diffs[0][0],
            "worst": [{"texture": k[0], "distance_m": k[1], "difference_deg": d} for d, k in diffs[:5]],
        }
    both = [all(abs(x - y) <= tolerance for cue in ("pursuit", "vergence")
                for x, y in zip(a[k][f"{cue}_errors_deg"], b[k][f"{cue}_errors_deg"])) for k in a]
    out["both_agree_trials"] = sum(both) / len(both)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path)
    parser.add_argument("second", type=Path)
    parser.add_argument("--tolerance", type=float, default=0.05, help="degrees (default 0.05)")
    parser.add_argument("--json", type=Path, default=None, help="also write the comparison here")
    args = parser.parse_args(argv)
    try:
        result = compare(_rows(args.first), _rows(args.second), args.tolerance)
    except (OSError, KeyError, ValueError, json.JSONDecodeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{result['trials']} trials; errors agree within {args.tolerance} deg:")
    for cue in ("pursuit", "vergence"):
        r = result[cue]
        worst = ", ".join(f"{w['texture']} {w['distance_m']} m ({w['difference_deg']:.3f})" for w in r["worst"][:3])
        print(f"  {cue:9s} {r['agree']:.1%} of fixation ends; largest difference {r['max_difference_deg']:.3f} deg: {worst}")
    print(f"  trials with both cues agreeing at both fixation ends: {result['both_agree_trials']:.1%}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
