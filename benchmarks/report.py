"""The tables of docs/performance.md, from the results under benchmarks/results.

``python -m benchmarks.report`` prints them; ``--write docs/performance.md`` replaces each table
that follows a ``<!-- table: NAME -->`` line there (tests/test_benchmarks.py checks they agree).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from pathlib import Path

from benchmarks.harness import RESULTS


def rows(name: str, **match) -> list[dict]:
    found = json.loads((RESULTS / f"{name}.json").read_text())["rows"]
    return [r for r in found if all(r.get(k) == v for k, v in match.items())]


def floor_ms(row: dict) -> float:
    return 1e3 * sum(row["flops_per_env_iteration"].values()) / row["matmul_flops_per_s"]


def train_rate() -> list[list]:
    found = rows("train_rate.amd-epyc-avx512-2c")
    base = {r["isa"]: r for r in found if r["commit"] == "b39d619"}
    return [[r["commit"], r["isa"], ", ".join(f"{x:,.1f}" for x in r["rates"]), f"**{r['env_iterations_per_s']:,.1f}**",
             f"{r['env_iterations_per_s'] / base[r['isa']]['env_iterations_per_s']:.2f}x",
             f"{statistics.median(r['per_round_ratio_to_baseline']):.2f}x" if r is not base[r["isa"]] else ""]
            for r in found]


def stages() -> list[list]:
    native, avx2 = (rows("loop.amd-epyc-avx512-2c", isa=isa)[0] for isa in ("native", "avx2"))
    out = [[name, *(f"{r['ms_per_env_iteration'][name]:.3f}" for r in (native, avx2))]
           for name in ("render", "encode", "dictionary", "rl")]
    out.append(["env + metrics", *(f"{r['ms_per_env_iteration']['env'] + r['ms_per_env_iteration']['metrics']:.3f}"
                                   for r in (native, avx2))])
    out.append(["**all** (env-iterations/s)", *(f"{sum(r['ms_per_env_iteration'].values()):.3f} "
                                                f"({r['env_iterations_per_s']:,.0f})" for r in (native, avx2))])
    out.append(["floor (matmul GFLOP/s)", *(f"{floor_ms(r):.3f} ({r['matmul_flops_per_s'] / 1e9:.0f})"
                                            for r in (native, avx2))])
    out.append(["**x floor**", *(f"**{sum(r['ms_per_env_iteration'].values()) / floor_ms(r):.1f}x**"
                                 for r in (native, avx2))])
    out.append(["peak memory rise (MB)", *(f"{r['peak_memory_mb']:.0f}" for r in (native, avx2))])
    return out


def gpu() -> list[list]:
    found = rows("loop.nvidia-h200")
    eager = {r["B"]: r["env_iterations_per_s"] for r in found if r["mode"] == "eager"}
    return [[f"{r['B']:,}", r["mode"], f"{r['env_iterations_per_s']:,.0f}", f"{r['env_iterations_per_s'] / eager[r['B']]:.2f}x",
             f"{r['peak_memory_mb']:,.0f}"] for r in found]


def rl_envs() -> list[list]:
    found = rows("rl_envs.amd-epyc-2c")
    return [[r["variant"], f"{r['median_step_s'] * 1e3:.1f}", f"{r['env_iterations_per_s']:,.0f}",
             f"{r['env_iterations_per_s'] / found[0]['env_iterations_per_s']:.2f}x"] for r in found]


def coding_target() -> list[list]:
    return [[r["method"], f"{r['patches_per_s']:,.0f}", f"{r['x_sklearn']:.1f}x", f"{r['support_match_vs_sklearn']:.4f}",
             f"{r['patches_per_s'] / r['flop_floor_patches_per_s']:.1%}"] for r in rows("coding.amd-epyc-avx2-2c", run="target")]


def coding_sweep() -> list[list]:
    found = [r for r in rows("coding.amd-epyc-avx2-2c", run="sweep", threads=1) if "compiled" not in r["method"]]
    sizes = sorted({r["M"] for r in found})
    cell = {(r["method"], r["M"]): r for r in found}
    methods = list(dict.fromkeys(r["method"] for r in found))
    return ([["scikit-learn (patches/s)", *(f"{cell[methods[0], m]['sklearn_patches_per_s']:,.0f}" for m in sizes)]]
            + [[method, *(f"{cell[method, m]['x_sklearn']:.0f}x" for m in sizes)] for method in methods])


def render() -> list[list]:
    return [["320x240" if r["window"] == "full" else "128x128 crops", r["B"], r["threads"], f"{r['torch_frames_per_s']:,.0f}",
             f"{r['pyrender_frames_per_s']:,.0f}", f"{r['torch_over_pyrender']:.1f}x"]
            for r in sorted(rows("render.intel-xeon-avx512-2c"), key=lambda r: (r["window"] != "full", r["B"], r["threads"]))]


def depth() -> list[list]:
    return [[f"{r['N']:,}", r["method"], f"{r['train_mae_mm']:.2f}", f"{r['test_over_floor']:.3f}", f"{r['epochs']:g}",
             f"{r['seconds']:.3f}", ", ".join(r["stops"])] for r in rows("depth.intel-xeon-avx512-2c", validation=0.15)]


def depth_defaults() -> list[list]:
    return [[f"{r['N']:,}", r["method"], f"{r['test_over_floor']:.3f}", f"{r['epochs']:g}", f"{r['seconds']:.3f}",
             ", ".join(r["stops"])] for r in rows("depth.amd-epyc-avx512-2c")]


def minpack() -> list[list]:
    return [[r["method"], ", ".join(f"{x:.3f}" for x in r["per_seed_train_mse_over_minpack"]),
             f"{r['train_mse_over_minpack']:.3f}", f"{r['test_over_floor']:.3f}", f"{r['epochs']:g}", f"{r['seconds']:.2f}"]
            for r in rows("depth.intel-xeon-avx512-2c", validation=0.0)]


TABLES = {  # name: (header, right-aligned columns from, rows)
    "train_rate": (["code", "ISA", "rounds (env-it/s)", "median", "x b39d619", "per-round ratio"], 3, train_rate),
    "stages": (["stage (ms / env-iteration)", "native (AVX-512)", "AVX2"], 1, stages),
    "gpu": (["B", "mode", "env-iterations/s", "x eager", "peak GPU memory (MB)"], 2, gpu),
    "rl_envs": (["workload", "median step (ms)", "env-iterations/s", "x the training loop"], 1, rl_envs),
    "coding_target": (["method", "patches/s", "x sklearn", "support = sklearn", "of the FLOP floor"], 1, coding_target),
    "coding_sweep": (["method (x sklearn)", "M = 113", "1,808", "14,464", "115,712"], 1, coding_sweep),
    "render": (["window", "B", "threads", "torch", "pyrender (OSMesa)", "torch / pyrender"], 1, render),
    "depth": (["N", "method", "train MAE (mm)", "test / floor", "epochs", "wall (s)", "stop"], 2, depth),
    "depth_defaults": (["N", "method", "test / floor", "epochs", "wall (s)", "stop"], 2, depth_defaults),
    "minpack": (["method", "train MSE / MINPACK's, per seed", "median", "test / floor", "epochs", "wall (s)"], 1, minpack),
}


def table(name: str) -> str:
    header, right, make = TABLES[name]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" if i < right else "---:" for i in range(len(header))) + "|"]
    return "\n".join(lines + ["| " + " | ".join(str(cell) for cell in row) + " |" for row in make()])


def write(page: Path) -> str:
    """``page``'s text with every marked table regenerated."""
    pattern = re.compile(r"(<!-- table: (\w+) -->\n)(?:\|.*\n)*")
    return pattern.sub(lambda m: m.group(1) + table(m.group(2)) + "\n", page.read_text())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", type=Path, help="the page whose marked tables to regenerate in place")
    args = parser.parse_args(argv)
    if args.write:
        args.write.write_text(write(args.write))
    else:
        print("\n\n".join(f"<!-- table: {name} -->\n{table(name)}" for name in TABLES))


if __name__ == "__main__":
    main()
