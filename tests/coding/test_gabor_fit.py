"""The lineage's binocularity measure: `fit_gabor` against scipy's least squares as the oracle, and
`gabor_binocularity` beside our `binocularity_index`."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import least_squares

from aectorch.coding.readouts import GABOR_PARAMETERS, binocularity_index, fit_gabor, gabor_binocularity

P = 10
#: amplitude, x0, y0, theta, frequency, phase, sigma_x, sigma_y (the canonical ranges of GaborFit)
TRUE = np.array([
    [1.0, 0.0, 0.0, 0.3, 0.20, 0.0, 2.0, 2.0],
    [0.7, 0.8, -0.5, 0.6, 0.15, 1.2, 1.8, 2.6],
    [1.5, -1.0, 0.7, 2.2, 0.25, -2.0, 1.5, 1.2],
    [0.5, 0.3, 1.1, 1.3, 0.12, 2.8, 2.2, 1.6],
    [1.2, -0.4, -0.9, 2.9, 0.30, -0.7, 1.3, 2.0],
])


def _gabor_np(q: np.ndarray) -> np.ndarray:
    """The Gabor of `fit_gabor`'s model written afresh in numpy (sigmas, not their logs), mean removed."""
    a, x0, y0, theta, f, phase, sx, sy = q
    c = np.arange(P) - (P - 1) / 2
    x, y = np.meshgrid(c, c)  # x along columns, y along rows
    u = (x - x0) * np.cos(theta) + (y - y0) * np.sin(theta)
    v = -(x - x0) * np.sin(theta) + (y - y0) * np.cos(theta)
    g = a * np.exp(-u ** 2 / (2 * sx ** 2) - v ** 2 / (2 * sy ** 2)) * np.cos(2 * np.pi * f * u + phase)
    return g - g.mean()


def _noisy(noise: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([_gabor_np(q) + noise * rng.standard_normal((P, P)) for q in TRUE])


def test_parameters_are_recovered_from_noisy_gabors():
    fit = fit_gabor(torch.tensor(_noisy(0.02)))
    got = fit.parameters.numpy()
    assert GABOR_PARAMETERS[3] == "theta" and got.shape == TRUE.shape
    np.testing.assert_allclose(got[:, [1, 2]], TRUE[:, [1, 2]], atol=0.15)        # centre, px
    np.testing.assert_allclose(got[:, 3], TRUE[:, 3], atol=0.05)                   # orientation, rad
    np.testing.assert_allclose(got[:, 4], TRUE[:, 4], atol=0.01)                   # cycles / px
    np.testing.assert_allclose(np.cos(got[:, 5] - TRUE[:, 5]), 1.0, atol=0.02)     # phase
    np.testing.assert_allclose(got[:, [0, 6, 7]], TRUE[:, [0, 6, 7]], rtol=0.1)    # amplitude, sigmas
    assert (fit.residual < 0.05).all()


def test_the_fit_and_residual_match_scipys_least_squares():
    images = _noisy(0.05, seed=1)
    fit = fit_gabor(torch.tensor(images))
    for image, truth, ours, residual in zip(images, TRUE, fit.parameters.numpy(), fit.residual.numpy()):
        from_truth = least_squares(lambda q: (_gabor_np(q) - image).ravel(), truth, method="lm")
        assert residual == pytest.approx(np.sum(from_truth.fun ** 2) / np.sum(image ** 2), rel=1e-4)
        oracle = least_squares(lambda q: (_gabor_np(q) - image).ravel(), ours, method="lm")
        scipy_residual = np.sum(oracle.fun ** 2) / np.sum(image ** 2)
        assert residual == pytest.approx(scipy_residual, rel=1e-4)  # scipy, started at ours, finds no better
        np.testing.assert_allclose(_gabor_np(oracle.x), _gabor_np(ours), atol=1e-4)
    np.testing.assert_allclose(fit.fitted.numpy(), np.stack([_gabor_np(q) for q in fit.parameters.numpy()]),
                               atol=1e-10)


def _atoms(*pairs) -> torch.Tensor:
    return torch.stack([torch.cat([torch.tensor(left).flatten(), torch.tensor(right).flatten()])
                        for left, right in pairs], dim=1)


def test_monocular_binocular_and_scaled_atoms_as_our_index():
    g, h = _gabor_np(TRUE[1]), _gabor_np(TRUE[2])
    atoms = _atoms((g, 0 * g), (0 * h, h), (g, g), (h, 3 * h), (3 * g, g))
    result = gabor_binocularity(atoms)
    expected = torch.tensor([-1.0, 1.0, 0.0, 0.5, -0.5], dtype=torch.float64)
    torch.testing.assert_close(result.binocularity, expected, atol=1e-6, rtol=0)
    torch.testing.assert_close(binocularity_index(atoms), expected, atol=1e-12, rtol=0)
    assert result.valid.all() and (result.residual < 1e-6).all()


def test_noise_atoms_are_dropped_and_an_empty_atom_is_not_valid():
    atoms = torch.randn(2 * P * P, 40, generator=torch.Generator().manual_seed(0))
    atoms[:, 0] = 0.0
    result = gabor_binocularity(atoms)
    assert not result.valid.any()
    assert result.binocularity[0] == 0 and result.residual[0] == 1
    assert torch.isfinite(result.binocularity).all() and (result.binocularity.abs() <= 1).all()


def test_batched_atoms_keep_their_shape_and_dtype():
    g = _gabor_np(TRUE[3])
    atoms = _atoms((g, 0.5 * g), (g, -g)).float()
    result = gabor_binocularity(torch.stack([atoms, atoms.flip(-1)]))
    assert result.binocularity.shape == (2, 2) and result.binocularity.dtype == torch.float32
    torch.testing.assert_close(result.binocularity[0], torch.tensor([-1 / 3, 0.0]), atol=1e-4, rtol=0)
    assert result.valid.all()


def test_bad_images_are_refused():
    with pytest.raises(ValueError, match="images"):
        fit_gabor(torch.zeros(3, 4, 5))
    with pytest.raises(ValueError, match="steps"):
        fit_gabor(torch.zeros(3, 4, 4), steps=0)
    assert math.isclose(float(fit_gabor(torch.zeros(1, 4, 4)).residual[0]), 1.0)
