"""The fused CPU pursuit kernel (aectorch.coding.native): built, used, and replaceable.

Its results are tested against scikit-learn and the MP reference with every test of
tests/test_pursuit.py, which runs on both backends."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from aectorch.coding import matching_pursuit, native, omp, use_backend


def test_native_kernel_is_built_and_used():
    # CI and `make test` must exercise the kernel, not silently fall back to torch.
    assert native.available(), "the fused CPU pursuit kernel did not build (see the warning)"
    d = torch.nn.functional.normalize(torch.randn(30, 60, dtype=torch.float64), dim=0)
    x = torch.randn(5, 30, dtype=torch.float64)
    a = omp(x, d, 4, backend="native")
    b = omp(x, d, 4, backend="torch")
    assert torch.equal(a.indices, b.indices)
    torch.testing.assert_close(a.coefficients, b.coefficients, rtol=0, atol=1e-12)


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
from aectorch.coding import native, omp
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    d = torch.nn.functional.normalize(torch.randn(30, 60), dim=0)
    code = omp(torch.randn(5, 30), d, 4)
print(native.available(), code.indices.shape[-1], "|".join(str(w.message) for w in caught))
"""


@pytest.mark.parametrize("how", ["disabled", "no compiler"])
def test_without_the_kernel_the_pursuits_fall_back_to_torch(tmp_path, how):
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
