"""Tests for aectorch.coding.omp, aectorch.coding.matching_pursuit and aectorch.coding.SparseCode.

Oracles: scikit-learn's ``orthogonal_mp_gram`` for OMP, a plain per-signal numpy loop written from
the definition for matching pursuit, closed-form selections on dictionaries whose correlations are
exact (so that ties are exact), and closed-form gradients for ``SparseCode.reconstruct``.
"""

from __future__ import annotations

import doctest
import warnings

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.datasets import load_sample_image
from sklearn.linear_model import orthogonal_mp_gram

from aectorch.coding import SparseCode, gram_matrix, matching_pursuit, omp, use_backend
from aectorch.coding import batch_omp as batch_omp_module
from aectorch.coding import sparse_code as sparse_code_module
from aectorch.coding.patches import COARSE, FINE, extract_patches

torch.set_num_threads(1)

P, N, K = 200, 288, 10
NUM_SIGNALS = 500
ALGORITHMS = [omp, matching_pursuit]


@pytest.fixture(autouse=True, params=["auto", "torch"])
def backend(request):
    """Every test runs on both CPU implementations: the fused C++ kernel ("auto" picks it on
    CPU; test_native_kernel_is_built makes sure it is there) and the pure-torch code (the CUDA
    path and the fallback)."""
    with use_backend(request.param):
        yield request.param


# ---------------------------------------------------------------------------------------------
# Data


def _unit_dictionary(p: int, n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).standard_normal((p, n))
    return d / np.linalg.norm(d, axis=0)


def _sparse_codes(m: int, n: int, max_nonzero: int, seed: int) -> np.ndarray:
    """Dense codes [m, n] with 1..max_nonzero nonzeros (cycling), magnitudes in [0.5, 2]."""
    rng = np.random.default_rng(seed)
    s = np.zeros((m, n))
    for i in range(m):
        nnz = i % max_nonzero + 1
        idx = rng.choice(n, nnz, replace=False)
        s[i, idx] = rng.uniform(0.5, 2.0, nnz) * rng.choice([-1.0, 1.0], nnz)
    return s


@pytest.fixture(scope="module")
def random_problem():
    d = _unit_dictionary(P, N, seed=0)
    codes = _sparse_codes(NUM_SIGNALS, N, K, seed=1)
    return {
        "dictionary": d,
        "sparse_codes": codes,
        "sparse": codes @ d.T,
        "gauss": np.random.default_rng(2).standard_normal((NUM_SIGNALS, P)),
    }


def _grey(name: str) -> np.ndarray:
    return load_sample_image(name).astype(np.float64).mean(-1) / 255.0


def _photo_patches(image: np.ndarray, crops: int, rng: np.random.Generator) -> np.ndarray:
    """Binocular patches [crops * (49 + 64), 200]: random 240x320 crops paired with a copy
    shifted by a few pixels, at both foveal scales."""
    firsts, seconds = [], []
    for _ in range(crops):
        dy, dx = rng.integers(0, 4, size=2) + 1
        r = rng.integers(0, image.shape[0] - 240 - dy + 1)
        c = rng.integers(0, image.shape[1] - 320 - dx + 1)
        firsts.append(image[r : r + 240, c : c + 320])
        seconds.append(image[r + dy : r + dy + 240, c + dx : c + dx + 320])
    first, second = torch.tensor(np.stack(firsts)), torch.tensor(np.stack(seconds))
    out = [extract_patches(first, second, scale).reshape(-1, 200) for scale in (COARSE, FINE)]
    return torch.cat(out).numpy()


@pytest.fixture(scope="module")
def photos():
    """For each photo: its patches as signals, and a dictionary of 288 unit-normalised textured
    patches of the *other* photo (coherent, realistic atoms)."""
    rng = np.random.default_rng(3)
    images = {"china": _grey("china.jpg"), "flower": _grey("flower.jpg")}
    signals = {name: _photo_patches(img, 3, rng) for name, img in images.items()}
    out = {}
    for name, other in (("china", "flower"), ("flower", "china")):
        pool = _photo_patches(images[other], 8, rng)
        pool = pool[np.linalg.norm(pool, axis=1) > 1.2]  # both halves textured (norm^2 = 2)
        atoms = pool[rng.choice(len(pool), N, replace=False)].T
        out[name] = (signals[name], atoms / np.linalg.norm(atoms, axis=0))
    return out


def _tie_dictionary(dtype) -> np.ndarray:
    """[200, 288]: the identity, then duplicates of its first 88 columns. All products with it
    are exact, so correlations tie exactly (atom j and atom 200 + j, and equal |x| entries)."""
    eye = np.eye(P)
    return np.concatenate([eye, eye[:, : N - P]], axis=1).astype(dtype)


def _tie_signals(m: int, seed: int, dtype) -> np.ndarray:
    """Entries drawn from a handful of magnitudes and their float neighbours (1 ulp apart),
    with random signs: many exact ties in |x| and many 1-ulp near-ties."""
    rng = np.random.default_rng(seed)
    base = np.array([0.5, 0.75, 1.0, 1.5, 3.0], dtype=dtype)
    values = np.concatenate(
        [base, np.nextafter(base, dtype(np.inf)), np.nextafter(base, dtype(0))]
    )
    x = rng.choice(values, size=(m, P)) * rng.choice(np.array([-1, 1], dtype=dtype), size=(m, P))
    return x.astype(dtype)


def _stable_selection(x: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k largest |x| per row, larger first, the smaller index first on ties."""
    return np.stack([np.argsort(-np.abs(row), kind="stable")[:k] for row in x])


# ---------------------------------------------------------------------------------------------
# Oracles


def _sklearn_dense(d: np.ndarray, x: np.ndarray, k: int) -> np.ndarray:
    """scikit-learn's OMP on signals as rows [M, P]; dense coefficients [M, N]."""
    with warnings.catch_warnings():
        # "Orthogonal matching pursuit ended prematurely": expected for early stops
        warnings.simplefilter("ignore", RuntimeWarning)
        coef = orthogonal_mp_gram(d.T @ d, d.T @ x.T, n_nonzero_coefs=k)
    assert coef.dtype == d.dtype
    return coef.reshape(d.shape[1], x.shape[0]).T


def _sklearn_order(d: np.ndarray, x: np.ndarray, k: int) -> list[int]:
    """The order in which scikit-learn's OMP picks atoms for one signal (from its path)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        path = orthogonal_mp_gram(d.T @ d, d.T @ x, n_nonzero_coefs=k, return_path=True)
    path = path.reshape(d.shape[1], -1)
    order: list[int] = []
    for step in range(path.shape[1]):
        new = set(np.flatnonzero(path[:, step]).tolist()) - set(order)
        assert len(new) == 1
        order.extend(new)
    return order


def _mp_reference(d: np.ndarray, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Matching pursuit from its definition, one signal at a time, in float64."""
    d = d.astype(np.float64)
    indices = np.zeros((len(x), k), dtype=np.int64)
    coefs = np.zeros((len(x), k))
    for m, signal in enumerate(x.astype(np.float64)):
        r = signal.copy()
        for step in range(k):
            c = d.T @ r
            j = int(np.argmax(np.abs(c)))  # first index on ties
            r -= c[j] * d[:, j]
            indices[m, step], coefs[m, step] = j, c[j]
    return indices, coefs


def _run(fn, d: np.ndarray, x: np.ndarray, k: int, **kwargs) -> SparseCode:
    return fn(torch.from_numpy(x), torch.from_numpy(d), k, **kwargs)


def _dense(code: SparseCode, n: int = N) -> np.ndarray:
    return code.to_dense(n).numpy()


def _used_slots(code: SparseCode) -> np.ndarray:
    """Per signal, the number of leading slots with a nonzero coefficient."""
    nonzero = code.coefficients.numpy() != 0
    return np.where(nonzero.all(1), nonzero.shape[1], np.argmin(nonzero, axis=1))


def _check_float32_disagreements(d32, x32, code, ref, k, min_fraction):
    """Supports agree for >= min_fraction of signals, coefficients agree where supports do, and
    every disagreement is a genuine near-tie: at the first step where our choice and
    scikit-learn's differ, the float64 |correlations| of the two competing atoms with the
    (float64) residual of the common prefix are within 1e-4 relative."""
    dense = _dense(code, d32.shape[1])
    same = ((dense != 0) == (ref != 0)).all(1)
    print(f"float32 support disagreements: {int((~same).sum())} of {len(same)}")
    assert same.mean() >= min_fraction
    np.testing.assert_allclose(dense[same], ref[same], rtol=0, atol=1e-4)
    d64 = d32.astype(np.float64)
    used = _used_slots(code)
    for m in np.flatnonzero(~same):
        ours = code.indices[m, : used[m]].tolist()
        theirs = _sklearn_order(d32, x32[m], k)
        s = 0  # first step where the two selections differ (or one has stopped)
        while s < len(ours) and s < len(theirs) and ours[s] == theirs[s]:
            s += 1
        prefix = ours[:s]
        x = x32[m].astype(np.float64)
        if prefix:
            sub = d64[:, prefix]
            x = x - sub @ np.linalg.lstsq(sub, x, rcond=None)[0]
        c = np.abs(d64.T @ x)
        assert s < len(ours) and s < len(theirs), (
            f"signal {m}: one coder stopped at step {s} and the other did not "
            f"(ours {ours}, sklearn {theirs}, float64 max|c|^2 = {c.max() ** 2:.3g})"
        )
        a, b = c[ours[s]], c[theirs[s]]
        assert abs(a - b) <= 1e-4 * max(a, b), (
            f"signal {m}, step {s}: ours picked {ours[s]} (|c| = {a}), sklearn {theirs[s]} "
            f"(|c| = {b}): not a near-tie"
        )


# ---------------------------------------------------------------------------------------------
# OMP against scikit-learn


def test_omp_float64_exactly_sparse_matches_sklearn(random_problem):
    d, x = random_problem["dictionary"], random_problem["sparse"]
    codes = random_problem["sparse_codes"]
    ref = _sklearn_dense(d, x, K)
    code = _run(omp, d, x, K)
    dense = _dense(code)
    nnz = (codes != 0).sum(1)
    # the true support is recovered, by scikit-learn and by us, and scikit-learn stops early
    np.testing.assert_array_equal(ref != 0, codes != 0)
    np.testing.assert_array_equal(dense != 0, codes != 0)
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(dense, codes, rtol=0, atol=1e-10)
    # slots after an early stop: coefficient exactly 0 (and index 0, as documented)
    slot = np.arange(K)[None, :]
    unused = slot >= nnz[:, None]
    assert unused.any()
    assert (code.coefficients.numpy()[unused] == 0).all()
    assert (code.indices.numpy()[unused] == 0).all()
    assert (code.coefficients.numpy()[~unused] != 0).all()


def test_omp_float64_gaussian_matches_sklearn(random_problem):
    d, x = random_problem["dictionary"], random_problem["gauss"]
    ref = _sklearn_dense(d, x, K)
    dense = _dense(_run(omp, d, x, K))
    assert ((ref != 0).sum(1) == K).all()
    np.testing.assert_array_equal(dense != 0, ref != 0)
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("kind", ["sparse", "gauss"])
def test_omp_float32_matches_sklearn(random_problem, kind):
    d = random_problem["dictionary"].astype(np.float32)
    x = random_problem[kind].astype(np.float32)
    ref = _sklearn_dense(d, x, K)
    code = _run(omp, d, x, K)
    assert code.coefficients.dtype == torch.float32
    _check_float32_disagreements(d, x, code, ref, K, min_fraction=0.995)
    if kind == "sparse":
        nnz = (random_problem["sparse_codes"] != 0).sum(1)
        unused = np.arange(K)[None, :] >= nnz[:, None]
        assert (code.coefficients.numpy()[unused] == 0).all()


@pytest.mark.parametrize("photo", ["china", "flower"])
def test_omp_photo_patches_match_sklearn(photos, photo):
    x, d = photos[photo]
    assert x.shape == (3 * (49 + 64), P) and d.shape == (P, N)
    ref = _sklearn_dense(d, x, K)
    dense = _dense(_run(omp, d, x, K))
    np.testing.assert_array_equal(dense != 0, ref != 0)
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-10)

    d32, x32 = d.astype(np.float32), x.astype(np.float32)
    ref32 = _sklearn_dense(d32, x32, K)
    _check_float32_disagreements(d32, x32, _run(omp, d32, x32, K), ref32, K, min_fraction=0.99)


def test_omp_photo_dictionary_is_coherent(photos):
    # guards the realism of the photo test: atoms of natural patches are far from orthogonal
    _, d = photos["china"]
    g = np.abs(d.T @ d - np.eye(N))
    assert g.max() > 0.9 and np.median(g) > 0.05


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_omp_first_step_exact_ties_match_sklearn(dtype):
    # Exact ties between duplicated atoms and between equal |x| entries: scikit-learn's first
    # pick is np.argmax, i.e. the smallest index. (Later sklearn picks are taken over a
    # permuted index order, so only the first step is compared with it.)
    d, x = _tie_dictionary(dtype), _tie_signals(300, seed=4, dtype=dtype)
    ref = _sklearn_dense(d, x, 1)
    dense = _dense(_run(omp, d, x, 1))
    np.testing.assert_array_equal(dense, ref)
    np.testing.assert_array_equal(np.argmax(dense != 0, axis=1), _stable_selection(x, 1)[:, 0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("fn", ALGORITHMS)
def test_exact_ties_and_ulp_near_ties_select_like_argmax(fn, dtype):
    # On the tie dictionary both coders reduce to: take the largest |x| left, the smallest
    # index on ties; every update is exact, so the whole sequence is exactly known.
    d, x = _tie_dictionary(dtype), _tie_signals(300, seed=5, dtype=dtype)
    code = _run(fn, d, x, K)
    expected = _stable_selection(x, K)
    np.testing.assert_array_equal(code.indices.numpy(), expected)
    np.testing.assert_array_equal(code.coefficients.numpy(), np.take_along_axis(x, expected, 1))


def test_omp_leading_batch_dimensions(photos):
    x, d = photos["china"]
    x = torch.from_numpy(x[: 2 * 3 * 49].copy()).reshape(2, 3, 49, P)
    dt = torch.from_numpy(d)
    for fn in ALGORITHMS:
        code = fn(x, dt, K)
        flat = fn(x.reshape(-1, P), dt, K)
        assert code.indices.shape == (2, 3, 49, K) and code.coefficients.shape == (2, 3, 49, K)
        assert torch.equal(code.indices.reshape(-1, K), flat.indices)
        assert torch.equal(code.coefficients.reshape(-1, K), flat.coefficients)
        single = fn(x[1, 2, 7], dt, K)  # a single signal [P] gives [K]
        assert single.indices.shape == (K,)
        assert torch.equal(single.indices, code.indices[1, 2, 7])
        torch.testing.assert_close(
            single.coefficients, code.coefficients[1, 2, 7], rtol=0, atol=1e-12
        )


@pytest.mark.parametrize("fn", ALGORITHMS)
def test_gram_argument_gives_same_result(random_problem, fn):
    d = torch.from_numpy(random_problem["dictionary"]).float()
    x = torch.from_numpy(random_problem["gauss"][:100]).float()
    plain = fn(x, d, K)
    given_gram = fn(x, d, K, gram=d.t() @ d)
    assert torch.equal(plain.indices, given_gram.indices)
    # The fused kernels' float32 products run in oneDNN (coder_cpu.cpp): torch's product (MKL)
    # up to rounding, which OMP's solves carry into the coefficients (a few ulps).
    torch.testing.assert_close(plain.coefficients, given_gram.coefficients, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(gram_matrix(d), d.t() @ d, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("fn", ALGORITHMS)
def test_block_size_does_not_change_the_result(random_problem, fn, dtype):
    d = torch.from_numpy(random_problem["dictionary"]).to(dtype)
    x = np.concatenate([random_problem["gauss"], random_problem["sparse"]])
    x = torch.from_numpy(x).to(dtype)
    x = x[:530]  # several blocks of 7 and 64, one full and one partial block of 512
    if fn is matching_pursuit:
        # An exact atom (1-sparse) leaves MP a residual of pure rounding noise after one step,
        # whose argmax depends on the BLAS's summation order for that block size (seen on an
        # AVX2 machine). OMP zeroes the chosen correlations and stops instead.
        ones = np.flatnonzero((random_problem["sparse_codes"] != 0).sum(1) == 1) + NUM_SIGNALS
        x = x[np.setdiff1d(np.arange(530), ones)]
    results = [fn(x, d, K, block_size=b) for b in (None, 7, 64, 512)]
    # BLAS may round a 7-row product differently from a 530-row one (a few ulps), so the
    # coefficients are compared to a tolerance; the selections must be identical.
    tol = 1e-5 if dtype == torch.float32 else 1e-13
    for other in results[1:]:
        assert torch.equal(results[0].indices, other.indices)
        torch.testing.assert_close(results[0].coefficients, other.coefficients, rtol=0, atol=tol)


# ---------------------------------------------------------------------------------------------
# Matching pursuit against a plain per-signal reference


def test_mp_float64_matches_reference(random_problem, photos):
    cases = [
        (random_problem["dictionary"], random_problem["gauss"]),
        photos["china"][::-1],
    ]
    # (No exactly-sparse signals: once their residual is zero, MP's later picks are decided by
    # rounding noise, which differs between the Gram-form update and the reference.)
    for d, x in cases:
        ref_idx, ref_coef = _mp_reference(d, x, K)
        code = _run(matching_pursuit, d, np.ascontiguousarray(x), K)
        np.testing.assert_array_equal(code.indices.numpy(), ref_idx)
        np.testing.assert_allclose(code.coefficients.numpy(), ref_coef, rtol=0, atol=1e-10)


def test_mp_float32_matches_reference(random_problem, photos):
    x_photo, d_photo = photos["flower"]
    cases = [(random_problem["dictionary"], random_problem["gauss"]), (d_photo, x_photo)]
    for d, x in cases:
        d32, x32 = d.astype(np.float32), x.astype(np.float32)
        ref_idx, ref_coef = _mp_reference(d32, x32, K)  # float64 on the float32 data
        code = _run(matching_pursuit, d32, x32, K)
        assert code.coefficients.dtype == torch.float32
        same = (code.indices.numpy() == ref_idx).all(1)
        print(f"float32 MP sequence disagreements: {int((~same).sum())} of {len(same)}")
        assert same.mean() >= 0.995
        coef = code.coefficients.numpy()
        np.testing.assert_allclose(coef[same], ref_coef[same], rtol=0, atol=1e-4)


def test_mp_repeats_an_atom_and_to_dense_sums_repeats():
    # Two nearly parallel atoms a = e0 and b (at 0.3 rad from a, in the e0-e1 plane), the other
    # atoms in the orthogonal complement, and x in the plane but along neither atom: the
    # residual keeps swinging between a and b, so MP picks a, b, a, b, ...
    d = np.zeros((8, 12))
    d[2:] = _unit_dictionary(6, 12, seed=7)
    d[:, 3] = 0
    d[:, 9] = 0
    d[0, 3] = 1.0
    d[:2, 9] = np.cos(0.3), np.sin(0.3)
    x = (0.6 * d[:, 3] + 0.4 * d[:, 9])[None]
    code = _run(matching_pursuit, d, x, 6)
    ref_idx, ref_coef = _mp_reference(d, x, 6)
    np.testing.assert_array_equal(code.indices.numpy(), ref_idx)
    np.testing.assert_allclose(code.coefficients.numpy(), ref_coef, rtol=0, atol=1e-12)
    idx = code.indices[0].tolist()
    assert idx == [3, 9, 3, 9, 3, 9]
    manual = np.zeros((1, 12))
    np.add.at(manual[0], code.indices[0].numpy(), code.coefficients[0].numpy())
    np.testing.assert_allclose(_dense(code, 12), manual, rtol=0, atol=1e-15)
    assert abs(manual[0, 3] - code.coefficients[0, 0].item()) > 1e-6  # repeats really summed
    np.testing.assert_allclose(
        code.reconstruct(torch.from_numpy(d)).numpy(), manual @ d.T, rtol=0, atol=1e-14
    )


def test_mp_to_dense_equals_manual_accumulation_on_random_data(random_problem):
    d, x = random_problem["dictionary"], random_problem["gauss"][:200]
    code = _run(matching_pursuit, d, x, 40)  # long enough for repeats on Gaussian data
    idx, coef = code.indices.numpy(), code.coefficients.numpy()
    assert any(len(set(row)) < len(row) for row in idx)
    manual = np.zeros((len(x), N))
    for m in range(len(x)):
        np.add.at(manual[m], idx[m], coef[m])
    np.testing.assert_allclose(_dense(code), manual, rtol=0, atol=1e-13)


# ---------------------------------------------------------------------------------------------
# SparseCode


def _small_code(dtype=torch.float64, requires_grad=False) -> tuple[SparseCode, torch.Tensor]:
    g = torch.Generator().manual_seed(8)
    # [2, 2, 4], with repeated atoms
    indices = torch.tensor([[[0, 4, 4, 6], [2, 2, 2, 2]], [[6, 5, 1, 0], [3, 0, 3, 1]]])
    coefficients = torch.randn(2, 2, 4, generator=g, dtype=dtype).requires_grad_(requires_grad)
    dictionary = torch.randn(5, 7, generator=g, dtype=dtype).requires_grad_(requires_grad)
    return SparseCode(indices, coefficients), dictionary


def _manual_dense(code: SparseCode, n: int) -> torch.Tensor:
    idx = code.indices.reshape(-1, code.sparsity)
    coef = code.coefficients.detach().reshape(-1, code.sparsity)
    out = torch.zeros(idx.shape[0], n, dtype=coef.dtype)
    for m in range(idx.shape[0]):
        for j in range(idx.shape[1]):
            out[m, idx[m, j]] += coef[m, j]
    return out.reshape(*code.indices.shape[:-1], n)


def test_sparse_code_to_dense_and_reconstruct_match_manual():
    code, d = _small_code()
    assert code.sparsity == 4
    dense = code.to_dense(7)
    assert dense.shape == (2, 2, 7)
    torch.testing.assert_close(dense, _manual_dense(code, 7), rtol=0, atol=1e-15)
    manual_rec = torch.einsum("...n,pn->...p", _manual_dense(code, 7), d)
    torch.testing.assert_close(code.reconstruct(d), manual_rec, rtol=0, atol=1e-13)
    # float32 coefficients are cast to the dictionary dtype
    rec32 = SparseCode(code.indices, code.coefficients.float()).reconstruct(d)
    assert rec32.dtype == torch.float64


def test_sparse_code_reconstruct_gradients_match_analytic():
    code, d = _small_code(requires_grad=True)
    target = torch.randn(2, 2, 5, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
    loss = 0.5 * (code.reconstruct(d) - target).square().sum()
    grad_d, grad_c = torch.autograd.grad(loss, (d, code.coefficients))
    with torch.no_grad():
        dense = _manual_dense(code, 7).reshape(-1, 7)  # A [M, N]
        err = (dense @ d.t() - target.reshape(-1, 5))  # E [M, P]
        expected_d = err.t() @ dense  # dL/dD = E^T A
        expected_c = torch.einsum("mp,pmk->mk", err, d[:, code.indices.reshape(-1, 4)])
    torch.testing.assert_close(grad_d, expected_d, rtol=0, atol=1e-12)
    torch.testing.assert_close(grad_c, expected_c.reshape(2, 2, 4), rtol=0, atol=1e-12)


def test_sparse_code_gradcheck():
    code, d = _small_code(requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda dd, cc: SparseCode(code.indices, cc).reconstruct(dd), (d, code.coefficients)
    )
    assert torch.autograd.gradcheck(
        lambda cc: SparseCode(code.indices, cc).to_dense(7), (code.coefficients,)
    )


def test_codes_are_constants_for_autograd(random_problem):
    d = torch.from_numpy(random_problem["dictionary"]).requires_grad_(True)
    x = torch.from_numpy(random_problem["gauss"][:20]).requires_grad_(True)
    for fn in ALGORITHMS:
        code = fn(x, d, K)
        assert not code.coefficients.requires_grad
        rec = code.reconstruct(d)
        (grad,) = torch.autograd.grad(rec.sum(), d)
        expected = torch.ones(20, P, dtype=torch.float64).t() @ code.to_dense(N)
        torch.testing.assert_close(grad, expected, rtol=0, atol=1e-12)


def test_sparse_code_helpers():
    code, _ = _small_code()
    moved = code.to(torch.float32)
    assert moved.coefficients.dtype == torch.float32 and moved.indices.dtype == torch.int64
    assert not _small_code(requires_grad=True)[0].detach().coefficients.requires_grad
    leaves, spec = torch.utils._pytree.tree_flatten(code)
    assert len(leaves) == 2 and torch.utils._pytree.tree_unflatten(leaves, spec) == code
    with pytest.raises(ValueError, match="num_atoms"):
        code.to_dense(0)
    with pytest.raises(ValueError, match="dictionary"):
        code.reconstruct(torch.zeros(5, 7, 1, dtype=torch.float64))


# ---------------------------------------------------------------------------------------------
# Edge cases


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("fn", ALGORITHMS)
def test_zero_signal_gives_zero_code(random_problem, fn, dtype):
    d = torch.from_numpy(random_problem["dictionary"]).to(dtype)
    x = torch.from_numpy(random_problem["gauss"][:6]).to(dtype)
    x[2] = 0
    code = fn(x, d, K)
    assert torch.isfinite(code.coefficients).all()
    assert (code.coefficients[2] == 0).all()
    assert (code.reconstruct(d)[2] == 0).all()
    rest = fn(x[[0, 1, 3, 4, 5]], d, K)  # the zero row does not disturb the others
    assert torch.equal(code.indices[[0, 1, 3, 4, 5]], rest.indices)
    torch.testing.assert_close(
        code.coefficients[[0, 1, 3, 4, 5]], rest.coefficients, rtol=0, atol=1e-6
    )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_omp_signal_equal_to_an_atom(random_problem, dtype):
    d = torch.from_numpy(random_problem["dictionary"]).to(dtype)
    atoms = [0, 17, 150, N - 1]
    code = omp(d[:, atoms].t().contiguous(), d, K)
    expected = torch.zeros(len(atoms), N, dtype=dtype)
    expected[range(len(atoms)), atoms] = 1
    assert code.indices[:, 0].tolist() == atoms
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(code.to_dense(N), expected, rtol=0, atol=tol)
    assert (code.coefficients[:, 1:] == 0).all()  # early stop: the residual is zero


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_omp_dependent_atom_stops_like_sklearn(dtype):
    # Atom 2 = (-1, 0, t) with t^2 below eps: its norm rounds to exactly 1, and after atom 0 is
    # chosen its new direction has squared norm Lkk = 1 - 1 = 0, yet it holds the largest
    # residual correlation (64 t, with (64 t)^2 >= eps). scikit-learn stops there ("dependent
    # atoms"); all the arithmetic below is exact in both dtypes.
    t = 2.0**-30 if dtype == np.float64 else 2.0**-15
    d = np.array([[1, 0, -1], [0, 1, 0], [0, 0, t]], dtype=dtype)
    x = np.array([[3, 0, 64]], dtype=dtype)
    assert np.linalg.norm(d, axis=0).tolist() == [1, 1, 1]
    ref = _sklearn_dense(d, x, 3)
    np.testing.assert_array_equal(ref, [[3, 0, 0]])
    code = _run(omp, d, x, 3)
    assert torch.isfinite(code.coefficients).all()
    np.testing.assert_array_equal(_dense(code, 3), ref)
    assert code.coefficients[0, 1:].tolist() == [0, 0]


@pytest.mark.parametrize(("p", "n"), [(8, 12), (12, 8), (10, 10)])
def test_omp_full_sparsity_matches_sklearn(p, n):
    k = min(p, n)
    d = _unit_dictionary(p, n, seed=10)
    x = np.random.default_rng(11).standard_normal((50, p))
    ref = _sklearn_dense(d, x, k)
    code = _run(omp, d, x, k)
    dense = _dense(code, n)
    np.testing.assert_array_equal(dense != 0, ref != 0)
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-9)
    if p <= n:  # a complete basis is chosen: the signals are reconstructed exactly
        np.testing.assert_allclose(code.reconstruct(torch.from_numpy(d)).numpy(), x, atol=1e-9)


def test_empty_batch(random_problem):
    d = torch.from_numpy(random_problem["dictionary"])
    for fn in ALGORITHMS:
        code = fn(torch.zeros(0, P, dtype=torch.float64), d, K)
        assert code.indices.shape == (0, K) and code.coefficients.shape == (0, K)


# ---------------------------------------------------------------------------------------------
# Validation


def _valid(dtype=torch.float32):
    d = torch.randn(20, 30, generator=torch.Generator().manual_seed(12))
    d = torch.nn.functional.normalize(d, dim=0)
    return torch.randn(4, 20, generator=torch.Generator().manual_seed(13)).to(dtype), d.to(dtype)


@pytest.mark.parametrize("fn", ALGORITHMS)
def test_validation_errors_name_the_argument(fn):
    x, d = _valid()
    with pytest.raises(ValueError, match=r"dictionary must have shape \[P, N\].*\(20, 30, 1\)"):
        fn(x, d[..., None], 3)
    with pytest.raises(ValueError, match=r"signals must have shape \[\.\.\., P\].*\(4, 21\)"):
        fn(torch.randn(4, 21), d, 3)
    for bad in (0, -1, 21, 31):
        with pytest.raises(ValueError, match=rf"sparsity must be in \[1, min\(P, N\)\].*got {bad}"):
            fn(x, d, bad)
    with pytest.raises(ValueError, match="sparsity"):  # > N, with N < P
        fn(x, d[:, :10].contiguous(), 11)
    for bad in (3.0, True, "3", None):
        with pytest.raises(TypeError, match="sparsity must be an int"):
            fn(x, d, bad)
    with pytest.raises(TypeError, match="signals must be a floating-point tensor.*int64"):
        fn(torch.ones(4, 20, dtype=torch.int64), d, 3)
    with pytest.raises(TypeError, match="signals must be a torch.Tensor"):
        fn(x.numpy(), d, 3)
    with pytest.raises(
        TypeError, match="dictionary dtype torch.float64 does not match signals dtype torch.float32"
    ):
        fn(x, d.double(), 3)
    for bad_value in (float("nan"), float("inf"), -float("inf")):
        bad = x.clone()
        bad[1, 3] = bad_value
        with pytest.raises(ValueError, match="signals contain non-finite"):
            fn(bad, d, 3)
    with pytest.raises(ValueError, match="dictionary columns must have unit norm"):
        fn(x, 1.1 * d, 3)
    bad_d = d.clone()
    bad_d[0, 0] = float("nan")
    with pytest.raises(ValueError, match="dictionary contains non-finite"):
        fn(x, bad_d, 3)
    with pytest.raises(ValueError, match=r"gram must have shape \[N, N\] = \[30, 30\].*\(20, 20\)"):
        fn(x, d, 3, gram=torch.eye(20))


@pytest.mark.parametrize("fn", ALGORITHMS)
def test_check_false_skips_value_checks(fn):
    x, d = _valid()
    x[1, 3] = float("nan")
    code = fn(x, 1.1 * d, 3, check=False)  # neither the NaN nor the norm raises
    assert code.indices.shape == (4, 3)
    assert torch.isfinite(code.coefficients[[0, 2, 3]]).all()
    with pytest.raises(ValueError, match="sparsity"):  # shapes are still checked
        fn(x, d, 0, check=False)


def test_doctests():
    for module in (batch_omp_module, sparse_code_module):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.attempted >= 3 and result.failed == 0, module.__name__


# ---------------------------------------------------------------------------------------------
# torch.compile


def _compile_cases(fn):
    d = torch.from_numpy(_unit_dictionary(P, N, seed=14)).float()
    x = torch.randn(64, P, generator=torch.Generator().manual_seed(15))
    x[5] = 0  # early stops under compile as well
    if fn is omp:
        # (not for MP: after the first step its residual is rounding noise, whose later picks
        # legitimately differ between fused and unfused arithmetic)
        x[6] = d[:, 40]
    tie_d = torch.from_numpy(_tie_dictionary(np.float32))
    tie_x = torch.from_numpy(_tie_signals(64, seed=16, dtype=np.float32))
    return [(x, d), (tie_x, tie_d)]


def _check_compiled(fn, backend):
    compiled = torch.compile(fn, fullgraph=True, backend=backend)  # fullgraph: no graph breaks
    for x, d in _compile_cases(fn):  # same shapes and dtype: one compilation
        eager, got = fn(x, d, K), compiled(x, d, K)
        assert torch.equal(got.indices, eager.indices)
        torch.testing.assert_close(got.coefficients, eager.coefficients, rtol=0, atol=1e-5)


@pytest.mark.parametrize("fn", ALGORITHMS)
def test_torch_compile_fullgraph_aot_eager_matches_eager(fn):
    _check_compiled(fn, "aot_eager")


@pytest.mark.slow
@pytest.mark.parametrize("fn", ALGORITHMS)
def test_torch_compile_fullgraph_inductor_matches_eager(fn):
    _check_compiled(fn, "inductor")


# ---------------------------------------------------------------------------------------------
# CUDA


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("fn", ALGORITHMS)
def test_cuda_matches_cpu(random_problem, photos, fn):
    cases = [
        (random_problem["dictionary"], random_problem["gauss"]),
        (random_problem["dictionary"], random_problem["sparse"]),
        photos["china"][::-1],
    ]
    for d, x in cases:
        dt, xt = torch.from_numpy(d), torch.from_numpy(np.ascontiguousarray(x))
        cpu = fn(xt, dt, K)
        gpu = fn(xt.cuda(), dt.cuda(), K)
        assert gpu.indices.is_cuda and gpu.coefficients.is_cuda
        gpu_dense, cpu_dense = gpu.to_dense(N).cpu(), cpu.to_dense(N)
        torch.testing.assert_close(gpu_dense, cpu_dense, rtol=0, atol=1e-10)
        # The same support above that tolerance: where plain MP picks an atom again for what is left
        # of its own coefficient, the sum can be exactly 0 on one device and ~1e-17 on the other.
        assert torch.equal(gpu_dense.abs() > 1e-10, cpu_dense.abs() > 1e-10)
    tie_d, tie_x = _tie_dictionary(np.float32), _tie_signals(100, seed=17, dtype=np.float32)
    gpu = fn(torch.from_numpy(tie_x).cuda(), torch.from_numpy(tie_d).cuda(), K)
    np.testing.assert_array_equal(gpu.indices.cpu().numpy(), _stable_selection(tie_x, K))


# ---------------------------------------------------------------------------------------------
# Properties


@st.composite
def _problems(draw):
    p = draw(st.integers(4, 30))
    n = draw(st.integers(p, 60))
    k = draw(st.integers(1, min(p, n)))
    m = draw(st.integers(1, 40))
    seed = draw(st.integers(0, 2**31 - 1))
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(p, n, generator=g, dtype=torch.float64), dim=0)
    x = torch.randn(m, p, generator=g, dtype=torch.float64)
    perm = torch.randperm(m, generator=g)
    return x, d, k, perm


PROPERTY_SETTINGS = settings(max_examples=25, deadline=None)


@pytest.mark.parametrize("fn", ALGORITHMS)
@PROPERTY_SETTINGS
@given(problem=_problems())
def test_property_shapes_and_batch_permutation(fn, problem):
    x, d, k, perm = problem
    code = fn(x, d, k)
    assert code.indices.shape == (x.shape[0], k) and code.coefficients.shape == (x.shape[0], k)
    assert code.indices.dtype == torch.int64 and code.coefficients.dtype == torch.float64
    assert ((code.indices >= 0) & (code.indices < d.shape[1])).all()
    assert code.reconstruct(d).shape == x.shape
    permuted = fn(x[perm], d, k)
    assert torch.equal(permuted.indices, code.indices[perm])
    # rows may round differently at another position in a BLAS block; with k close to P the
    # least-squares refit amplifies that, hence not bitwise equality
    torch.testing.assert_close(permuted.coefficients, code.coefficients[perm], rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("fn", ALGORITHMS)
@PROPERTY_SETTINGS
@given(problem=_problems(), s=st.floats(0.1, 10.0))
def test_property_positive_scaling(fn, problem, s):
    x, d, k, _ = problem
    code, scaled = fn(x, d, k), fn(s * x, d, k)
    assert torch.equal(scaled.indices, code.indices)
    assert torch.equal(scaled.coefficients != 0, code.coefficients != 0)
    tol = 1e-9 * s * x.norm(dim=1, keepdim=True)
    assert ((scaled.coefficients - s * code.coefficients).abs() <= tol).all()


@PROPERTY_SETTINGS
@given(problem=_problems())
def test_property_omp_residual_orthogonal_to_chosen_atoms(problem):
    x, d, k, _ = problem
    code = omp(x, d, k)
    residual = x - code.reconstruct(d)
    used = code.coefficients != 0
    correlations = (residual @ d).gather(1, code.indices)  # D_I^T r, per slot
    assert (correlations[used].abs() < 1e-8).all()
    # and no atom is chosen twice
    for row, mask in zip(code.indices.tolist(), used.tolist()):
        chosen = [j for j, u in zip(row, mask) if u]
        assert len(chosen) == len(set(chosen))
