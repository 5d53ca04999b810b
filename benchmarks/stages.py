"""Where an iteration of the default run goes, stage by stage, beside each stage's floor; memory per environment.

For each B (``--batches``) and kernel-thread count (``--kernel-threads``; torch's own operations
on one thread, as ``train.threads=0`` runs them), in a fresh process: ``train.py``'s default
environments and learner (``ExperimentConfig()``), ``--warmup`` iterations, then ``--iterations``
timed with :class:`aectorch.profiling.StageTimer` (with the heap frozen, as the training loop runs). Per stage:

  * milliseconds per env-iteration (stage time / B);
  * its matrix-product FLOPs per env-iteration (``FlopCounterMode`` over one iteration, stage by
    stage, with the pure-torch pursuit so that the products inside the fused kernel are
    counted; the dictionary step's are those of the sparse gradient it runs, ``2 M k P`` per
    dictionary, not the dense product of the torch backend) and the **floor** they imply at this machine's sustained float32 matmul rate
    (measured in the same process on the loop's largest product, on as many threads as the
    kernels use, the faster of torch's product (MKL) and oneDNN's, which the fused kernels call:
    on an AMD CPU with AVX-512 oneDNN's runs at about twice MKL's rate); rendering has no matrix
    products: its row gives the rendered pixels and bilinear lookups per env-iteration instead;
  * the process's peak resident memory rise over the imports (``VmHWM``), whose slope against B
    is the memory per environment.

``--isa avx2`` runs the same on what a CPU without AVX-512 would execute: the fused kernels built
for ``x86-64-v3`` (AVX2, ``AECTORCH_NATIVE_MARCH``), torch's own kernels dispatched at AVX2
(``ATEN_CPU_CAPABILITY=avx2``), MKL and oneDNN limited to AVX2 (``MKL_ENABLE_INSTRUCTIONS=AVX2``,
``ONEDNN_MAX_CPU_ISA=AVX2``): the instruction set of an AVX2 machine, on this machine's cores and
caches.

Usage:
    python benchmarks/stages.py [--batches 32 256] [--kernel-threads 1 2] [--isa native avx2] [--repeats 5] [--json benchmarks/results/stages.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("render", "encode", "dictionary", "rl", "env", "metrics", "depth")
#: Environment of a worker per instruction set (``--isa``).
ISAS = {
    "native": {},
    "avx2": {"AECTORCH_NATIVE_MARCH": "x86-64-v3", "ATEN_CPU_CAPABILITY": "avx2", "MKL_ENABLE_INSTRUCTIONS": "AVX2",
             "ONEDNN_MAX_CPU_ISA": "AVX2"},
}


def _rss_mb(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def worker(batch: int, kernel_threads: int, iterations: int, warmup: int) -> dict:
    sys.path.insert(0, str(ROOT))
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from aectorch import profiling
    from aectorch.coding import use_backend
    from aectorch.ops import native
    from aectorch.runtime.config import ExperimentConfig
    from aectorch.runtime import build_env, build_learner
    from aectorch.sim.env import _finer

    torch.set_num_threads(1)
    native.set_threads(kernel_threads)
    base = _rss_mb("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")
    cfg = ExperimentConfig()
    cfg.env.num_envs = batch
    env, learner = build_env(cfg), build_learner(cfg)
    for _ in range(warmup):
        learner.iteration(env)
    from aectorch.runtime.loop import frozen_heap

    with frozen_heap(), profiling.StageTimer() as timer:  # the heap frozen as the training loop runs
        start = time.perf_counter()
        for _ in range(iterations):
            learner.iteration(env)
        wall = time.perf_counter() - start
    peak = _rss_mb("VmHWM") - base

    class FlopStages(profiling.StageTimer):  # one FlopCounterMode per stage
        def __init__(self):
            super().__init__()
            self.flops = {}
            self._counters = []

        def _push(self, name):
            counter = FlopCounterMode(display=False)
            counter.__enter__()
            self._counters.append(counter)
            super()._push(name)

        def _pop(self, name):
            super()._pop(name)
            counter = self._counters.pop()
            counter.__exit__(None, None, None)
            self.flops[name] = self.flops.get(name, 0) + counter.get_total_flops()

    with use_backend("torch"), FlopStages() as flops:
        learner.iteration(env)
    threads = kernel_threads
    torch.set_num_threads(threads)  # the matmul rate on the kernels' thread count
    a, b = torch.randn(batch * 122, 200), torch.randn(200, 288)
    out, b_t = torch.empty(batch * 122, 288), b.t().contiguous()
    products = {"mm": lambda: torch.mm(a, b, out=out)}  # torch's product: MKL on x86
    if hasattr(torch.ops.mkldnn, "_linear_pointwise"):  # oneDNN's, which the fused kernels call
        products["onednn"] = lambda: torch.ops.mkldnn._linear_pointwise(a, b_t, None, "none", [], "")
    rates = {}
    for name, product in products.items():
        times = []
        for _ in range(12):
            t = time.perf_counter()
            for _ in range(5):
                product()
            times.append((time.perf_counter() - t) / 5)
        rates[name] = 2 * a.shape[0] * 200 * 288 / statistics.median(times[2:])
    rate = max(rates.values())  # the floor: the faster of the two
    scales = learner.parallax.encoder.scales
    pixels = sum(((s.crop + 2 * s.downsample) * _finer(s.downsample) // s.downsample) ** 2 for s in scales)
    # The dictionary step runs the sparse gradient (aectorch::sparse_gradient: k atoms per patch), not
    # the dense product the torch backend counts: its floor is that scatter's multiply-adds.
    sparse = 0
    for cue in learner.cues.values():
        for scale in cue.encoder.scales:
            d = cue.encoder.dictionaries[scale.name]
            sparse += 2 * batch * scale.num_patches * d.sparsity * d.dim
    flops.flops["dictionary"] = sparse
    return {
        "B": batch, "kernel_threads": kernel_threads, "iterations": iterations,
        "env_iterations_per_s": batch * iterations / wall,
        "ms_per_env_iteration": {k: 1e3 * timer.seconds.get(k, 0.0) / iterations / batch for k in STAGES},
        "flops_per_env_iteration": {k: flops.flops.get(k, 0) / batch for k in STAGES},
        "matmul_flops_per_s": rate,
        "matmul_flops_per_s_by_library": rates,
        # eye images per iteration: 3 (parallax second, stereo pair), less the reused ones
        "rendered_pixels_per_eye_image": pixels,
        "peak_rss_rise_mb": peak,
    }


def _x_floor(row: dict) -> float:
    """All stages' milliseconds per env-iteration over the floor of their matrix products."""
    floor = 1e3 * sum(row["flops_per_env_iteration"].values()) / row["matmul_flops_per_s"]
    return sum(row["ms_per_env_iteration"].values()) / floor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[32, 256])
    parser.add_argument("--kernel-threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--isa", nargs="+", default=["native"], choices=list(ISAS),
                        help="instruction sets to run on (default: native; avx2: no AVX-512, see above)")
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=1,
                        help="runs per row, in interleaved rounds; the table shows each row's median run")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "stages.json")
    parser.add_argument("--from-json", type=Path, default=None, help="only print the table of an earlier run")
    parser.add_argument("--worker", nargs=2, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(*args.worker, args.iterations, args.warmup)))
        return
    rows = []
    if args.from_json is not None:
        rows = json.loads(args.from_json.read_text())["rows"]
        args.batches = sorted({row["B"] for row in rows})
    runs: dict[tuple, list[dict]] = {}
    for repeat in range(0 if args.from_json is not None else args.repeats):  # rounds: drift hits every row
        for batch in args.batches:
            for threads in args.kernel_threads:
                for isa in args.isa:
                    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE", PYOPENGL_PLATFORM="osmesa", **ISAS[isa])
                    iterations = max(8, args.iterations * 32 // batch)
                    result = subprocess.run([sys.executable, __file__, "--worker", str(batch), str(threads),
                                             "--iterations", str(iterations), "--warmup", str(args.warmup)],
                                            env=env, stdout=subprocess.PIPE, text=True, check=True)
                    run = dict(json.loads(result.stdout.strip().splitlines()[-1]), isa=isa)
                    runs.setdefault((batch, threads, isa), []).append(run)
                    print(f"round {repeat + 1}: B={batch}, kernel threads {threads}, {isa}: "
                          f"{run['env_iterations_per_s']:,.0f} env-iterations/s, {_x_floor(run):.1f}x floor",
                          file=sys.stderr, flush=True)
    for key, found in runs.items():  # each row: its median run by the ratio to the floor
        ordered = sorted(found, key=_x_floor)
        rows.append(dict(ordered[(len(ordered) - 1) // 2], repeats=[
            {"env_iterations_per_s": r["env_iterations_per_s"], "x_floor": _x_floor(r)} for r in found]))
    if len(runs) and args.repeats > 1:
        for row in rows:
            ratios = sorted(r["x_floor"] for r in row["repeats"])
            print(f"B={row['B']}, kernel threads {row['kernel_threads']}, {row['isa']}: x floor over "
                  f"{len(ratios)} runs {', '.join(f'{x:.1f}' for x in ratios)} (median run below)", file=sys.stderr)
    isa_column = any(row.get("isa", "native") != "native" for row in rows)
    print("| B | kernel threads |" + (" ISA |" if isa_column else "")
          + " stage | ms / env-iteration | MFLOP / env-iteration | floor (ms) | x floor |")
    print("|---:|---:|" + ("---|" if isa_column else "") + "---|---:|---:|---:|---:|")
    for row in rows:
        lead = f"| {row['B']} | {row['kernel_threads']} |" + (f" {row.get('isa', 'native')} |" if isa_column else "")
        for name in STAGES:
            ms = row["ms_per_env_iteration"][name]
            flops = row["flops_per_env_iteration"][name]
            if ms < 0.0005 and not flops:
                continue
            floor = 1e3 * flops / row["matmul_flops_per_s"] if flops > 1e5 and name != "render" else None
            if name == "render":  # gathers, not products: no FLOP floor
                note = f"no matmul floor: {row['rendered_pixels_per_eye_image']:,} px per eye image, 8 lookups each | "
            else:
                note = f"{floor:.3f} | {ms / floor:.1f}x" if floor else " | "
            print(f"{lead} {name} | {ms:.3f} | {flops / 1e6:.2f} | {note} |")
        total = sum(row["ms_per_env_iteration"].values())
        all_flops = sum(row["flops_per_env_iteration"].values())
        floor = 1e3 * all_flops / row["matmul_flops_per_s"]
        print(f"{lead} **all** ({row['env_iterations_per_s']:,.0f} env-it/s) | "
              f"{total:.3f} | {all_flops / 1e6:.2f} | {floor:.3f} | {total / floor:.1f}x |")
    if len(args.batches) > 1:
        by_b = {}
        for row in rows:
            by_b.setdefault(row["B"], []).append(row["peak_rss_rise_mb"])
        (b0, m0), (b1, m1) = [(b, min(m)) for b, m in sorted(by_b.items())][:2]
        per_env = (m1 - m0) / (b1 - b0)
        print(f"\npeak memory rise: " + ", ".join(f"B={b}: {min(m):.0f} MB" for b, m in sorted(by_b.items()))
              + f"; {per_env:.2f} MB per environment (slope), the rest is the textures, mipmaps and learner")
    if args.from_json is not None:
        return
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"benchmark": "stages", "machine": machine_info(), "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
