"""The fused CPU kernels (aectorch.ops.native): built, used, and replaceable.

Its results are tested against scikit-learn and the MP reference with every test of
tests/coding/test_batch_omp.py, which runs on both backends."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from aectorch.coding import matching_pursuit, omp, use_backend
from aectorch.ops import native


def test_native_kernel_is_built_and_used():
    # CI and `make test` must exercise the kernel, not silently fall back to torch.
    assert native.available(), "the fused CPU kernels did not build (see the warning)"
    d = torch.nn.functional.normalize(torch.randn(30, 60, dtype=torch.float64), dim=0)
    x = torch.randn(5, 30, dtype=torch.float64)
    a = omp(x, d, 4, backend="native")
    b = omp(x, d, 4, backend="torch")
    assert torch.equal(a.indices, b.indices)
    torch.testing.assert_close(a.coefficients, b.coefficients, rtol=0, atol=1e-12)


@pytest.mark.skipif(os.uname().machine != "x86_64", reason="-march targets of x86-64")
def test_the_kernels_target_is_this_cpu_unless_aectorch_native_march_names_another(monkeypatch):
    monkeypatch.delenv("AECTORCH_NATIVE_MARCH", raising=False)
    assert "-march=native" in native._flags()
    default_folder = native._build_dir()[1]
    monkeypatch.setenv("AECTORCH_NATIVE_MARCH", "x86-64-v3")
    assert "-march=x86-64-v3" in native._flags() and "-march=native" not in native._flags()
    assert native._build_dir()[1] != default_folder  # a build of its own
    monkeypatch.setenv("AECTORCH_NATIVE_MARCH", "native; rm -rf ~")
    with pytest.raises(ValueError, match="AECTORCH_NATIVE_MARCH must name a -march target"):
        native._flags()


def test_backend_argument_is_validated():
    d = torch.nn.functional.normalize(torch.randn(30, 60), dim=0)
    with pytest.raises(ValueError, match="backend must be one of"):
        omp(torch.randn(5, 30), d, 4, backend="fast")
    with pytest.raises(ValueError, match="backend must be one of"):
        with use_backend("cuda"):
            pass
    with pytest.raises(ValueError, match="backend='native' needs float32 or float64"):
        matching_pursuit(torch.randn(5, 30).half(), d.half(), 4, backend="native")


_FALLBACK = """
import warnings, torch
from aectorch.coding import omp
from aectorch.ops import native
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    d = torch.nn.functional.normalize(torch.randn(30, 60), dim=0)
    code = omp(torch.randn(5, 30), d, 4)
print(native.available(), code.indices.shape[-1], "|".join(str(w.message) for w in caught))
"""


@pytest.mark.integration
@pytest.mark.parametrize("how", ["disabled", "no compiler"])
def test_without_the_kernel_the_coders_fall_back_to_torch(tmp_path, how):
    env = dict(os.environ, AECTORCH_CACHE=str(tmp_path))  # nothing cached: a fresh build
    if how == "disabled":
        env["AECTORCH_NATIVE"] = "0"
    else:
        env["CXX"] = "/bin/false"
    out = subprocess.run([sys.executable, "-c", _FALLBACK], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out.startswith("False 4")
    if how == "disabled":
        assert out == "False 4"  # silent: the user asked for it
    else:
        assert "fused CPU kernels are not available" in out and "pure-torch" in out




@pytest.mark.parametrize("orthogonal", [False, True])
def test_kernel_threads_split_the_work_and_change_nothing(orthogonal):
    """Two kernel threads (their own OpenMP pool) give the one-thread result bit for bit, also for a
    dictionary that requires grad outside no_grad (each worker takes the caller's grad mode)."""
    coder = omp if orthogonal else matching_pursuit
    d = torch.nn.functional.normalize(torch.randn(40, 90), dim=0).requires_grad_(True)
    x = torch.randn(1100, 40)
    with pytest.raises(ValueError, match="threads"):
        native.set_threads(0)
    before = native.get_threads()
    try:
        native.set_threads(1)
        one = coder(x, d.detach(), 5, backend="native", block_size=256)
        native.set_threads(2)
        assert native.get_threads() == 2
        two = coder(x, d, 5, backend="native", block_size=256)
    finally:
        native.set_threads(before)
    assert torch.equal(one.indices, two.indices) and torch.equal(one.coefficients, two.coefficients)


def _gram_of(seed: int, child: bool = False) -> torch.Tensor:
    if child:  # what a DataLoader's worker does: torch's own operations on one thread
        torch.set_num_threads(1)
    d = torch.randn(40, 96, generator=torch.Generator().manual_seed(seed))
    return torch.ops.aectorch.gram(d)


@pytest.mark.integration
def test_kernels_run_in_a_forked_child_after_their_threads_started():
    """A fork's child has none of the parent's OpenMP threads: its kernels run on one thread, with
    the same bits. Before, a child that used them (a multiprocessing pool, a DataLoader's worker
    forked after training) waited forever for the missing threads."""
    import multiprocessing

    before = native.get_threads()
    try:
        native.set_threads(2)
        parent = _gram_of(0)  # the parent's second thread runs
        with multiprocessing.get_context("fork").Pool(1) as pool:
            child = pool.apply_async(_gram_of, (0, True)).get(timeout=120)
        again = _gram_of(0)
    finally:
        native.set_threads(before)
    assert torch.equal(parent, child) and torch.equal(parent, again)


def _coded(algorithm: str, dtype, *, seed: int = 0):
    from aectorch.coding import SparseDictionary

    d = SparseDictionary(96, 40, 6, algorithm, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    x = torch.randn(5, 17, 40, generator=torch.Generator().manual_seed(seed + 1), dtype=dtype)
    x[0, 0] = 0  # a zero signal: error 0, no gradient
    return d, x


@pytest.mark.parametrize("algorithm", ["mp", "omp"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fused_reconstruction_error_gradient_and_pooling_match_torch(algorithm, dtype):
    """The dictionary's fused kernels (reconstruction and eq. (4) error, the gradient from the active
    atoms, the pooled activities) against torch's dense operations, on the same codes."""
    from aectorch.coding.dictionary import pooled_activity, reconstruction_error

    assert native.available()
    d, x = _coded(algorithm, dtype)
    tol = dict(rtol=1e-5, atol=1e-6) if dtype == torch.float32 else dict(rtol=1e-12, atol=1e-13)
    with torch.no_grad():
        fused = d(x)
    code = fused.code
    dense = code.to_dense(d.num_atoms)
    reconstruction = dense @ d.atoms.detach().t()
    torch.testing.assert_close(fused.reconstruction, reconstruction, **tol)
    torch.testing.assert_close(fused.error, reconstruction_error(x, reconstruction), **tol)
    assert float(fused.error[0, 0]) == 0.0
    # the gradient: autograd of the mean error through torch's differentiable path
    atoms = d.atoms.detach().clone().requires_grad_(True)
    reference = reconstruction_error(x, code.reconstruct(atoms)).mean()
    reference.backward()
    torch.testing.assert_close(d.gradient(x, fused), atoms.grad, **tol)
    for reduction in ("sum", "mean"):
        torch.testing.assert_close(d.pooled_activity(code, reduction=reduction),
                                   pooled_activity(code, d.num_atoms, reduction=reduction), **tol)


@pytest.mark.parametrize("algorithm", ["mp", "omp"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("lead", [(), (4,), (2, 3)])
def test_encode_in_one_pass_gives_the_bits_of_the_three_kernels_on_any_number_of_threads(algorithm, dtype, lead):
    """`SparseDictionary.forward_pooled` (one aectorch::encode call) against the coder, then
    reconstruct_error, then pooled_power: every output bit-identical, with 1, 2 and 3 threads."""
    from torch.profiler import ProfilerActivity, profile

    d, x = _coded(algorithm, dtype, seed=4)
    x = x.reshape(-1, 40)[:84].reshape(*lead, -1, 40) if lead else x.reshape(-1, 40)[:9]
    before = native.get_threads()
    try:
        for threads in (1, 2, 3):
            native.set_threads(threads)
            with torch.no_grad():
                with profile(activities=[ProfilerActivity.CPU]) as prof:
                    out, features = d.forward_pooled(x, reduction="mean")
                plain = d(x)
                plain_features = d.pooled_activity(plain.code, reduction="mean")
            ops = {e.key for e in prof.key_averages()}
            assert "aectorch::encode" in ops and not ops & {"aectorch::gram", "aectorch::sparse_code",
                                                            "aectorch::reconstruct_error", "aectorch::pooled_power"}
            for got, expected in zip((*out.code, out.reconstruction, out.error, features),
                                     (*plain.code, plain.reconstruction, plain.error, plain_features)):
                assert got.shape == expected.shape and torch.equal(got, expected)
    finally:
        native.set_threads(before)
    assert features.shape == (*lead, d.num_atoms)
    # a Gram matrix given to the kernel: the same codes as the one it computes
    atoms = d.atoms.detach()
    given = torch.ops.aectorch.encode(x.reshape(-1, 40), atoms, torch.ops.aectorch.gram(atoms), 6,
                                      algorithm == "omp", 512, max(1, x[..., 0, 0].numel()))
    assert torch.equal(given[0], out.code.indices.reshape(-1, 6)) and torch.equal(given[4].reshape(features.shape) / x.shape[-2], features)
    # with a graph to build, or on torch's backend: the unfused path, the same numbers
    out_graph, features_graph = d.forward_pooled(x, reduction="sum")
    assert out_graph.error.requires_grad
    torch.testing.assert_close(features_graph, features * x.shape[-2])
    with use_backend("torch"), torch.no_grad():
        out_torch, features_torch = d.forward_pooled(x, reduction="mean")
    assert torch.equal(out_torch.code.indices, out.code.indices)
    torch.testing.assert_close(features_torch, features)


_PRODUCTS = """
import torch
from aectorch.coding import gram_matrix
from aectorch.ops import native
d = torch.nn.functional.normalize(torch.randn(200, 288, generator=torch.Generator().manual_seed(5)), dim=0)
print(native.available(), torch.equal(gram_matrix(d), d.t() @ d),
      bool(torch.allclose(gram_matrix(d), d.t() @ d, rtol=1e-6, atol=1e-6)))
"""


@pytest.mark.integration
@pytest.mark.parametrize("onednn", ["1", "0"])
def test_the_kernels_products_are_onednns_unless_aectorch_onednn_is_0(onednn):
    """By default the fused kernels' float32 products run in oneDNN: torch's product (MKL) within
    rounding; ``AECTORCH_ONEDNN=0`` keeps torch's product, bit for bit."""
    env = dict(os.environ, AECTORCH_ONEDNN=onednn)
    out = subprocess.run([sys.executable, "-c", _PRODUCTS], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "True" and out[2] == "True"
    if onednn == "0":
        assert out[1] == "True"


def test_the_kernels_products_give_the_same_codes_on_any_number_of_torch_and_kernel_threads():
    """oneDNN runs on torch's threads inside the kernels' own: neither count changes a bit."""
    g = torch.Generator().manual_seed(6)
    d = torch.nn.functional.normalize(torch.randn(200, 288, generator=g), dim=0)
    x = torch.nn.functional.normalize(torch.randn(1568, 200, generator=g), dim=1)
    kernel_threads, torch_threads = native.get_threads(), torch.get_num_threads()
    results = []
    try:
        for torch_count in (1, 2):
            for kernel_count in (1, 2, 3):
                torch.set_num_threads(torch_count)
                native.set_threads(kernel_count)
                results.append(torch.ops.aectorch.encode(x, d, None, 10, False, 512, 32))
    finally:
        native.set_threads(kernel_threads)
        torch.set_num_threads(torch_threads)
    assert all(torch.equal(a, b) for other in results[1:] for a, b in zip(results[0], other))


def test_encode_checks_its_groups_and_has_shapes_for_torch_compile():
    from torch._subclasses.fake_tensor import FakeTensorMode

    d, x = _coded("mp", torch.float32)
    atoms = d.atoms.detach()
    gram = atoms.t() @ atoms
    with pytest.raises(RuntimeError, match="groups must be >= 1 and divide"):
        torch.ops.aectorch.encode(x.reshape(-1, 40)[:7], atoms, gram, 6, False, 512, 2)
    with FakeTensorMode():
        outs = torch.ops.aectorch.encode(torch.empty(12, 40), torch.empty(40, 96), None, 6, True, 512, 3)
    assert [tuple(o.shape) for o in outs] == [(12, 6), (12, 6), (12, 40), (12,), (3, 96)]
    assert outs[0].dtype == torch.long


def test_pooled_power_adds_an_atom_picked_twice_before_squaring():
    from aectorch.coding import SparseCode, SparseDictionary
    from aectorch.coding.dictionary import pooled_activity

    d = SparseDictionary(6, 4, 3, "mp", dtype=torch.float64)
    code = SparseCode(torch.tensor([[[1, 1, 2], [0, 5, 0]], [[3, 3, 3], [4, 2, 1]]]),
                      torch.tensor([[[1.0, 2, 3], [0.5, 1, -2]], [[1, 1, 1.0], [2, 2, 2]]], dtype=torch.float64))
    expected = torch.tensor([[(0.5 - 2) ** 2, 3.0 ** 2, 9, 0, 0, 1], [0, 4, 4, 9, 4, 0]], dtype=torch.float64)
    assert torch.equal(d.pooled_activity(code), expected)
    assert torch.equal(pooled_activity(code, 6), expected)
    with pytest.raises(RuntimeError, match="outside"):
        torch.ops.aectorch.pooled_power(torch.tensor([[[6]]]), torch.ones(1, 1, 1), 6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("num_atoms", [7, 96, 288])
def test_fused_gram_matrix_is_torchs_product_on_any_number_of_threads(num_atoms, dtype):
    from aectorch.coding import gram_matrix

    d = torch.nn.functional.normalize(torch.randn(40, num_atoms, dtype=dtype, generator=torch.Generator().manual_seed(2)), dim=0)
    reference = d.t() @ d
    tol = dict(rtol=1e-6, atol=1e-6) if dtype == torch.float32 else dict(rtol=1e-13, atol=1e-14)
    before = native.get_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            native.set_threads(threads)
            results.append(gram_matrix(d))
    finally:
        native.set_threads(before)
    torch.testing.assert_close(results[0], reference, **tol)
    assert all(torch.equal(results[0], r) for r in results[1:])
    # with a graph to build, torch's differentiable product runs
    leaf = d.clone().requires_grad_(True)
    gram_matrix(leaf).sum().backward()
    assert leaf.grad is not None


@pytest.mark.parametrize("op", ["reconstruct_error", "sparse_gradient", "pooled_power", "pair_patches"])
def test_fused_dictionary_kernels_give_the_same_bits_on_any_number_of_threads(op):
    d, x = _coded("mp", torch.float32, seed=3)
    with torch.no_grad():
        out = d(x)
    flat_x, idx, coef = x.reshape(-1, 40), out.code.indices.reshape(-1, 6), out.code.coefficients.reshape(-1, 6)
    calls = {
        "reconstruct_error": lambda: torch.cat([t.reshape(-1) for t in torch.ops.aectorch.reconstruct_error(
            flat_x, d.atoms.detach().t().contiguous(), idx, coef)]),
        "sparse_gradient": lambda: torch.ops.aectorch.sparse_gradient(
            flat_x, out.reconstruction.reshape(-1, 40), idx, coef, 96),
        "pooled_power": lambda: torch.ops.aectorch.pooled_power(out.code.indices, out.code.coefficients, 96),
        "pair_patches": lambda: torch.ops.aectorch.pair_patches(x.reshape(10, 17, 20), 1, 5, 2, 6, 1e-8, 1e-6),
    }
    before = native.get_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            native.set_threads(threads)
            results.append(calls[op]())
    finally:
        native.set_threads(before)
    assert all(torch.equal(results[0], r) for r in results[1:])


def test_the_sparse_gradient_of_many_signals_gives_the_same_bits_on_any_number_of_threads():
    # from 2^20 signal values the kernel splits the atoms over threads (below, one thread runs)
    g = torch.Generator().manual_seed(7)
    m, p, k, n = 6000, 200, 10, 288
    x, reconstruction = torch.randn(m, p, generator=g), torch.randn(m, p, generator=g)
    indices, coefficients = torch.randint(0, n, (m, k), generator=g), torch.randn(m, k, generator=g)
    before = native.get_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            native.set_threads(threads)
            results.append(torch.ops.aectorch.sparse_gradient(x, reconstruction, indices, coefficients, n))
    finally:
        native.set_threads(before)
    assert all(torch.equal(results[0], r) for r in results[1:])
    weighted = (x - reconstruction) / x.square().sum(-1, keepdim=True)
    dense = torch.zeros(m, n).scatter_add_(1, indices, coefficients)
    torch.testing.assert_close(results[0], dense.t() @ weighted, rtol=1e-4, atol=1e-4)


def test_fused_dictionary_kernels_have_shapes_for_torch_compile():
    from torch._subclasses.fake_tensor import FakeTensorMode

    with FakeTensorMode():
        x, idx, coef = torch.empty(7, 40), torch.zeros(7, 6, dtype=torch.long), torch.empty(7, 6)
        recon, error = torch.ops.aectorch.reconstruct_error(x, torch.empty(96, 40), idx, coef)
        grad = torch.ops.aectorch.sparse_gradient(x, x, idx, coef, 96)
        pooled = torch.ops.aectorch.pooled_power(idx.reshape(1, 7, 6), coef.reshape(1, 7, 6), 96)
        patches = torch.ops.aectorch.pair_patches(torch.empty(4, 20, 20), 0, 5, 5, 4, 1e-8, 1e-6)
        gram = torch.ops.aectorch.gram(torch.empty(40, 96))
    assert gram.shape == (96, 96)
    assert (recon.shape, error.shape, grad.shape, pooled.shape) == ((7, 40), (7,), (96, 40), (1, 96))
    assert patches.shape == (2, 16, 50)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("scale", ["wide", "coarse", "fine", "full"])
def test_fused_patches_match_torch_including_flat_patches(scale, dtype):
    from aectorch.coding.patches import as_scale, scale_patches

    side = as_scale(scale).side
    pair = torch.rand(3, 2, side, side, generator=torch.Generator().manual_seed(0), dtype=dtype)
    pair[0, :, : side // 2, : side // 2] = 0.5  # flat patches: zero
    pair[1, 1] = 0.25  # a flat second image
    fused = scale_patches(pair, scale)
    with use_backend("torch"):
        reference = scale_patches(pair, scale)
    tol = dict(rtol=1e-5, atol=1e-6) if dtype == torch.float32 else dict(rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(fused, reference, **tol)
    flat = fused.reshape(*fused.shape[:2], 2, -1).abs().sum(-1) == 0  # per half
    assert torch.equal(flat, reference.reshape(flat.shape + (-1,)).abs().sum(-1) == 0)
    assert bool(flat[1, :, 1].all()) and not bool(flat[1, :, 0].any())
    # with a graph to build, torch's differentiable path runs
    leaf = pair.clone().requires_grad_(True)
    scale_patches(leaf, scale).sum().backward()
    assert leaf.grad is not None


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fused_dictionary_step_matches_torch(mirrored, dtype):
    """`SparseDictionary.learn_`: the fused step (aectorch::dictionary_step_) against torch's
    sub_ / symmetrize_ / renormalize_, from the same atoms and codes."""
    import copy

    from aectorch.coding import SparseDictionary, patch_permutation

    mirror = patch_permutation(4) if mirrored else None
    d = SparseDictionary(64, 32, 5, "mp", generator=torch.Generator().manual_seed(0), mirror=mirror, dtype=dtype)
    x = torch.randn(3, 11, 32, generator=torch.Generator().manual_seed(1), dtype=dtype)
    with torch.no_grad():
        out = d(x)
    reference = copy.deepcopy(d)
    version = d.atoms._version
    grad = d.learn_(x, out, 0.3)
    assert d.atoms._version > version  # autograd sees the in-place change
    with use_backend("torch"):
        reference_grad = reference.learn_(x, out, 0.3)
    tol = dict(rtol=1e-5, atol=1e-6) if dtype == torch.float32 else dict(rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(grad, reference_grad, **tol)
    torch.testing.assert_close(d.atoms.detach(), reference.atoms.detach(), **tol)
    torch.testing.assert_close(d.atoms.detach().norm(dim=0), torch.ones(64, dtype=dtype), **tol)
    if mirrored:
        atoms = d.atoms.detach()
        torch.testing.assert_close(atoms[d.mirror][:, d.partner], atoms, **tol)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dictionaries_learn_together_with_the_bits_of_learning_one_by_one(mirrored, dtype):
    """`learn_together_` (aectorch::learn_steps_: the dictionaries spread over the kernels' threads,
    each on one) against `SparseDictionary.learn_` of each in turn, on 1-3 threads; an index out of
    range changes no dictionary."""
    import copy

    from aectorch.coding import SparseDictionary, patch_permutation
    from aectorch.coding.dictionary import learn_together_

    mirror = patch_permutation(4) if mirrored else None
    g = torch.Generator().manual_seed(0)
    # unequal work: 2, 40, 90 and 25 signals
    dicts = [SparseDictionary(64, 32, 5, "mp", generator=g, mirror=mirror, dtype=dtype) for _ in range(4)]
    xs = [torch.randn(m, 32, generator=g, dtype=dtype) for m in (2, 40, 90, 25)]
    with torch.no_grad():
        outs = [d(x) for d, x in zip(dicts, xs)]
    reference = copy.deepcopy(dicts)
    for d, x, out in zip(reference, xs, outs):
        d.learn_(x, out, 0.3)
    threads = native.get_threads()
    try:
        for count in (1, 2, 3):
            native.set_threads(count)
            together = copy.deepcopy(dicts)
            versions = [d.atoms._version for d in together]
            learn_together_(together, xs, outs, 0.3)
            for d, r, version in zip(together, reference, versions):
                assert torch.equal(d.atoms, r.atoms), count
                assert d.atoms._version > version  # autograd sees the in-place change
    finally:
        native.set_threads(threads)
    broken = copy.deepcopy(dicts)
    bad = outs[2]._replace(code=outs[2].code._replace(indices=outs[2].code.indices.clone().fill_(64)))
    with pytest.raises(RuntimeError, match="outside .0, num_atoms.; no dictionary was changed"):
        learn_together_(broken, xs, outs[:2] + [bad] + outs[3:], 0.3)
    for d, before in zip(broken, dicts):
        assert torch.equal(d.atoms, before.atoms)
    with pytest.raises(ValueError, match="one signals and one output per dictionary"):
        learn_together_(broken, xs[:3], outs, 0.3)
