"""Patches per second of aectorch's batched OMP and MP against scikit-learn's ``orthogonal_mp_gram``,
interleaved in one run, on real binocular patches of scikit-learn's photographs (P = 200, N = 288,
k = 10, float32, a random unit-norm dictionary); also the fraction of patches with scikit-learn's
atoms and the FLOP floor (docs/performance.md).
"""

import functools
import statistics

import numpy as np
import pytest
import torch

from aectorch.coding import COARSE, FINE, extract_patches, gram_matrix, matching_pursuit, omp
from benchmarks import harness

P, N, K = 200, 288, 10
METHODS = ["omp", "mp", "omp_torch", "mp_torch"] + harness.size([], ["omp_compiled", "mp_compiled",
                                                                     "omp_torch_compiled", "mp_torch_compiled"])


@functools.cache
def photo_patches(count: int, seed: int = 0) -> torch.Tensor:
    """``count`` binocular patches ``[count, 200]`` from scikit-learn's sample photographs."""
    from sklearn.datasets import load_sample_image

    gen = torch.Generator().manual_seed(seed)
    photos = [torch.from_numpy(load_sample_image(name).astype(np.float32) / 255).mean(-1)
              for name in ("china.jpg", "flower.jpg")]
    out, have = [], 0
    while have < count:
        photo = photos[int(torch.randint(0, 2, (1,), generator=gen))]
        top = int(torch.randint(0, photo.shape[0] - 240 + 1, (1,), generator=gen))
        left = int(torch.randint(8, photo.shape[1] - 328 + 1, (1,), generator=gen))
        shift = int(torch.randint(-6, 7, (1,), generator=gen))
        pair = (photo[top:top + 240, left:left + 320][None], photo[top:top + 240, left + shift:left + shift + 320][None])
        for scale in (COARSE, FINE):
            x = extract_patches(*pair, scale)[0]
            out.append(x[x.norm(dim=1) > 0])  # flat patches carry no information
            have += len(out[-1])
    return torch.cat(out)[:count].contiguous()


def flops_per_patch(method: str) -> int:
    # the correlations, one Gram-row axpy per MP step but the last (OMP: i + 1 rows at step i, and the triangles)
    if method.startswith("mp"):
        return 2 * P * N + (K - 1) * 2 * N
    return 2 * P * N + sum(2 * N * (i + 1) + 2 * N for i in range(K - 1)) + 2 * K**3


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # scikit-learn's on a residual reached early
@pytest.mark.parametrize("threads", harness.size([1], [1, 2]))
@pytest.mark.parametrize("size", harness.size([113], [113, 1808, 14464, 115712]))
@pytest.mark.parametrize("method", METHODS)
def test_coding(benchmark, method, size, threads):
    from sklearn.linear_model import orthogonal_mp_gram
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(threads)
    d = torch.nn.functional.normalize(torch.randn(P, N, generator=torch.Generator().manual_seed(1)), dim=0)
    gram, x = gram_matrix(d), photo_patches(size)
    fn = functools.partial(matching_pursuit if method.startswith("mp") else omp,
                           backend="torch" if "_torch" in method else None)
    if method.endswith("_compiled"):
        torch._dynamo.config.recompile_limit = 64  # a graph per size and backend
        fn = torch.compile(fn, fullgraph=True, dynamic=False)
    ours = lambda: fn(x, d, K, gram=gram, check=False)  # noqa: E731
    theirs = lambda: orthogonal_mp_gram(gram.numpy(), d.numpy().T @ x.numpy().T, n_nonzero_coefs=K).T  # noqa: E731
    with threadpool_limits(threads):
        times = harness.interleaved({"ours": ours, "sklearn": theirs}, rounds=harness.size(1, 5))
        benchmark.pedantic(ours, rounds=harness.size(1, 5))
        a, b = torch.randn(1024, 1024), torch.randn(1024, 1024)
        matmul = 2 * 1024**3 / harness.median_seconds(lambda: a @ b, harness.size(None, 0.5))
    code, reference = ours(), theirs()
    ours_sets = [frozenset(i[c != 0].tolist()) for i, c in zip(code.indices.numpy(), code.coefficients.numpy())]
    match = np.mean([a == frozenset(np.flatnonzero(r).tolist()) for a, r in zip(ours_sets, reference)])
    rate, sklearn_rate = size / statistics.median(times["ours"]), size / statistics.median(times["sklearn"])
    if method.startswith("omp"):
        assert match == 1.0  # every OMP variant picks scikit-learn's atoms
    harness.record("coding", [{
        "variant": f"{method}, M={size}, {threads} thread(s)", "method": method, "M": size, "threads": threads,
        "patches_per_s": rate, "sklearn_patches_per_s": sklearn_rate, "x_sklearn": rate / sklearn_rate,
        "support_match_vs_sklearn": float(match), "flop_floor_patches_per_s": matmul / flops_per_patch(method)}],
        benchmark)
