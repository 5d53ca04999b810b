"""The tables of docs/performance.md from benchmarks/results: ``python -m benchmarks.report`` prints
them, ``--write docs/performance.md`` replaces each table after a ``<!-- table: NAME -->`` line."""

import argparse
import json
import re
import statistics
from pathlib import Path

from benchmarks.harness import RESULTS


def rows(name: str, **match) -> list[dict]:
    found = json.loads((RESULTS / f"{name}.json").read_text())["rows"]
    return [r for r in found if all(r.get(k) == v for k, v in match.items())]


def stages() -> list[list]:
    pair = [rows("loop.amd-epyc-avx512-2c", isa=isa)[0] for isa in ("native", "avx2")]
    ms = lambda r, *names: sum(r["ms_per_env_iteration"][n] for n in names or r["ms_per_env_iteration"])  # noqa: E731
    floor = lambda r: 1e3 * sum(r["flops_per_env_iteration"].values()) / r["matmul_flops_per_s"]  # noqa: E731
    cells = {**{name: lambda r, n=name: f"{ms(r, n):.3f}" for name in ("render", "encode", "dictionary", "rl")},
             "env + metrics": lambda r: f"{ms(r, 'env', 'metrics'):.3f}",
             "**all** (env-iterations/s)": lambda r: f"{ms(r):.3f} ({r['env_iterations_per_s']:,.0f})",
             "floor (matmul GFLOP/s)": lambda r: f"{floor(r):.3f} ({r['matmul_flops_per_s'] / 1e9:.0f})",
             "**x floor**": lambda r: f"**{ms(r) / floor(r):.1f}x**",
             "peak memory rise (MB)": lambda r: f"{r['peak_memory_mb']:.0f}"}
    return [[label, *(cell(r) for r in pair)] for label, cell in cells.items()]


def train_rate() -> list[list]:
    found = rows("train_rate.amd-epyc-avx512-2c")
    base = {r["isa"]: r for r in found if r["commit"] == "b39d619"}
    return [[r["commit"], r["isa"], ", ".join(f"{x:,.1f}" for x in r["rates"]), f"**{r['env_iterations_per_s']:,.1f}**",
             f"{r['env_iterations_per_s'] / base[r['isa']]['env_iterations_per_s']:.2f}x",
             f"{statistics.median(r['per_round_ratio_to_baseline']):.2f}x" if r is not base[r["isa"]] else ""]
            for r in found]


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


def depth(name: str, **match) -> list[list]:
    return [[f"{r['N']:,}", r["method"], f"{r['train_mae_mm']:.2f}", f"{r['test_over_floor']:.3f}", f"{r['epochs']:g}",
             f"{r['seconds']:.3f}", ", ".join(r["stops"])] for r in rows(name, **match)]


def minpack() -> list[list]:
    return [[r["method"], ", ".join(f"{x:.3f}" for x in r["per_seed_train_mse_over_minpack"]),
             f"{r['train_mse_over_minpack']:.3f}", f"{r['test_over_floor']:.3f}", f"{r['epochs']:g}", f"{r['seconds']:.2f}"]
            for r in rows("depth.intel-xeon-avx512-2c", validation=0.0)]


DEPTH = ["N", "method", "train MAE (mm)", "test / floor", "epochs", "wall (s)", "stop"]
TABLES = {  # name: (header, right-aligned columns from, rows)
    "train_rate": (["code", "ISA", "rounds (env-it/s)", "median", "x b39d619", "per-round ratio"], 3, train_rate),
    "stages": (["stage (ms / env-iteration)", "native (AVX-512)", "AVX2"], 1, stages),
    "gpu": (["B", "mode", "env-iterations/s", "x eager", "peak GPU memory (MB)"], 2, gpu),
    "rl_envs": (["workload", "median step (ms)", "env-iterations/s", "x the training loop"], 1, rl_envs),
    "coding_target": (["method", "patches/s", "x sklearn", "support = sklearn", "of the FLOP floor"], 1, coding_target),
    "coding_sweep": (["method (x sklearn)", "M = 113", "1,808", "14,464", "115,712"], 1, coding_sweep),
    "render": (["window", "B", "threads", "torch", "pyrender (OSMesa)", "torch / pyrender"], 1, render),
    "depth": (DEPTH, 2, lambda: depth("depth.intel-xeon-avx512-2c", validation=0.15)),
    "depth_defaults": (DEPTH, 2, lambda: depth("depth.amd-epyc-avx512-2c")),
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
    page = parser.parse_args(argv).write
    if page:
        page.write_text(write(page))
    else:
        print("\n\n".join(f"<!-- table: {name} -->\n{table(name)}" for name in TABLES))


if __name__ == "__main__":
    main()
