"""Patches per second of aectorch's batched OMP / MP versus scikit-learn's OMP.

Signals are real binocular patches: foveal patches (coarse and fine scale) cut
from the two photographs scikit-learn ships, paired with a copy shifted by a few
pixels, as the sensory coding model sees them. P = 200, N = 288, k = 10, float32.
The dictionary is random and unit-norm, as at the start of training.

Compared, each in the same process, median of --repeats runs:
  * aectorch ``omp`` and ``matching_pursuit`` with their default backend (the fused C++ kernel,
    ``aectorch.ops.native``), eager and ``torch.compile``-d (the operator inside the graph);
  * the same with ``backend="torch"`` (``*_torch``: the pure-torch code, the CUDA path and the
    fallback), eager and compiled;
  * scikit-learn ``orthogonal_mp_gram`` with the Gram matrix precomputed
    (what a user would otherwise call), ``Xy = D^T X`` included in its time.
The fraction of patches whose support set equals scikit-learn's is reported
(for MP this compares a different algorithm and is for information only).

A FLOP floor is derived from the machine's sustained float32 matmul rate,
measured in the same run on the same thread count.

Usage:
    python benchmarks/omp.py                    # full sweep (about 10 minutes)
    python benchmarks/omp.py --quick            # M = 113, 1808, 14464; 1 thread
    python benchmarks/omp.py --sizes 14464 --threads 1 --repeats 5

Writes a table to stdout and JSON to benchmarks/results/omp.json (--json).
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.machine import cpu_model, machine_info  # noqa: E402

from aectorch.coding import COARSE, FINE, extract_patches, gram_matrix, matching_pursuit, omp  # noqa: E402

P, N, K = 200, 288, 10


def photo_patches(count: int, seed: int = 0) -> torch.Tensor:
    """`count` binocular patches [count, 200] from scikit-learn's sample photographs."""
    from sklearn.datasets import load_sample_image

    gen = torch.Generator().manual_seed(seed)
    photos = [
        torch.from_numpy(load_sample_image(name).astype(np.float32) / 255.0).mean(-1)
        for name in ("china.jpg", "flower.jpg")
    ]
    out, have = [], 0
    while have < count:
        photo = photos[int(torch.randint(0, len(photos), (1,), generator=gen))]
        h, w = photo.shape
        top = int(torch.randint(0, h - 240 + 1, (1,), generator=gen))
        left = int(torch.randint(8, w - 320 - 8 + 1, (1,), generator=gen))
        shift = int(torch.randint(-6, 7, (1,), generator=gen))
        first = photo[top : top + 240, left : left + 320][None]
        second = photo[top : top + 240, left + shift : left + shift + 320][None]
        for scale in (COARSE, FINE):
            x = extract_patches(first, second, scale)[0]
            x = x[x.norm(dim=1) > 0]  # flat patches carry no information
            out.append(x)
            have += x.shape[0]
    return torch.cat(out)[:count].contiguous()


def median_time(fn, repeats: int, warmup: int = 1) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def matmul_gflops(repeats: int) -> float:
    """Sustained float32 GEMM rate (GFLOP/s) on the current thread count."""
    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    t = median_time(lambda: a @ b, repeats=max(3, repeats))
    return 2 * 2048**3 / t / 1e9


def flops_per_patch(algorithm: str) -> int:
    """Floating-point operations per patch of the Gram-form algorithms (P=200, N=288, k=10)."""
    correlations = 2 * P * N  # X D
    if algorithm == "mp":
        return correlations + (K - 1) * 2 * N  # one G-row axpy per step but the last
    # OMP: u_i = G[:, I] Linv_i (i+1 rows) and one axpy per step but the last,
    # plus the k x k triangles (negligible next to N).
    return correlations + sum(2 * N * (i + 1) + 2 * N for i in range(K - 1)) + 2 * K**3


def support_sets(indices: np.ndarray, coefficients: np.ndarray) -> list[frozenset]:
    return [frozenset(i[c != 0].tolist()) for i, c in zip(indices, coefficients)]


def sklearn_omp(dictionary: np.ndarray, gram: np.ndarray, signals: np.ndarray) -> np.ndarray:
    from sklearn.linear_model import orthogonal_mp_gram

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return orthogonal_mp_gram(gram, dictionary.T @ signals.T, n_nonzero_coefs=K).T


def breakdown(repeats: int, block: int) -> list[dict]:
    """Median time of each stage of one pursuit step on a `[block, N]` tile, one thread.

    The evidence for where eager time goes: a step is a handful of passes over the
    tile plus a few dozen small ops, each paying torch's dispatch cost.
    """
    import torch.nn.functional as F

    from aectorch.coding import pursuit

    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(2)
    dictionary = torch.nn.functional.normalize(torch.randn(P, N, generator=gen), dim=0)
    gram = gram_matrix(dictionary)
    x = photo_patches(block)
    ws = pursuit._Workspace.make(block, N, torch.float32, x.device)
    alpha = x @ dictionary
    lam = alpha.abs().argmax(-1)
    c = alpha.gather(1, lam[:, None])
    support = torch.randint(0, N, (block, 5), generator=gen)
    weights = torch.randn(block, 5, generator=gen)
    tiny = torch.randn(16)
    stages = {
        "correlations X D (matmul)": lambda: torch.mm(x, dictionary, out=ws.alpha),
        "exact argmax |alpha| (packed int32 key + check)": lambda: pursuit._argmax_abs_int32_key(
            alpha, ws.key, ws.reversed_index
        ),
        "  for comparison: alpha.abs().argmax(-1)": lambda: alpha.abs().argmax(-1),
        "MP update (index_select + addcmul_)": lambda: ws.rows.copy_(alpha).addcmul_(
            torch.index_select(gram, 0, lam, out=ws.alpha), c, value=-1.0
        ),
        "OMP update (embedding_bag of 5 Gram rows + addcmul_)": lambda: ws.rows.addcmul_(
            F.embedding_bag(support, gram, per_sample_weights=weights, mode="sum"), c, value=-1.0
        ),
        "one trivial op (dispatch cost)": lambda: tiny.mul(1.0),
        "whole MP block (k = 10)": lambda: matching_pursuit(
            x, dictionary, K, gram=gram, check=False, block_size=block, backend="torch"),
        "whole OMP block (k = 10)": lambda: omp(
            x, dictionary, K, gram=gram, check=False, block_size=block, backend="torch"),
        "whole MP block, fused C++ kernel": lambda: matching_pursuit(
            x, dictionary, K, gram=gram, check=False, block_size=block, backend="native"),
        "whole OMP block, fused C++ kernel": lambda: omp(
            x, dictionary, K, gram=gram, check=False, block_size=block, backend="native"),
    }
    rows = []
    with torch.inference_mode():
        for name, fn in stages.items():
            t = median_time(fn, max(repeats, 50), warmup=3)
            rows.append({"stage": name, "block": block, "microseconds": t * 1e6})
            print(f"| {name} | {t * 1e6:,.1f} |", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[113, 1808, 14464, 115712])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sklearn-repeats", type=int, default=3)
    parser.add_argument("--no-compile", action="store_true")
    parser.add_argument("--quick", action="store_true", help="M = 113, 1808, 14464 on 1 thread")
    parser.add_argument("--json", type=Path, default=None, help="default: benchmarks/results/omp.json (omp_breakdown.json with --breakdown)")
    parser.add_argument("--breakdown", action="store_true", help="time the stages of one step on a [block, N] tile instead")
    parser.add_argument("--block", type=int, default=512)
    args = parser.parse_args()
    results = Path(__file__).parent / "results"
    if args.breakdown:
        print(f"\n| stage (one [{args.block}, {N}] tile, 1 thread) | median microseconds |\n|---|---:|")
        rows = breakdown(args.repeats, args.block)
        out = args.json or results / "omp_breakdown.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"meta": {"torch": torch.__version__, "cpu_model": cpu_model()}, "rows": rows}, indent=2))
        print(f"\nwrote {out}")
        return
    args.json = args.json or results / "omp.json"
    if args.quick:
        args.sizes, args.threads = [113, 1808, 14464], [1]

    from threadpoolctl import threadpool_limits

    gen = torch.Generator().manual_seed(1)
    dictionary = torch.nn.functional.normalize(torch.randn(P, N, generator=gen), dim=0)
    gram = gram_matrix(dictionary)
    d_np, g_np = dictionary.numpy().astype(np.float32), gram.numpy().astype(np.float32)
    print(f"making {max(args.sizes)} photo patches ...", flush=True)
    all_signals = photo_patches(max(args.sizes))

    # Each (function, backend, size) is its own graph: 4 sizes x 2 backends pass dynamo's default
    # limit of 8 recompilations per function, which fullgraph=True turns into an error.
    torch._dynamo.config.recompile_limit = 64
    torch_omp = functools.partial(omp, backend="torch")
    torch_mp = functools.partial(matching_pursuit, backend="torch")
    compiled = {}
    if not args.no_compile:
        compiled = {
            "omp": torch.compile(omp, fullgraph=True, dynamic=False),
            "mp": torch.compile(matching_pursuit, fullgraph=True, dynamic=False),
            "omp_torch": torch.compile(torch_omp, fullgraph=True, dynamic=False),
            "mp_torch": torch.compile(torch_mp, fullgraph=True, dynamic=False),
        }
    rows = []
    for threads in args.threads:
        torch.set_num_threads(threads)
        with threadpool_limits(threads):
            gflops = matmul_gflops(args.repeats)
            for m in args.sizes:
                x = all_signals[:m].contiguous()
                x_np = x.numpy()
                t_sk = median_time(lambda: sklearn_omp(d_np, g_np, x_np), args.sklearn_repeats, warmup=0 if m > 20000 else 1)
                ref = sklearn_omp(d_np, g_np, x_np)
                ref_sets = [frozenset(np.flatnonzero(r).tolist()) for r in ref]
                entries = {"sklearn_omp": (t_sk, 1.0)}
                candidates = {
                    "omp": lambda: omp(x, dictionary, K, gram=gram, check=False),
                    "mp": lambda: matching_pursuit(x, dictionary, K, gram=gram, check=False),
                    "omp_torch": lambda: torch_omp(x, dictionary, K, gram=gram, check=False),
                    "mp_torch": lambda: torch_mp(x, dictionary, K, gram=gram, check=False),
                }
                for name, fn in compiled.items():
                    cfn = fn
                    candidates[f"{name}_compiled"] = (
                        lambda cfn=cfn: cfn(x, dictionary, K, gram=gram, check=False)
                    )
                for name, fn in candidates.items():
                    t0 = time.perf_counter()
                    code = fn()  # also compiles
                    first = time.perf_counter() - t0
                    t = median_time(fn, args.repeats, warmup=1)
                    sets = support_sets(code.indices.numpy(), code.coefficients.numpy())
                    match = float(np.mean([a == b for a, b in zip(sets, ref_sets)]))
                    entries[name] = (t, match)
                    if name.endswith("compiled"):
                        entries[name] += (first,)
                for name, entry in entries.items():
                    t, match = entry[:2]
                    algo = "mp" if name.startswith("mp") else "omp"
                    rate = m / t
                    floor = gflops * 1e9 / flops_per_patch(algo)
                    rows.append(
                        {
                            "method": name,
                            "threads": threads,
                            "M": m,
                            "seconds_median": t,
                            "patches_per_s": rate,
                            "speedup_vs_sklearn": (m / t) / (m / t_sk),
                            "support_match_vs_sklearn": match,
                            "flop_floor_patches_per_s": floor,
                            "fraction_of_floor": rate / floor,
                            "first_call_s": entry[2] if len(entry) > 2 else None,
                        }
                    )
                    print(
                        f"threads={threads} M={m:>6} {name:<14} {rate:>11,.0f} patches/s  "
                        f"x{rows[-1]['speedup_vs_sklearn']:6.1f} vs sklearn  support match {match:6.4f}  "
                        f"{rate / floor:5.1%} of floor",
                        flush=True,
                    )
            rows.append({"method": "matmul_gflops", "threads": threads, "gflops": gflops})
    print_table(rows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        **machine_info(),
        "P": P,
        "N": N,
        "k": K,
        "dtype": "float32",
        "flops_per_patch": {"omp": flops_per_patch("omp"), "mp": flops_per_patch("mp")},
    }
    args.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(f"\nwrote {args.json}")


def print_table(rows: list[dict]) -> None:
    print("\n| threads | M | method | patches/s | x sklearn | support = sklearn | % of FLOP floor |")
    print("|---:|---:|---|---:|---:|---:|---:|")
    for r in rows:
        if r["method"] == "matmul_gflops":
            print(f"| {r['threads']} | | float32 matmul | {r['gflops']:.1f} GFLOP/s | | | |")
            continue
        print(
            f"| {r['threads']} | {r['M']} | {r['method']} | {r['patches_per_s']:,.0f} | "
            f"{r['speedup_vs_sklearn']:.1f} | {r['support_match_vs_sklearn']:.4f} | "
            f"{r['fraction_of_floor']:.1%} |"
        )


if __name__ == "__main__":
    main()
