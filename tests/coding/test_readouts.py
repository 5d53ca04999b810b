"""The read-outs of a learned code (`aectorch.coding.readouts`) on constructed dictionaries."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.decomposition import PCA

from aectorch.coding import BinocularEncoder, patch_permutation
from aectorch.coding.readouts import (
    atom_halves,
    binocularity_histogram,
    binocularity_index,
    code_summary,
    disparity_histogram,
    disparity_tuning,
    orientation_histogram,
    orientation_preference,
    preferred_disparity,
    principal_components,
)

P = 10


def _atoms(*pairs) -> torch.Tensor:
    """A dictionary ``[2 p^2, N]`` of atoms given as (left, right) ``p x p`` halves."""
    return torch.stack([torch.cat([left.flatten(), right.flatten()]) for left, right in pairs], dim=1)


def _grating(orientation_deg: float, frequency: float, phase: float = 0.3, p: int = P,
             dtype=torch.float64) -> torch.Tensor:
    """A ``p x p`` grating whose stripes have ``orientation_deg`` (counter-clockwise from the
    rows as displayed, y up)."""
    y, x = torch.meshgrid(torch.arange(p, dtype=dtype), torch.arange(p, dtype=dtype), indexing="ij")
    wave = math.radians(orientation_deg - 90.0)  # the wave vector is normal to the stripes
    return torch.cos(2 * math.pi * frequency * (x * math.cos(wave) - y * math.sin(wave)) + phase)


def _noise(seed: int, shape=(P, P), dtype=torch.float64) -> torch.Tensor:
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


# ---------------------------------------------------------------------------------------------
# binocularity


def test_pure_left_pure_right_and_identical_halves_give_minus_one_plus_one_and_zero():
    half, zero = _noise(0), torch.zeros(P, P, dtype=torch.float64)
    atoms = _atoms((half, zero), (zero, half), (half, half), (half, -half), (half, 3 * half))
    index = binocularity_index(atoms)
    torch.testing.assert_close(index, torch.tensor([-1.0, 1.0, 0.0, 0.0, 0.5], dtype=torch.float64))


def test_the_index_ignores_each_halfs_mean_which_no_zero_mean_patch_can_excite():
    half, zero = _noise(1), torch.zeros(P, P, dtype=torch.float64)
    atoms = _atoms((half, zero + 5.0), (half + 2.0, 3 * half - 1.0))
    torch.testing.assert_close(binocularity_index(atoms), torch.tensor([-1.0, 0.5], dtype=torch.float64))
    assert atom_halves(atoms).mean((-2, -1)).abs().max() < 1e-12


def test_an_all_zero_atom_gets_index_zero_and_flat_tuning_not_nan():
    atoms = torch.zeros(2 * P * P, 2)
    assert binocularity_index(atoms).tolist() == [0.0, 0.0]
    tuning, _ = disparity_tuning(atoms)
    assert torch.equal(tuning, torch.ones_like(tuning))
    o = orientation_preference(atoms)
    assert not o.selectivity.isnan().any() and o.selectivity.tolist() == [0.0, 0.0]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), left_gain=st.just(0.0) | st.floats(1e-6, 4.0),
       right_gain=st.just(0.0) | st.floats(1e-6, 4.0))
def test_index_is_the_norm_contrast_bounded_and_antisymmetric_under_the_eye_swap(seed, left_gain, right_gain):
    left, right = _noise(seed), _noise(seed + 1)
    atoms = _atoms((left_gain * left, right_gain * right))
    index = binocularity_index(atoms)
    nl = left_gain * np.linalg.norm(left.numpy() - left.numpy().mean())
    nr = right_gain * np.linalg.norm(right.numpy() - right.numpy().mean())
    expected = 0.0 if nl + nr == 0 else (nr - nl) / (nr + nl)
    assert index.item() == pytest.approx(expected, abs=1e-12)
    assert -1.0 <= index.item() <= 1.0
    swapped = atoms[patch_permutation(P, flip=False, swap=True)]
    assert binocularity_index(swapped).item() == pytest.approx(-index.item(), abs=1e-12)


def test_binocularity_histogram_matches_numpy_and_counts_every_atom():
    index = torch.rand(3, 500, generator=torch.Generator().manual_seed(2)) * 2 - 1
    index[0, :3] = torch.tensor([-1.0, 1.0, 0.0])
    counts, edges = binocularity_histogram(index, bins=7)
    assert counts.shape == (3, 7) and counts.dtype == torch.int64
    for row in range(3):
        expected, np_edges = np.histogram(index[row].numpy(), bins=7, range=(-1, 1))
        assert counts[row].tolist() == expected.tolist()
    np.testing.assert_allclose(edges.numpy(), np_edges, atol=1e-6)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="P = 2 \\* patch_size"):
        binocularity_index(torch.zeros(7, 3))
    with pytest.raises(TypeError, match="floating point"):
        binocularity_index(torch.zeros(8, 3, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"\[\.\.\., P, N\]"):
        binocularity_index(torch.zeros(8))
    with pytest.raises(ValueError, match="max_disparity"):
        disparity_tuning(torch.zeros(200, 3), max_disparity=10)
    with pytest.raises(ValueError, match="bins"):
        binocularity_histogram(torch.zeros(3), bins=0)
    with pytest.raises(ValueError, match="frequencies"):
        orientation_preference(torch.zeros(200, 3), frequencies=(0.1, 0.7))
    with pytest.raises(ValueError, match="orientations"):
        orientation_preference(torch.zeros(200, 3), orientations=0)
    with pytest.raises(ValueError, match="one dictionary"):
        code_summary(torch.zeros(2, 200, 3))


# ---------------------------------------------------------------------------------------------
# disparity


@pytest.mark.parametrize("disparity", [-4, -1, 0, 2, 3])
def test_a_horizontally_shifted_pair_peaks_at_its_disparity(disparity):
    # A texture wider than the patch, seen by the right half `disparity` px further right.
    texture = _noise(3, (P, P + 12))
    left = texture[:, 6:6 + P]
    right = texture[:, 6 - disparity:6 - disparity + P]
    atoms = _atoms((left, right), (right, left))
    tuning, disparities = disparity_tuning(atoms, max_disparity=5)
    preference = preferred_disparity(tuning, disparities)
    assert preference.disparity.tolist() == [disparity, -disparity]  # the eye swap negates it
    # the curve's peak: 1 + the overlap's share of the energy (a random pair of halves: about 1.14)
    assert (tuning.amax(-1) > 1.5).all() and (preference.modulation > 0.25).all()


def test_tuning_is_the_halves_cross_correlation_as_numpy_computes_it():
    left, right = _noise(4), _noise(5)
    tuning, disparities = disparity_tuning(_atoms((left, right)))
    lc, rc = left.numpy() - left.numpy().mean(), right.numpy() - right.numpy().mean()
    # np.correlate(a, v, "full")[k] = sum_n a[n + k - (p - 1)] v[n]: with a = R's row, v = L's row
    # that is sum_x L[x] R[x + d] at d = k - (p - 1).
    cross = sum(np.correlate(rc[y], lc[y], "full") for y in range(P))
    expected = 1 + 2 * cross / ((lc**2).sum() + (rc**2).sum())
    assert disparities.tolist() == list(range(-(P - 1), P))
    np.testing.assert_allclose(tuning[0].numpy(), expected, rtol=1e-12)


def test_tuning_is_the_mean_squared_response_to_white_noise_stereograms():
    left, right = _noise(6), _noise(7)
    atoms = _atoms((left, right))
    tuning, disparities = disparity_tuning(atoms, max_disparity=3)
    halves = atom_halves(atoms)[0]
    generator = torch.Generator().manual_seed(8)
    noise = torch.randn(40000, P, P + 6, generator=generator, dtype=torch.float64)
    energy = (halves[0].square().sum() + halves[1].square().sum())
    for column, d in enumerate(disparities.tolist()):
        # the right half sees s[y, x - d]: the texture shifted d px to the right
        shown_left = noise[:, :, 3:3 + P]
        shown_right = noise[:, :, 3 - d:3 - d + P]
        response = (shown_left * halves[0]).sum((-2, -1)) + (shown_right * halves[1]).sum((-2, -1))
        assert (response.square().mean() / energy).item() == pytest.approx(tuning[0, column].item(), abs=0.04)


def test_a_monocular_atom_has_a_flat_curve_and_prefers_zero():
    half, zero = _noise(9), torch.zeros(P, P, dtype=torch.float64)
    tuning, disparities = disparity_tuning(_atoms((half, zero), (zero, half)))
    preference = preferred_disparity(tuning, disparities)
    assert torch.equal(tuning, torch.ones_like(tuning))
    assert preference.disparity.tolist() == [0, 0] and preference.modulation.tolist() == [0.0, 0.0]


def test_disparity_histogram_counts_and_clamps():
    counts, disparities = disparity_histogram(torch.tensor([[0, 0, 1, -9], [3, 3, 3, 3]]), 2)
    assert disparities.tolist() == [-2, -1, 0, 1, 2]
    assert counts.tolist() == [[1, 0, 2, 1, 0], [0, 0, 0, 0, 4]]


# ---------------------------------------------------------------------------------------------
# orientation


@pytest.mark.parametrize("frequency", [0.15, 0.25, 0.35])
def test_a_grating_atom_gives_its_orientation(frequency):
    orientations = torch.arange(0.0, 180.0, 7.5, dtype=torch.float64) + 1.1  # between the bank's 2.5 deg
    atoms = _atoms(*[(_grating(o, frequency), _grating(o, frequency)) for o in orientations.tolist()])
    preference = orientation_preference(atoms)
    error = torch.remainder(preference.orientation_deg - orientations + 90.0, 180.0) - 90.0
    assert error.abs().max() < 3.0
    assert (preference.frequency - frequency).abs().max() < 0.03
    assert (preference.selectivity > 0.6).all()


def test_stripes_along_the_columns_are_vertical_and_rising_to_the_right_is_45_degrees():
    y, x = torch.meshgrid(torch.arange(float(P)), torch.arange(float(P)), indexing="ij")
    vertical = torch.cos(2 * math.pi * 0.25 * x)
    horizontal = torch.cos(2 * math.pi * 0.25 * y)
    rising = torch.cos(2 * math.pi * 0.2 * (x + y) / math.sqrt(2))  # constant along x = -y: up-right
    zero = torch.zeros(P, P)
    atoms = _atoms((vertical, zero), (zero, horizontal), (rising, rising))
    orientation = orientation_preference(atoms).orientation_deg
    assert orientation[:2].tolist() == [90.0, 0.0]
    assert orientation[2].item() == pytest.approx(45.0, abs=3.0)


def test_a_monocular_grating_has_the_orientation_of_its_half_and_noise_is_unselective():
    atoms = _atoms((_grating(30.0, 0.25), torch.zeros(P, P, dtype=torch.float64)))
    assert orientation_preference(atoms).orientation_deg.item() == pytest.approx(30.0, abs=4.0)
    noise = torch.randn(200, 500, generator=torch.Generator().manual_seed(10), dtype=torch.float64)
    assert orientation_preference(noise).selectivity.mean() < 0.35


def test_orientation_histogram_wraps_at_180_degrees():
    counts, centres = orientation_histogram(torch.tensor([0.0, 11.0, 11.25, 170.0, 179.9, 90.0, 360.0 + 45.0]))
    assert centres.tolist() == [0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5]
    assert counts.tolist() == [4, 1, 1, 0, 1, 0, 0, 0]


# ---------------------------------------------------------------------------------------------
# batching, dtype, device, the summary


def test_leading_dimensions_are_batched_and_dtype_follows_the_input():
    atoms = torch.randn(3, 2 * P * P, 16, generator=torch.Generator().manual_seed(11))
    index = binocularity_index(atoms)
    tuning, _ = disparity_tuning(atoms, 4)
    orientation = orientation_preference(atoms)
    assert index.shape == (3, 16) and index.dtype == torch.float32
    assert tuning.shape == (3, 16, 9) and orientation.orientation_deg.dtype == torch.float32
    for b in range(3):
        torch.testing.assert_close(index[b], binocularity_index(atoms[b]))
        torch.testing.assert_close(tuning[b], disparity_tuning(atoms[b], 4)[0])
        torch.testing.assert_close(orientation.orientation_deg[b], orientation_preference(atoms[b]).orientation_deg)


def test_summary_of_an_encoder_with_the_swap_symmetry_is_json_and_symmetric():
    encoder = BinocularEncoder(scales=("wide", "coarse"), symmetry="swap", num_atoms=32,
                               generator=torch.Generator().manual_seed(12))
    for name, dictionary in encoder.dictionaries.items():
        summary = json.loads(json.dumps(code_summary(dictionary.atoms)))
        p = 6 if name == "wide" else 10
        assert summary["atoms"] == 32 and summary["patch_size"] == p
        b, d = summary["binocularity"], summary["disparity"]
        assert sum(b["counts"]) == sum(d["counts"]) == sum(summary["orientation"]["counts"]) == 32
        # the eye swap pairs every atom with its mirror image in binocularity and disparity
        assert b["counts"] == b["counts"][::-1] and d["counts"] == d["counts"][::-1]
        assert d["disparities_px"] == list(range(-(p - 1), p))
        assert 0.0 <= b["mean_abs_index"] <= 1.0


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
def test_cuda_matches_cpu():
    atoms = torch.randn(200, 64, generator=torch.Generator().manual_seed(13))
    gpu = atoms.cuda()
    torch.testing.assert_close(binocularity_index(gpu).cpu(), binocularity_index(atoms))
    torch.testing.assert_close(disparity_tuning(gpu)[0].cpu(), disparity_tuning(atoms)[0])
    torch.testing.assert_close(orientation_preference(gpu).selectivity.cpu(), orientation_preference(atoms).selectivity)


# ---------------------------------------------------------------------------------------------
# principal_components (the axes of Fig. 2)


def canonical_signs(scores, components):
    """Flip sklearn's axes with the module's convention: largest-|loading| component positive."""
    idx = np.abs(components).argmax(axis=1)
    signs = np.sign(components[np.arange(len(idx)), idx])
    return scores * signs


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_principal_components_matches_sklearn(dtype):
    gen = torch.Generator().manual_seed(1)
    atoms = torch.randn(30, 50, generator=gen, dtype=torch.float64) * torch.linspace(0.2, 3, 30, dtype=torch.float64)[:, None]
    atoms = atoms.to(dtype)
    scores, ratio = principal_components(atoms, k=2)
    assert scores.shape == (50, 2) and ratio.shape == (2,)
    assert scores.dtype == dtype and ratio.dtype == dtype
    pca = PCA(n_components=2, svd_solver="full").fit(atoms.double().numpy().T)
    expected = canonical_signs(pca.transform(atoms.double().numpy().T), pca.components_)
    tol = 1e-4 if dtype == torch.float32 else 1e-10
    np.testing.assert_allclose(scores.double().numpy(), expected, atol=tol * 10, rtol=tol)
    np.testing.assert_allclose(ratio.double().numpy(), pca.explained_variance_ratio_, rtol=tol)


def test_principal_components_sign_convention_is_deterministic():
    gen = torch.Generator().manual_seed(2)
    atoms = torch.randn(10, 25, generator=gen, dtype=torch.float64)
    scores, _ = principal_components(atoms, k=3)
    # a sign flip of the data flips the scores but the convention fixes the axes: scores of -atoms
    # are the negated scores (each axis's loadings keep their orientation)
    flipped, _ = principal_components(-atoms, k=3)
    np.testing.assert_allclose(flipped.numpy(), -scores.numpy(), atol=1e-10)
    # the largest |loading| of each axis is positive: projections of the centred atoms reproduce it
    centred = atoms.T - atoms.T.mean(0)
    loadings = torch.linalg.lstsq(centred, scores).solution  # [P, k], centred @ loadings = scores
    top = loadings.abs().argmax(0)
    assert bool((loadings[top, torch.arange(3)] > 0).all())


def test_principal_components_recovers_two_dimensional_structure():
    gen = torch.Generator().manual_seed(3)
    basis = torch.linalg.qr(torch.randn(40, 2, generator=gen, dtype=torch.float64)).Q  # [P, 2] orthonormal
    latent = torch.randn(2, 60, generator=gen, dtype=torch.float64) * torch.tensor([[5.0], [2.0]])
    latent = latent - latent.mean(1, keepdim=True)
    atoms = basis @ latent + 0.7  # a 2-D plane (offset by a constant atom)
    scores, ratio = principal_components(atoms, k=2)
    assert float(ratio.sum()) == pytest.approx(1.0, abs=1e-12)
    # the scores are the latent coordinates up to a rotation: same Gram matrix
    np.testing.assert_allclose((scores @ scores.T).numpy(), (latent.T @ latent).numpy(), atol=1e-9)
    # axes ordered by variance
    assert float(scores[:, 0].var()) > float(scores[:, 1].var())


def test_principal_components_constant_atoms_and_bad_input():
    scores, ratio = principal_components(torch.ones(5, 4), k=2)
    assert bool((scores == 0).all()) and bool((ratio == 0).all())
    with pytest.raises(ValueError, match="atoms"):
        principal_components(torch.randn(5), k=1)
    with pytest.raises(ValueError, match="atoms"):
        principal_components(torch.ones(5, 4, dtype=torch.int64))
    with pytest.raises(ValueError, match="atoms"):
        principal_components(torch.tensor([[1.0, math.nan], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="k must"):
        principal_components(torch.randn(5, 4), k=5)
    with pytest.raises(ValueError, match="k must"):
        principal_components(torch.randn(5, 4), k=0)




def test_principal_components_keeps_its_public_path_in_figures():
    import aectorch.figures

    assert aectorch.figures.principal_components is principal_components
