"""Tests for aectorch.coding.dictionary: SparseDictionary, pooled_activity, reconstruction_error.

Oracles: hand-written loops of eqs. (1), (3), (4) of the paper, the closed-form gradient written
out independently, torch.optim.SGD, and a hidden sparse generative model the dictionary must learn.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from torch import nn

from aectorch.coding import (
    SparseCode,
    SparseDictionary,
    matching_pursuit,
    omp,
    pooled_activity,
    reconstruction_error,
)

torch.set_num_threads(1)

F64 = torch.float64
ALGORITHMS = ["omp", "mp"]
CODERS = {"omp": omp, "mp": matching_pursuit}
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _randn(*shape, seed=0, dtype=F64):
    return torch.randn(*shape, generator=_gen(seed), dtype=dtype)


def _close(actual: torch.Tensor, expected: torch.Tensor, atol: float = 1e-12) -> None:
    """Same shape and dtype and max |actual - expected| <= atol.

    (torch.testing.assert_close's first call costs ~2 s of imports.)
    """
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    assert actual.dtype == expected.dtype, (actual.dtype, expected.dtype)
    if actual.numel() == 0:
        return
    diff = (actual.detach().cpu() - expected.detach().cpu()).abs().max().item()
    assert diff <= atol, f"max abs difference {diff:.3g} > {atol:.3g}"


def _dense_loop(code: SparseCode, num_atoms: int) -> torch.Tensor:
    """Dense coefficients [M, N] by an explicit loop (repeated atoms summed)."""
    idx = code.indices.reshape(-1, code.indices.shape[-1])
    coef = code.coefficients.detach().reshape(-1, code.indices.shape[-1])
    dense = torch.zeros(idx.shape[0], num_atoms, dtype=coef.dtype)
    for m in range(idx.shape[0]):
        for j in range(idx.shape[1]):
            dense[m, int(idx[m, j])] += coef[m, j]
    return dense


# ---------------------------------------------------------------------------------------------
# Construction


def test_atoms_are_unit_norm_parameter():
    d = SparseDictionary(num_atoms=30, dim=20, sparsity=3, generator=_gen(0))
    assert isinstance(d.atoms, nn.Parameter)
    assert d.atoms.requires_grad
    assert d.atoms.shape == (20, 30)
    assert d.atoms.dtype == torch.get_default_dtype()
    assert [p is d.atoms for p in d.parameters()] == [True]
    _close(d.atoms.detach().norm(dim=0), torch.ones(30), atol=1e-6)
    assert (d.num_atoms, d.dim, d.sparsity, d.algorithm) == (30, 20, 3, "omp")


def test_same_seed_same_atoms_different_seed_different():
    a = SparseDictionary(30, 20, 3, generator=_gen(5)).atoms.detach()
    b = SparseDictionary(30, 20, 3, generator=_gen(5)).atoms.detach()
    c = SparseDictionary(30, 20, 3, generator=_gen(6)).atoms.detach()
    assert torch.equal(a, b)
    assert not torch.allclose(a, c)
    # the initial atoms are white noise, unit-normalised (not e.g. a fixed basis)
    assert (a.t() @ a - torch.eye(30)).abs().max() > 0.1


def test_dtype_and_device_honoured():
    d = SparseDictionary(30, 20, 3, generator=_gen(0), dtype=F64, device="cpu")
    assert d.atoms.dtype == F64
    assert d.atoms.device.type == "cpu"
    _close(d.atoms.detach().norm(dim=0), torch.ones(30, dtype=F64), atol=1e-14)
    out = d(_randn(4, 20))
    assert out.reconstruction.dtype == F64 and out.error.dtype == F64
    assert out.code.coefficients.dtype == F64


@needs_cuda
def test_cuda_device_matches_cpu():
    cpu = SparseDictionary(30, 20, 3, generator=_gen(0), dtype=F64)
    gpu = SparseDictionary(30, 20, 3, generator=_gen(0), dtype=F64, device="cuda")
    assert gpu.atoms.device.type == "cuda"
    _close(gpu.atoms.detach().cpu(), cpu.atoms.detach())
    x = _randn(16, 20, seed=1)
    out_cpu, out_gpu = cpu(x), gpu(x.cuda())
    assert torch.equal(out_gpu.code.indices.cpu(), out_cpu.code.indices)
    _close(out_gpu.error.cpu(), out_cpu.error)
    out_gpu.error.mean().backward()
    _close(gpu.atoms.grad.cpu(), cpu.gradient(x, out_cpu))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(num_atoms=0), "num_atoms"),
        (dict(num_atoms=2.5), "num_atoms"),
        (dict(num_atoms=True), "num_atoms"),
        (dict(dim=-1), "dim"),
        (dict(sparsity=0), "sparsity"),
        (dict(num_atoms=30, dim=20, sparsity=21), "sparsity"),  # sparsity > dim
        (dict(num_atoms=5, dim=20, sparsity=6), "sparsity"),  # sparsity > num_atoms
        (dict(algorithm="lasso"), "algorithm"),
    ],
)
def test_validation_names_the_argument(kwargs, name):
    args = dict(num_atoms=30, dim=20, sparsity=3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        SparseDictionary(**args)


def test_sparsity_equal_to_min_is_allowed():
    d = SparseDictionary(num_atoms=8, dim=20, sparsity=8, generator=_gen(0))
    assert d(torch.randn(2, 20)).code.indices.shape == (2, 8)


# ---------------------------------------------------------------------------------------------
# Forward


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("lead", [(7,), (2, 5)])
def test_forward_shapes_error_and_code(algorithm, lead):
    d = SparseDictionary(30, 20, 4, algorithm, generator=_gen(1), dtype=F64)
    x = _randn(*lead, 20, seed=2)
    out = d(x)
    assert out.code.indices.shape == (*lead, 4)
    assert out.code.indices.dtype == torch.int64
    assert out.code.coefficients.shape == (*lead, 4)
    assert out.reconstruction.shape == (*lead, 20)
    assert out.error.shape == lead

    # the code is exactly that of the coder called directly
    direct = CODERS[algorithm](x, d.atoms.detach(), 4)
    assert torch.equal(out.code.indices, direct.indices)
    _close(out.code.coefficients, direct.coefficients, atol=1e-12)
    assert torch.equal(d.encode(x).indices, direct.indices)

    # eq. (1) by hand, then eq. (4) by hand
    atoms = d.atoms.detach()
    dense = _dense_loop(out.code, 30).reshape(*lead, 30)
    recon = dense @ atoms.t()
    _close(out.reconstruction.detach(), recon, atol=1e-12)
    manual = ((x - recon) ** 2).sum(-1) / (x**2).sum(-1)
    _close(out.error.detach(), manual, atol=1e-12)
    _close(reconstruction_error(x, recon), manual, atol=1e-12)

    # the code is a constant for autograd, the reconstruction is not
    assert not out.code.coefficients.requires_grad
    assert out.reconstruction.requires_grad and out.error.requires_grad


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_large_batch_equals_small_pieces(algorithm):
    """1100 signals (past the CPU block size of the coders) code like 100 at a time."""
    d = SparseDictionary(30, 20, 4, algorithm, generator=_gen(21), dtype=F64)
    x = _randn(1100, 20, seed=22)
    with torch.no_grad():
        whole = d(x)
        pieces = [d(x[s : s + 100]) for s in range(0, 1100, 100)]
    assert torch.equal(whole.code.indices, torch.cat([p.code.indices for p in pieces]))
    _close(whole.error, torch.cat([p.error for p in pieces]), atol=1e-12)


def test_omp_forward_is_greedy_least_squares():
    """A loop of textbook OMP (argmax |D^T r|, then least squares on the support) agrees."""
    d = SparseDictionary(30, 20, 5, "omp", generator=_gen(3), dtype=F64)
    atoms = d.atoms.detach()
    x = _randn(6, 20, seed=4)
    out = d(x)
    for m in range(6):
        support, r = [], x[m].clone()
        for j in range(5):
            n = int((atoms.t() @ r).abs().argmax())
            assert int(out.code.indices[m, j]) == n
            support.append(n)
            coef = torch.linalg.lstsq(atoms[:, support], x[m][:, None]).solution[:, 0]
            r = x[m] - atoms[:, support] @ coef
        _close(out.code.coefficients[m], coef, atol=1e-10)


def test_mp_forward_is_plain_matching_pursuit():
    """A loop of Mallat & Zhang's MP on the residual (no Gram trick) gives the same code."""
    d = SparseDictionary(30, 20, 5, "mp", generator=_gen(3), dtype=F64)
    atoms = d.atoms.detach()
    x = _randn(6, 20, seed=4)
    out = d(x)
    for m in range(6):
        r = x[m].clone()
        for j in range(5):
            corr = atoms.t() @ r
            n = int(corr.abs().argmax())
            assert int(out.code.indices[m, j]) == n
            _close(out.code.coefficients[m, j], corr[n], atol=1e-12)
            r = r - corr[n] * atoms[:, n]


# ---------------------------------------------------------------------------------------------
# Gradient and learning step


def _independent_gradient(x: torch.Tensor, out, atoms: torch.Tensor) -> torch.Tensor:
    """-(2/M) sum_i r_i a_i^T / ||x_i||^2, one signal at a time."""
    num_atoms = atoms.shape[1]
    xs = x.reshape(-1, atoms.shape[0])
    dense = _dense_loop(out.code, num_atoms)
    grad = torch.zeros_like(atoms)
    for i in range(xs.shape[0]):
        r = xs[i] - atoms @ dense[i]
        grad -= torch.outer(r, dense[i]) / xs[i].dot(xs[i])
    return grad * 2.0 / xs.shape[0]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("lead", [(9,), (3, 4)])
def test_gradient_autograd_closed_form_and_independent(algorithm, lead):
    d = SparseDictionary(30, 20, 4, algorithm, generator=_gen(7), dtype=F64)
    x = _randn(*lead, 20, seed=8) * torch.linspace(0.5, 3.0, 20, dtype=F64)  # varied ||x_i||
    out = d(x)
    out.error.mean().backward()
    auto = d.atoms.grad.clone()
    closed = d.gradient(x, out)
    independent = _independent_gradient(x, out, d.atoms.detach())
    assert closed.shape == (20, 30)
    assert auto.abs().max() > 1e-3  # a gradient that is not trivially zero
    _close(auto, closed, atol=1e-10)
    _close(auto, independent, atol=1e-10)


def test_gradient_finite_difference():
    """The gradient of the mean error with the code held fixed, checked numerically."""
    d = SparseDictionary(12, 8, 3, "omp", generator=_gen(9), dtype=F64)
    x = _randn(5, 8, seed=10)
    out = d(x)
    code = out.code

    def loss(atoms):
        return reconstruction_error(x, code.reconstruct(atoms)).mean()

    assert torch.autograd.gradcheck(loss, (d.atoms.detach().clone().requires_grad_(),))
    atoms = d.atoms.detach().clone().requires_grad_()
    (grad,) = torch.autograd.grad(loss(atoms), atoms)
    _close(grad, d.gradient(x, out), atol=1e-12)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_learn_equals_sgd_step_then_renormalize(algorithm):
    lr = 0.3
    d1 = SparseDictionary(30, 20, 4, algorithm, generator=_gen(11), dtype=F64)
    d2 = copy.deepcopy(d1)
    before = d1.atoms.detach().clone()
    x = _randn(4, 6, 20, seed=12)

    grad = d1.learn_(x, d1(x), lr)

    opt = torch.optim.SGD(d2.parameters(), lr=lr)
    opt.zero_grad()
    d2(x).error.mean().backward()
    opt.step()
    d2.renormalize_()

    _close(grad, d2.atoms.grad, atol=1e-10)
    _close(d1.atoms.detach(), d2.atoms.detach(), atol=1e-10)
    assert (d1.atoms.detach() - before).abs().max() > 1e-3  # the step did move the atoms
    _close(d1.atoms.detach().norm(dim=0), torch.ones(30, dtype=F64), atol=1e-12)
    assert d1.atoms.grad is None  # learn_ builds no graph and leaves .grad alone


@pytest.mark.parametrize("lr", [-0.1, float("nan")])
def test_learn_rejects_bad_lr(lr):
    d = SparseDictionary(30, 20, 3, generator=_gen(0))
    x = torch.randn(4, 20)
    with pytest.raises(ValueError, match="lr"):
        d.learn_(x, d(x), lr)


def _hidden_model_signals(truth: torch.Tensor, n: int, g: torch.Generator, noise=0.01):
    """n signals, each 3 random distinct atoms of `truth` with coefficients |c| >= 0.5, + noise."""
    dim, num_atoms = truth.shape
    idx = torch.rand(n, num_atoms, generator=g, dtype=truth.dtype).argsort(-1)[:, :3]
    c = torch.randn(n, 3, generator=g, dtype=truth.dtype)
    c = c.sign() * (c.abs() + 0.5)
    x = (truth[:, idx] * c[None]).sum(-1).t()
    return x + noise * torch.randn(n, dim, generator=g, dtype=truth.dtype)


# Measured with these seeds (200 steps of 64 signals, lr 1, 500 held-out signals): error ratio
# final/initial omp 0.108 (0.422 -> 0.046), mp 0.165 (0.441 -> 0.073), 27 of the 30 hidden atoms
# recovered with |cos| > 0.9 by both; learn_ and SGD + renormalize_ follow the same trajectory.
# With 300 steps over seeds 0-3 the ratio stayed below 0.25 and recovery at >= 24 atoms.
@pytest.mark.parametrize("method", ["learn_", "sgd"])
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_learning_recovers_hidden_sparse_model(algorithm, method):
    g = _gen(0)
    truth = nn.functional.normalize(torch.randn(20, 30, generator=g, dtype=F64), dim=0)
    held_out = _hidden_model_signals(truth, 500, g)
    d = SparseDictionary(30, 20, 3, algorithm, generator=_gen(100), dtype=F64)
    opt = torch.optim.SGD(d.parameters(), lr=1.0)
    with torch.no_grad():
        initial = d(held_out).error.mean().item()
    for _ in range(200):
        x = _hidden_model_signals(truth, 64, g)
        if method == "learn_":
            d.learn_(x, d(x), 1.0)
        else:
            opt.zero_grad()
            d(x).error.mean().backward()
            opt.step()
            d.renormalize_()
    with torch.no_grad():
        final = d(held_out).error.mean().item()
    recovered = (d.atoms.detach().t() @ truth).abs().amax(0)
    assert initial > 0.35
    assert final < 0.3 * initial, (initial, final)
    assert int((recovered > 0.9).sum()) >= 20, recovered


# ---------------------------------------------------------------------------------------------
# Zero signals and renormalisation


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_zero_signal_gives_zero_code_zero_error_no_nan(algorithm):
    d = SparseDictionary(30, 20, 4, algorithm, generator=_gen(13), dtype=F64)
    signal = _randn(1, 20, seed=14)
    x = torch.cat([torch.zeros(1, 20, dtype=F64), signal])
    out = d(x)
    assert torch.equal(out.code.coefficients[0], torch.zeros(4, dtype=F64))
    assert out.error[0].item() == 0.0
    assert torch.isfinite(out.error).all() and torch.isfinite(out.reconstruction).all()
    out.error.mean().backward()
    assert torch.isfinite(d.atoms.grad).all()
    # the zero signal contributes nothing: the gradient is half that of the other signal alone
    _close(d.atoms.grad, 0.5 * d.gradient(signal, d(signal)), atol=1e-12)
    _close(d.gradient(x, out), d.atoms.grad, atol=1e-12)
    # all-zero batch
    zero = torch.zeros(3, 20, dtype=F64, requires_grad=True)
    d.atoms.grad = None
    out = d(zero)
    assert torch.equal(out.error, torch.zeros(3, dtype=F64))
    out.error.mean().backward()
    assert torch.equal(d.atoms.grad, torch.zeros_like(d.atoms))


def test_renormalize_restores_unit_norm_and_keeps_zero_atom():
    d = SparseDictionary(30, 20, 3, generator=_gen(15), dtype=F64)
    original = d.atoms.detach().clone()
    scales = torch.rand(30, generator=_gen(16), dtype=F64) * 10 + 0.01
    with torch.no_grad():
        d.atoms.mul_(scales)
        d.atoms[:, 3] = 0.0
    assert d.renormalize_() is d
    norms = d.atoms.detach().norm(dim=0)
    assert not torch.isnan(d.atoms).any()
    assert torch.equal(d.atoms[:, 3].detach(), torch.zeros(20, dtype=F64))
    keep = torch.arange(30) != 3
    _close(norms[keep], torch.ones(29, dtype=F64), atol=1e-14)
    _close(d.atoms.detach()[:, keep], original[:, keep], atol=1e-14)


# ---------------------------------------------------------------------------------------------
# Pooled activity, eq. (3)


def _pooled_loop(code: SparseCode, num_atoms: int) -> torch.Tensor:
    """f_n = sum_i (sum of the coefficients of atom n in patch i)^2, loop by loop."""
    idx, coef = code.indices, code.coefficients
    lead, (n_patches, k) = idx.shape[:-2], idx.shape[-2:]
    idx = idx.reshape(-1, n_patches, k)
    coef = coef.reshape(-1, n_patches, k)
    f = torch.zeros(idx.shape[0], num_atoms, dtype=coef.dtype)
    for b in range(idx.shape[0]):
        for i in range(n_patches):
            a = {}
            for j in range(k):
                n = int(idx[b, i, j])
                a[n] = a.get(n, 0.0) + float(coef[b, i, j])
            for n, value in a.items():
                f[b, n] += value**2
    return f.reshape(*lead, num_atoms)


@pytest.mark.parametrize("lead", [(), (3,), (2, 2)])
def test_pooled_activity_matches_loop_with_repeated_atoms(lead):
    g = _gen(17)
    shape = (*lead, 6, 5)  # [..., n_patches, k]; with N = 4 atoms repeats are certain
    code = SparseCode(
        torch.randint(0, 4, shape, generator=g), torch.randn(shape, generator=g, dtype=F64)
    )
    assert any(len(set(row.tolist())) < 5 for row in code.indices.reshape(-1, 5))
    f = pooled_activity(code, 4)
    assert f.shape == (*lead, 4)
    expected = _pooled_loop(code, 4)
    _close(f, expected, atol=1e-12)
    _close(pooled_activity(code, 4, reduction="mean"), expected / 6, atol=1e-12)
    # squaring the slots separately would be wrong whenever an atom repeats with mixed signs
    naive = torch.zeros_like(f).reshape(-1, 4)
    flat_codes = zip(code.indices.reshape(-1, 30), code.coefficients.reshape(-1, 30))
    for b, (ii, cc) in enumerate(flat_codes):
        naive[b].index_add_(0, ii, cc**2)
    assert not torch.allclose(f.reshape(-1, 4), naive)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_pooled_activity_of_dictionary_codes(algorithm):
    d = SparseDictionary(30, 20, 6, algorithm, generator=_gen(18), dtype=F64)
    out = d(_randn(2, 7, 20, seed=19))
    f = d.pooled_activity(out.code)
    assert f.shape == (2, 30)
    _close(f, _pooled_loop(out.code, 30), atol=1e-12)
    _close(d.pooled_activity(out.code, reduction="mean"), f / 7, atol=1e-12)
    assert (f >= 0).all()


def test_pooled_activity_validation():
    code = SparseCode(torch.zeros(3, 2, dtype=torch.long), torch.ones(3, 2))
    with pytest.raises(ValueError, match="reduction"):
        pooled_activity(code, 4, reduction="max")
    with pytest.raises(ValueError, match="code"):
        pooled_activity(SparseCode(torch.zeros(2, dtype=torch.long), torch.ones(2)), 4)


# ---------------------------------------------------------------------------------------------
# Property: eq. (4) bounds

_PROPERTY_DICT = {
    a: SparseDictionary(24, 12, 4, a, generator=_gen(20), dtype=F64) for a in ALGORITHMS
}


@settings(max_examples=20, deadline=None)
@given(
    x=hnp.arrays(np.float64, (5, 12), elements=st.floats(-1e3, 1e3)),
    algorithm=st.sampled_from(ALGORITHMS),
)
def test_error_bounds(x, algorithm):
    d = _PROPERTY_DICT[algorithm]
    with torch.no_grad():
        error = d(torch.from_numpy(x)).error
    assert torch.isfinite(error).all()
    assert (error >= 0).all()
    if algorithm == "omp":  # a least-squares fit never makes the residual exceed the signal
        assert (error <= 1 + 1e-12).all(), error
    else:  # MP removes the residual's projection on one unit atom per step
        assert (error <= 1 + 1e-9).all(), error


def test_mirror_pairs_survive_learning_and_code_mirrored_signals_with_the_partners():
    from aectorch.coding import patch_permutation

    mirror = patch_permutation(10)
    d = SparseDictionary(32, 200, 4, "mp", mirror=mirror, generator=torch.Generator().manual_seed(0), dtype=F64)
    partner = d.partner
    assert torch.equal(partner[partner], torch.arange(32))
    torch.testing.assert_close(d.atoms[mirror][:, partner], d.atoms, rtol=0, atol=1e-15)
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):  # learning from signals that are not mirror-symmetric keeps the pairs
        x = torch.randn(7, 200, generator=gen, dtype=F64)
        d.learn_(x, d(x), lr=0.3)
        torch.testing.assert_close(d.atoms[mirror][:, partner], d.atoms, rtol=0, atol=1e-15)
        torch.testing.assert_close(d.atoms.norm(dim=0), torch.ones(32, dtype=F64))
    code, mirrored = d.encode(x), d.encode(x[:, mirror])
    assert torch.equal(partner[code.indices], mirrored.indices)
    torch.testing.assert_close(mirrored.coefficients, code.coefficients)
    torch.testing.assert_close(d.pooled_activity(mirrored)[..., :], d.pooled_activity(code)[..., partner])
    # Without a mirror nothing is paired.
    plain = SparseDictionary(32, 200, 4, generator=torch.Generator().manual_seed(0), dtype=F64)
    assert plain.partner is None
    assert not torch.allclose(plain.atoms[mirror][:, torch.arange(32).roll(16)], plain.atoms)


def test_mirror_is_validated():
    from aectorch.coding import patch_permutation

    with pytest.raises(ValueError, match="even"):
        SparseDictionary(31, 200, 4, mirror=patch_permutation(10))
    with pytest.raises(ValueError, match="permutation of range"):
        SparseDictionary(32, 100, 4, mirror=patch_permutation(10))
    with pytest.raises(ValueError, match="involution"):
        SparseDictionary(32, 4, 2, mirror=torch.tensor([1, 2, 3, 0]))
    with pytest.raises(TypeError, match="integer tensor"):
        SparseDictionary(32, 4, 2, mirror=[1, 0, 3, 2])
