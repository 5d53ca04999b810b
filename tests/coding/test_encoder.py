"""Tests for aectorch.coding.encoder: BinocularEncoder and EncoderOutput (paper sec. 2.2-2.3).

Oracles: eqs. (3)-(6) recomputed by hand from `extract_patches`, the dictionaries' atoms and the
coders, torch.optim.SGD for the learning step, and stereo pairs of 1/f textures with a known
disparity that the dictionaries must learn to code.
"""

from __future__ import annotations

import copy

import pytest
import torch
import torch.nn.functional as F

from aectorch.coding import (
    COARSE,
    FINE,
    BinocularEncoder,
    EncoderOutput,
    Scale,
    SparseDictionary,
    extract_patches,
    matching_pursuit,
    omp,
)

torch.set_num_threads(1)

F64 = torch.float64
CODERS = {"omp": omp, "mp": matching_pursuit}
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


#: The paper's coder (its two scales, eq. 3's sum pooling, a constant rate, the classic pyramid):
#: the setting of these hand-computed oracles; the defaults differ (`EncoderConfig`).
PAPER = dict(scales=(COARSE, FINE), pooling="sum", lr=0.05, decay=None, centred=False)


def paper_encoder(**options) -> BinocularEncoder:
    return BinocularEncoder(**{**PAPER, **options})


def _images(b: int, seed: int, dtype=torch.float32):
    g = _gen(seed)
    return (
        torch.rand(b, 240, 320, generator=g, dtype=dtype),
        torch.rand(b, 240, 320, generator=g, dtype=dtype),
    )


def _close(actual: torch.Tensor, expected: torch.Tensor, atol: float) -> None:
    """Same shape and dtype and max |actual - expected| <= atol.

    (torch.testing.assert_close's first call costs ~2 s of imports.)
    """
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    assert actual.dtype == expected.dtype, (actual.dtype, expected.dtype)
    diff = (actual.detach().cpu() - expected.detach().cpu()).abs().max().item()
    assert diff <= atol, f"max abs difference {diff:.3g} > {atol:.3g}"


@pytest.fixture(scope="module")
def encoded():
    enc = paper_encoder(generator=_gen(0))
    first, second = _images(3, seed=1)
    with torch.no_grad():
        out = enc(first, second)
    return enc, first, second, out


# ---------------------------------------------------------------------------------------------
# Structure and shapes


def test_output_shapes(encoded):
    enc, _, _, out = encoded
    assert isinstance(out, EncoderOutput)
    assert out.features.shape == (3, 576)
    assert out.reward.shape == (3,)
    assert out.errors.shape == (3, 2)
    assert [tuple(p.shape) for p in out.patches] == [(3, 49, 200), (3, 64, 200)]
    assert [tuple(c.error.shape) for c in out.codes] == [(3, 49), (3, 64)]
    assert [tuple(c.code.indices.shape) for c in out.codes] == [(3, 49, 10), (3, 64, 10)]
    assert enc.num_features == 576
    assert torch.isfinite(out.features).all() and torch.isfinite(out.reward).all()
    assert (out.features >= 0).all()
    assert (out.errors > 0).all() and (out.errors < 1).all()


def test_scale_dictionaries(encoded):
    enc = encoded[0]
    assert isinstance(enc.coarse, SparseDictionary) and isinstance(enc.fine, SparseDictionary)
    assert enc.coarse is enc.dictionaries["coarse"] and enc.fine is enc.dictionaries["fine"]
    assert enc.coarse is not enc.fine
    for d in (enc.coarse, enc.fine):
        assert (d.dim, d.num_atoms, d.sparsity, d.algorithm) == (200, 288, 10, "mp")
    assert enc.scales == (COARSE, FINE)
    # both dictionaries are registered parameters, and they differ
    assert len(list(enc.parameters())) == 2
    assert not torch.allclose(enc.coarse.atoms, enc.fine.atoms)
    with pytest.raises(AttributeError):
        enc.medium


def test_same_seed_same_encoder():
    a = paper_encoder(generator=_gen(3))
    b = paper_encoder(generator=_gen(3))
    assert torch.equal(a.coarse.atoms, b.coarse.atoms) and torch.equal(a.fine.atoms, b.fine.atoms)


# ---------------------------------------------------------------------------------------------
# Eqs. (3)-(6) by hand


@pytest.mark.parametrize("algorithm", ["mp", "omp"])
def test_reward_errors_features_by_hand(algorithm):
    enc = paper_encoder(algorithm=algorithm, generator=_gen(4), dtype=F64)
    first, second = _images(3, seed=5, dtype=F64)
    with torch.no_grad():
        out = enc(first, second)
    errors, features = [], []
    for j, (scale, dictionary) in enumerate(((COARSE, enc.coarse), (FINE, enc.fine))):
        x = extract_patches(first, second, scale)
        _close(out.patches[j], x, atol=0.0)
        atoms = dictionary.atoms.detach()
        code = CODERS[algorithm](x, atoms, 10)
        assert torch.equal(out.codes[j].code.indices, code.indices)
        # a[b, i, n]: the dense code, repeated atoms summed (one-hot, not scatter)
        dense = (F.one_hot(code.indices, 288).to(F64) * code.coefficients[..., None]).sum(-2)
        recon = dense @ atoms.t()  # eq. (1)
        per_patch = ((x - recon) ** 2).sum(-1) / (x**2).sum(-1)  # eq. (4) summand
        _close(out.codes[j].error, per_patch, atol=1e-10)
        errors.append(per_patch.mean(-1))  # eq. (4)
        features.append((dense**2).sum(-2))  # eq. (3)
    errors = torch.stack(errors, -1)
    _close(out.errors, errors, atol=1e-10)
    _close(out.reward, -(errors[:, 0] + errors[:, 1]), atol=1e-10)  # eq. (6)
    _close(out.reward, -out.errors.sum(-1), atol=0.0)
    _close(out.features, torch.cat(features, -1), atol=1e-10)  # eq. (5): coarse first


def test_mean_pooling_divides_by_each_scales_patch_count():
    first, second = _images(2, seed=6)
    summed = paper_encoder(generator=_gen(7))
    meaned = paper_encoder(generator=_gen(7), pooling="mean")
    with torch.no_grad():
        fs, fm = summed(first, second).features, meaned(first, second).features
    _close(fm[:, :288], fs[:, :288] / 49, atol=1e-6)
    _close(fm[:, 288:], fs[:, 288:] / 64, atol=1e-6)


def test_batch_equals_one_pair_at_a_time(encoded):
    enc, first, second, out = encoded
    with torch.no_grad():
        for b in range(3):
            one = enc(first[b : b + 1], second[b : b + 1])
            scale = float(out.features.abs().max())
            _close(one.features, out.features[b : b + 1], atol=1e-5 * scale)
            _close(one.reward, out.reward[b : b + 1], atol=1e-5)
            _close(one.errors, out.errors[b : b + 1], atol=1e-5)


def test_single_scale_encoder():
    enc = paper_encoder(num_atoms=50, sparsity=4, scales=("fine",), generator=_gen(8))
    first, second = _images(2, seed=9)
    with torch.no_grad():
        out = enc(first, second)
    assert enc.num_features == 50
    assert out.features.shape == (2, 50) and out.errors.shape == (2, 1)
    _close(out.reward, -out.errors[:, 0], atol=0.0)


# ---------------------------------------------------------------------------------------------
# Learning


@pytest.mark.parametrize("algorithm", ["mp", "omp"])
def test_learn_equals_backward_sgd_renormalize(algorithm):
    lr = 0.3
    enc1 = paper_encoder(algorithm=algorithm, generator=_gen(10), dtype=F64, lr=0.01)
    enc2 = copy.deepcopy(enc1)
    before = [d.atoms.detach().clone() for d in enc1.dictionaries.values()]
    first, second = _images(2, seed=11, dtype=F64)

    assert enc1.learn_(enc1(first, second), lr=lr) is enc1

    opt = torch.optim.SGD(enc2.parameters(), lr=lr)
    opt.zero_grad()
    (-enc2(first, second).reward.mean()).backward()
    opt.step()
    for d in enc2.dictionaries.values():
        d.renormalize_()

    for d1, d2, b in zip(enc1.dictionaries.values(), enc2.dictionaries.values(), before):
        _close(d1.atoms, d2.atoms, atol=1e-10)
        assert (d1.atoms.detach() - b).abs().max() > 1e-5  # the step moved the atoms (~1.7e-4)
        _close(d1.atoms.detach().norm(dim=0), torch.ones(288, dtype=F64), atol=1e-12)


def test_learn_default_lr_is_the_configured_one():
    first, second = _images(1, seed=12, dtype=F64)
    enc1 = paper_encoder(generator=_gen(13), dtype=F64, lr=0.2)
    enc2 = copy.deepcopy(enc1)
    enc1.learn_(enc1(first, second))
    enc2.learn_(enc2(first, second), lr=0.2)
    for d1, d2 in zip(enc1.dictionaries.values(), enc2.dictionaries.values()):
        _close(d1.atoms, d2.atoms, atol=0.0)


def _textures(b: int, g: torch.Generator, h: int = 240, w: int = 320) -> torch.Tensor:
    """Periodic 1/f noise images scaled to [0, 1], float32 [b, h, w]."""
    fy = torch.fft.fftfreq(h, dtype=F64)[:, None]
    fx = torch.fft.rfftfreq(w, dtype=F64)[None, :]
    f = (fx**2 + fy**2).sqrt()
    amplitude = 1.0 / f.clamp_min(1.0 / max(h, w))
    amplitude[0, 0] = 0.0
    shape = (b, h, w // 2 + 1)
    real = torch.randn(shape, generator=g, dtype=F64)
    spectrum = torch.complex(real, torch.randn(shape, generator=g, dtype=F64))
    image = torch.fft.irfft2(spectrum * amplitude, s=(h, w))
    lo, hi = image.amin((-2, -1), keepdim=True), image.amax((-2, -1), keepdim=True)
    return ((image - lo) / (hi - lo)).float()


def _stereo(images: torch.Tensor, disparity: int):
    """Second image = the first shifted right by `disparity` px (the textures are periodic)."""
    return images, torch.roll(images, disparity, dims=-1)


def _mean_reward(enc, images, disparity):
    with torch.no_grad():
        return enc(*_stereo(images, disparity)).reward.mean().item()


# Measured (seeds below, 100 steps, B = 2, lr 0.5, MP): held-out reward at disparity 2 went from
# -1.424 to -0.692; disparity 0 vs 20 went from -1.422 vs -1.431 (gap 0.009) before training to
# -0.707 vs -1.044 (gap 0.337) after. About 4-5 s on one core.
def test_learning_improves_reward_and_prefers_small_disparity():
    pool = _textures(8, _gen(99))  # training textures, randomly re-centred every step
    held_out = _textures(4, _gen(123))
    enc = paper_encoder(lr=0.5, generator=_gen(1))
    initial = _mean_reward(enc, held_out, 2)
    initial_gap = _mean_reward(enc, held_out, 0) - _mean_reward(enc, held_out, 20)
    g = _gen(0)
    for _ in range(100):
        pick = torch.randint(0, 8, (2,), generator=g).tolist()
        dy = torch.randint(0, 240, (2,), generator=g).tolist()
        dx = torch.randint(0, 320, (2,), generator=g).tolist()
        moved = [torch.roll(pool[i], (y, x), (-2, -1)) for i, y, x in zip(pick, dy, dx)]
        batch = torch.stack(moved)
        with torch.no_grad():
            out = enc(*_stereo(batch, 2))
        enc.learn_(out)
    final = _mean_reward(enc, held_out, 2)
    zero, far = _mean_reward(enc, held_out, 0), _mean_reward(enc, held_out, 20)
    assert final > initial + 0.4, (initial, final)
    assert zero > far + 0.15, (zero, far)
    assert zero - far > initial_gap + 0.1, (initial_gap, zero - far)


# ---------------------------------------------------------------------------------------------
# Flat images, validation, dtypes and devices


@pytest.mark.parametrize("algorithm", ["mp", "omp"])
def test_flat_images_give_zero_features_and_reward(algorithm):
    enc = paper_encoder(algorithm=algorithm, generator=_gen(14))
    flat = torch.full((2, 240, 320), 0.5)
    out = enc(flat, flat.clone())
    assert torch.equal(out.features, torch.zeros(2, 576))
    assert torch.equal(out.reward, torch.zeros(2))
    assert torch.equal(out.errors, torch.zeros(2, 2))
    (-out.reward.mean()).backward()
    for d in enc.dictionaries.values():
        assert torch.equal(d.atoms.grad, torch.zeros_like(d.atoms))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(pooling="max"), "pooling"),
        (dict(lr=-0.1), "lr"),
        (dict(lr=float("nan")), "lr"),
        (dict(scales=()), "scales"),
        (dict(scales=(COARSE, COARSE)), "scales"),
        (dict(scales=(COARSE, Scale("coarse", crop=80, downsample=2, stride=4))), "scales"),
        (dict(scales=("coarse", "medium")), "scale"),
        (dict(sparsity=0), "sparsity"),
    ],
)
def test_validation_names_the_field(kwargs, name):
    with pytest.raises(ValueError, match=name):
        paper_encoder(**kwargs)


def test_integer_images_raise_type_error():
    enc = paper_encoder(num_atoms=20, sparsity=2, generator=_gen(15))
    image = torch.zeros(1, 240, 320, dtype=torch.uint8)
    with pytest.raises(TypeError, match="first"):
        enc(image, image)


def test_float64_encoder():
    enc = paper_encoder(generator=_gen(16), dtype=F64)
    assert enc.coarse.atoms.dtype == F64 and enc.fine.atoms.dtype == F64
    first, second = _images(2, seed=17, dtype=F64)
    with torch.no_grad():
        out = enc(first, second)
    assert out.features.dtype == F64 and out.reward.dtype == F64 and out.errors.dtype == F64
    assert all(p.dtype == F64 for p in out.patches)
    assert torch.isfinite(out.reward).all() and (out.reward < 0).all()
    with pytest.raises(TypeError, match="dtype"):
        enc(first.float(), second.float())  # float32 images against float64 atoms


@needs_cuda
def test_cuda_matches_cpu():
    cpu = paper_encoder(generator=_gen(18), dtype=F64)
    gpu = paper_encoder(generator=_gen(18), dtype=F64, device="cuda")
    assert gpu.coarse.atoms.device.type == "cuda"
    first, second = _images(2, seed=19, dtype=F64)
    out_cpu = cpu(first, second)
    out_gpu = gpu(first.cuda(), second.cuda())
    assert out_gpu.features.device.type == "cuda"
    _close(out_gpu.features, out_cpu.features, atol=1e-8)
    _close(out_gpu.reward, out_cpu.reward, atol=1e-10)
    cpu.learn_(out_cpu, lr=0.3)
    gpu.learn_(out_gpu, lr=0.3)
    _close(gpu.fine.atoms, cpu.fine.atoms, atol=1e-10)


@pytest.mark.parametrize("symmetry", ["mirror", "swap"])
def test_symmetric_encoders_give_the_transformed_pair_permuted_features(symmetry):
    # Scales without a pyramid reduction: the transformed images give exactly the transformed
    # patches, so the features of the transformed pair are the permuted features.
    from aectorch.coding import Scale

    scales = (Scale("a", crop=20, downsample=1, patch_size=5, stride=5),
              Scale("b", crop=10, downsample=1, patch_size=5, stride=1))
    enc = paper_encoder(num_atoms=16, sparsity=3, scales=scales, symmetry=symmetry, generator=torch.Generator().manual_seed(0),
                           dtype=torch.float64)
    first, second = torch.rand(2, 4, 24, 30, generator=torch.Generator().manual_seed(1), dtype=torch.float64).unbind(0)
    pair = (first.flip(-1), second.flip(-1)) if symmetry == "mirror" else (second, first)
    with torch.no_grad():
        f, ft = enc(first, second).features, enc(*pair).features
    perm = enc.feature_permutation
    assert perm.shape == (32,) and torch.equal(perm[perm], torch.arange(32))
    torch.testing.assert_close(ft, f[:, perm])
    assert not torch.allclose(ft, f)
    assert paper_encoder(num_atoms=16, sparsity=3, scales=scales).feature_permutation is None
    with pytest.raises(ValueError, match="symmetry must be one of"):
        paper_encoder(num_atoms=16, sparsity=3, scales=scales, symmetry="rotate")


def test_fovea_weights_the_reward_and_the_features_by_hand():
    """encoder.fovea_px: each patch's normalised error and squared coefficients count by a
    Gaussian of its centre's distance from the crop's centre (mean 1 per scale); the code (which
    atoms) and the dictionaries' learning are those of the uniform encoder."""
    from aectorch.coding import fovea_weights

    first, second = _images(3, seed=8, dtype=F64)
    plain = paper_encoder(generator=_gen(9), dtype=F64, centred=True)
    fovea = paper_encoder(generator=_gen(9), dtype=F64, centred=True, fovea_px=12.0)
    with torch.no_grad():
        a, b = plain(first, second), fovea(first, second)
    features = []
    for j, scale in enumerate(plain.scales):
        w = fovea_weights(scale, 12.0, dtype=F64)
        # The weights by hand: the centred fine grid's patch centres lie at -28, -20, ..., 28 px (8 x 8).
        if scale.name == "fine":
            c = torch.arange(-28.0, 29.0, 8.0, dtype=F64)
            by_hand = torch.exp(-(c[:, None] ** 2 + c[None, :] ** 2) / (2 * 12.0**2)).reshape(-1)
            _close(w, by_hand / by_hand.mean(), atol=1e-12)
        assert torch.equal(a.codes[j].code.indices, b.codes[j].code.indices)
        _close(b.errors[:, j], (a.codes[j].error * w).mean(-1), atol=1e-10)
        dense = (F.one_hot(a.codes[j].code.indices, 288).to(F64) * a.codes[j].code.coefficients[..., None]).sum(-2)
        features.append(((dense**2) * w[:, None]).sum(-2))
    _close(b.reward, -b.errors.sum(-1), atol=0.0)
    _close(b.features, torch.cat(features, -1), atol=1e-10)
    assert not torch.allclose(a.reward, b.reward)
    # A weighting so wide it is flat is the uniform encoder.
    wide = paper_encoder(generator=_gen(9), dtype=F64, centred=True, fovea_px=1e9)
    with torch.no_grad():
        _close(wide(first, second).reward, a.reward, atol=1e-12)
    with pytest.raises(ValueError, match="encoder.fovea_px must be null or a number of pixels > 0"):
        paper_encoder(generator=_gen(9), fovea_px=0)
