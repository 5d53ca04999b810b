"""The final state's errors of the trials in a band of distances, mean over runs.

    .venv/bin/python scripts/distance_band.py runs/ppo_full_s0 runs/ppo_full_s1 runs/ppo_full_s2 \
        --eval final_report.json --low 1.0 --high 1.5

Reads each run's evaluation (``per_trial`` rows of ``python -m aectorch.evaluate``) and prints,
averaged over the runs, the pursuit, vergence and depth MAE of the trials at ``low`` to ``high``
metres, the fraction of their fixation ends with both eyes within 0.22 deg and either beyond 2 deg,
and the depth error's mean (its bias).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def band(path: Path, low: float, high: float) -> dict:
    rows = [r for r in json.loads(path.read_text())["per_trial"] if low - 1e-9 <= r["distance_m"] <= high + 1e-9]
    ends = [(p, v) for r in rows for p, v in zip(r["pursuit_errors_deg"], r["vergence_errors_deg"])]
    depth = [r["depth_error_m"] for r in rows if r["depth_error_m"] is not None]
    return {"trials": len(rows),
            "pursuit_mae_deg": statistics.fmean(abs(p) for p, _ in ends),
            "vergence_mae_deg": statistics.fmean(abs(v) for _, v in ends),
            "depth_mae_m": statistics.fmean(abs(d) for d in depth) if depth else float("nan"),
            "depth_bias_m": statistics.fmean(depth) if depth else float("nan"),
            "within_1px": statistics.fmean(abs(p) <= 0.22 and abs(v) <= 0.22 for p, v in ends),
            "beyond_2deg": statistics.fmean(abs(p) > 2.0 or abs(v) > 2.0 for p, v in ends)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--eval", default="final_report.json")
    parser.add_argument("--low", type=float, required=True)
    parser.add_argument("--high", type=float, required=True)
    args = parser.parse_args(argv)
    per_run = [band(run / args.eval, args.low, args.high) for run in args.runs]
    mean = {k: statistics.fmean(r[k] for r in per_run) for k in per_run[0]}
    print(f"{args.low}-{args.high} m, {args.eval}, mean of {len(per_run)} runs: pursuit {mean['pursuit_mae_deg']:.3f} deg, "
          f"vergence {mean['vergence_mae_deg']:.3f} deg, depth {mean['depth_mae_m']:.3f} m (bias "
          f"{mean['depth_bias_m']:+.3f} m), within 1 px {mean['within_1px']:.1%}, beyond 2 deg {mean['beyond_2deg']:.1%} "
          f"({per_run[0]['trials']} trials each)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
