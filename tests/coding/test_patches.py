"""Tests for aectorch.coding.patches: foveal two-scale binocular patch extraction."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from aectorch.coding import patches as patches_module
from aectorch.coding.patches import (
    COARSE,
    FINE,
    FovealPatches,
    WIDE,
    FULL,
    Scale,
    as_scale,
    extract_patches,
    pyramid_down,
)

SCALES = [COARSE, FINE, WIDE, FULL]
BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0


def _rand(*shape, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(*shape, generator=g, dtype=dtype)


# ---------------------------------------------------------------------------------------------
# Independent numpy/scipy oracles


def _scipy_pyramid(image: np.ndarray, levels: int) -> np.ndarray:
    """scipy.ndimage with mode="mirror" is reflect-101 (d c b | a b c d | c b a)."""
    for _ in range(levels):
        image = ndimage.correlate1d(image, BINOMIAL, axis=0, mode="mirror")
        image = ndimage.correlate1d(image, BINOMIAL, axis=1, mode="mirror")
        image = image[::2, ::2]
    return image


def _numpy_extract(first: np.ndarray, second: np.ndarray, scale: Scale, eps=1e-8) -> np.ndarray:
    """Loop-by-loop float64 reference of extract_patches for one image pair [H, W]."""
    h, w = first.shape
    top, left = (h - scale.crop) // 2, (w - scale.crop) // 2
    levels = int(np.log2(scale.downsample))
    halves = []
    for image in (first, second):
        crop = image[top : top + scale.crop, left : left + scale.crop].astype(np.float64)
        small = _scipy_pyramid(crop, levels)
        p, s = scale.patch_size, scale.stride
        grid = (small.shape[0] - p) // s + 1
        cut = []
        for r in range(grid):
            for c in range(grid):
                v = small[r * s : r * s + p, c * s : c * s + p].reshape(-1).copy()
                v -= v.mean()
                n = np.linalg.norm(v)
                cut.append(v / n if n > eps else np.zeros_like(v))
        halves.append(np.stack(cut))
    return np.concatenate(halves, axis=1)


# ---------------------------------------------------------------------------------------------
# Scale


def test_scale_properties():
    assert (COARSE.crop, COARSE.downsample, COARSE.patch_size, COARSE.stride) == (128, 8, 10, 1)
    assert (COARSE.side, COARSE.levels, COARSE.grid, COARSE.num_patches, COARSE.dim) == (
        16, 3, 7, 49, 200,
    )
    assert (FINE.crop, FINE.downsample, FINE.patch_size, FINE.stride) == (80, 2, 10, 4)
    assert (FINE.side, FINE.levels, FINE.grid, FINE.num_patches, FINE.dim) == (40, 1, 8, 64, 200)
    odd = Scale("odd", crop=60, downsample=4, patch_size=5, stride=3)
    assert (odd.grid, odd.num_patches, odd.dim) == (4, 16, 50)  # 15 px: starts 0, 3, 6, 9


def test_as_scale():
    assert as_scale("coarse") is COARSE and as_scale("fine") is FINE and as_scale(FINE) is FINE
    assert as_scale("wide") is WIDE and (WIDE.grid, WIDE.num_patches, WIDE.dim) == (3, 9, 72)
    assert as_scale("full") is FULL and (FULL.levels, FULL.grid, FULL.num_patches, FULL.dim) == (0, 7, 49, 200)
    with pytest.raises(ValueError, match="scale must be"):
        as_scale("medium")
    with pytest.raises(TypeError, match="scale must be"):
        as_scale(8)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(crop=0, downsample=2, stride=1), "crop"),
        (dict(crop=64, downsample=2, stride=0), "stride"),
        (dict(crop=64, downsample=2, patch_size=-1, stride=1), "patch_size"),
        (dict(crop=64, downsample=2.0, stride=1), "downsample"),
        (dict(crop=96, downsample=6, stride=1), "power of two"),
        (dict(crop=100, downsample=8, stride=1), "divisible"),
        (dict(crop=64, downsample=8, patch_size=10, stride=1), "patch_size"),
        (dict(crop=8, downsample=8, patch_size=1, stride=1), "too small"),
    ],
)
def test_scale_validation(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Scale("bad", **kwargs)


def test_scale_is_frozen():
    with pytest.raises(AttributeError):
        COARSE.crop = 64  # type: ignore[misc]


# ---------------------------------------------------------------------------------------------
# Pyramid


@pytest.mark.parametrize("shape", [(64, 64), (37, 53), (50, 41), (128, 128)])
@pytest.mark.parametrize("levels", [1, 2, 3])
def test_pyramid_matches_scipy(shape, levels):
    images = _rand(2, *shape, seed=levels)
    got = pyramid_down(images, levels)
    for b in range(2):
        want = _scipy_pyramid(images[b].numpy(), levels)
        assert got[b].shape == want.shape
        np.testing.assert_allclose(got[b].numpy(), want, rtol=0, atol=1e-12)


def _scipy_centred_pyramid(image: np.ndarray, levels: int) -> np.ndarray:
    """The centred reduce: the 6-tap binomial, output i over pixels 2i - 2 .. 2i + 3 (scipy centres an
    even kernel of length 6 on tap 3, so output i is the full-resolution sample 2i + 1)."""
    taps = np.array([1, 5, 10, 10, 5, 1], dtype=np.float64) / 32
    for _ in range(levels):
        image = ndimage.correlate1d(image, taps, axis=0, mode="mirror")
        image = ndimage.correlate1d(image, taps, axis=1, mode="mirror")
        image = image[1::2, 1::2]
    return image


@pytest.mark.parametrize("levels", [1, 2, 4])
def test_centred_pyramid_matches_scipy_and_commutes_with_mirroring(levels):
    images = _rand(2, 64, 48, seed=levels)
    got = pyramid_down(images, levels, centred=True)
    for b in range(2):
        np.testing.assert_allclose(got[b].numpy(), _scipy_centred_pyramid(images[b].numpy(), levels), rtol=0, atol=1e-12)
    torch.testing.assert_close(pyramid_down(images.flip(-1), levels, centred=True), got.flip(-1), rtol=0, atol=1e-12)
    torch.testing.assert_close(pyramid_down(images.flip(-2), levels, centred=True), got.flip(-2), rtol=0, atol=1e-12)
    # the classic reduce keeps even samples: it does not commute with mirroring
    classic = pyramid_down(images, levels)
    assert (pyramid_down(images.flip(-1), levels) - classic.flip(-1)).abs().max() > 1e-3
    with pytest.raises(ValueError, match="even"):
        pyramid_down(_rand(1, 10, 10), 2, centred=True)  # 10 -> 5: odd at level 1


@pytest.mark.parametrize("name", ["wide", "coarse", "fine", "full"])
def test_centred_scales_give_the_mirrored_patches_of_mirrored_images(name):
    import dataclasses

    from aectorch.coding.patches import as_scale, patch_permutation

    scale = dataclasses.replace(as_scale(name), centred=True)
    assert scale.grid == as_scale(name).grid  # the same patches, placed in the middle
    assert scale.offset == (1 if name == "fine" else 0)
    first, second = _rand(2, 3, 128, 128, seed=5).unbind(0)
    x = extract_patches(first, second, scale)
    g = scale.grid
    y = extract_patches(first.flip(-1), second.flip(-1), scale).view(3, g, g, -1).flip(2).reshape(3, g * g, -1)
    torch.testing.assert_close(y, x[..., patch_permutation(scale.patch_size)], rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="centred"):
        Scale("odd", crop=40, downsample=2, stride=3, centred=True)  # 20 px, patches cover 10 + 3 + 3 + 3


def test_pyramid_levels_zero_and_constant():
    x = _rand(1, 9, 9)
    assert pyramid_down(x, 0) is x
    c = torch.full((1, 33, 20), 0.25, dtype=torch.float64)
    out = pyramid_down(c, 2)
    assert out.shape == (1, 9, 5)
    assert torch.equal(out, torch.full_like(out, 0.25))


def test_pyramid_validation():
    with pytest.raises(ValueError, match=r"images.*rank 3"):
        pyramid_down(torch.rand(8, 8), 1)
    with pytest.raises(TypeError, match=r"images.*floating-point"):
        pyramid_down(torch.zeros(1, 8, 8, dtype=torch.uint8), 1)
    with pytest.raises(ValueError, match="levels"):
        pyramid_down(torch.rand(1, 8, 8), -1)
    with pytest.raises(ValueError, match="too small"):
        pyramid_down(torch.rand(1, 8, 8), 3)  # 8 -> 4 -> 2: level 2 reads 2 px


# ---------------------------------------------------------------------------------------------
# Extraction


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
def test_shapes(scale):
    first, second = _rand(3, 240, 320, seed=1), _rand(3, 240, 320, seed=2)
    out = extract_patches(first, second, scale)
    assert out.shape == (3, scale.num_patches, scale.dim)
    assert out.shape == (3, {"coarse": 49, "fine": 64, "wide": 9, "full": 49}[scale.name], {"wide": 72}.get(scale.name, 200))
    assert extract_patches(first, second, scale.name).shape == out.shape


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
@pytest.mark.parametrize("size", [(240, 320), (241, 323), (128, 131)], ids=str)
def test_matches_numpy_oracle(scale, size):
    first, second = _rand(1, *size, seed=3), _rand(1, *size, seed=4)
    got = extract_patches(first, second, scale)[0].numpy()
    want = _numpy_extract(first[0].numpy(), second[0].numpy(), scale)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
def test_halves_normalised_and_ordered(scale):
    first, second = _rand(2, 240, 320, seed=5), _rand(2, 240, 320, seed=6)
    out = extract_patches(first, second, scale)
    h = scale.dim // 2
    halves = out.view(2, scale.num_patches, 2, h)
    torch.testing.assert_close(halves.mean(-1), torch.zeros(2, scale.num_patches, 2, dtype=out.dtype))
    torch.testing.assert_close(halves.norm(dim=-1), torch.ones(2, scale.num_patches, 2, dtype=out.dtype))
    torch.testing.assert_close(out.square().sum(-1), torch.full((2, scale.num_patches), 2.0, dtype=out.dtype))
    # The first half comes from `first`: swapping the images swaps the halves.
    swapped = extract_patches(second, first, scale)
    torch.testing.assert_close(swapped[..., :h], out[..., h:], rtol=0, atol=0)
    torch.testing.assert_close(swapped[..., h:], out[..., :h], rtol=0, atol=0)
    # ... and equals the half of a pair whose first image is `first` (second image irrelevant).
    other = extract_patches(first, _rand(2, 240, 320, seed=7), scale)
    torch.testing.assert_close(other[..., :h], out[..., :h], rtol=0, atol=0)
    assert not torch.allclose(other[..., h:], out[..., h:])


def test_crop_is_central():
    # Texture only in the central crop: the border content must not matter.
    first, second = _rand(1, 240, 320, seed=8), _rand(1, 240, 320, seed=9)
    moved = first.clone()
    moved[:, :50] = 0.0  # rows 0..49 lie outside the central 128 rows (56..183)
    moved[:, :, :90] = 1.0  # columns 0..89 lie outside the central 128 columns (96..223)
    torch.testing.assert_close(
        extract_patches(moved, second, COARSE), extract_patches(first, second, COARSE), rtol=0, atol=0
    )
    moved[:, 120, 160] += 0.5  # a pixel in the middle does matter
    assert not torch.allclose(extract_patches(moved, second, COARSE), extract_patches(first, second, COARSE))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
def test_flat_images_give_zeros(dtype, scale):
    values = torch.tensor([0.0, 0.3, 0.7, 1.0, 0.123456789, 2.0 / 3.0], dtype=dtype)
    flat = values.view(-1, 1, 1).expand(-1, 240, 320).contiguous()
    out = extract_patches(flat, flat, scale)
    assert not torch.isnan(out).any()
    assert torch.equal(out, torch.zeros_like(out))

    textured = _rand(6, 240, 320, seed=10, dtype=dtype)
    half, h = extract_patches(flat, textured, scale), scale.dim // 2
    assert not torch.isnan(half).any()
    assert torch.equal(half[..., :h], torch.zeros_like(half[..., :h]))
    torch.testing.assert_close(half[..., h:].norm(dim=-1), torch.ones(6, scale.num_patches, dtype=dtype))


def test_flat_region_gives_zero_patches_only_there():
    # Coarse reduced column j sits on source column 96 + 8 j and three blur levels reach
    # +-(2 + 4 + 8) = 14 px, so grid column k reads source columns 82 + 8 k .. 182 + 8 k.
    # Flat source columns 0..189: only grid column 0 is wholly flat.
    first = _rand(1, 240, 320, seed=11)
    first[:, :, :190] = 0.4
    out = extract_patches(first, first, COARSE).view(7, 7, 200)
    zero_cols = (out == 0).all(dim=-1).all(dim=0)
    assert zero_cols.tolist() == [True] + [False] * 6


def test_flat_half_has_finite_gradient():
    flat = torch.full((1, 240, 320), 0.3, requires_grad=True)
    textured = _rand(1, 240, 320, seed=12, dtype=torch.float32).requires_grad_(True)
    extract_patches(flat, textured, FINE).sum().backward()
    assert torch.isfinite(flat.grad).all() and torch.isfinite(textured.grad).all()


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
def test_batch_consistency(scale):
    first, second = _rand(3, 240, 320, seed=13), _rand(3, 240, 320, seed=14)
    batched = extract_patches(first, second, scale)
    for b in range(3):
        alone = extract_patches(first[b : b + 1], second[b : b + 1], scale)
        torch.testing.assert_close(batched[b : b + 1], alone, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_follows_input(dtype):
    first, second = _rand(2, 240, 320, seed=15, dtype=dtype), _rand(2, 240, 320, seed=16, dtype=dtype)
    for scale in SCALES:
        out = extract_patches(first, second, scale)
        assert out.dtype == dtype
        ref = extract_patches(first.double(), second.double(), scale)
        torch.testing.assert_close(out.double(), ref, rtol=0, atol=1e-5 if dtype == torch.float32 else 0)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("scale", SCALES, ids=lambda s: s.name)
def test_cuda_matches_cpu(scale, dtype):
    first, second = _rand(3, 240, 320, seed=17, dtype=dtype), _rand(3, 240, 320, seed=18, dtype=dtype)
    cpu = extract_patches(first, second, scale)
    gpu = extract_patches(first.cuda(), second.cuda(), scale)
    assert gpu.device.type == "cuda" and gpu.dtype == dtype
    atol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=atol)
    flat = torch.full((1, 240, 320), 0.3, dtype=dtype, device="cuda")
    assert torch.equal(extract_patches(flat, flat, scale), torch.zeros(1, scale.num_patches, 200, dtype=dtype, device="cuda"))


def test_module_wrapper():
    first, second = _rand(2, 240, 320, seed=19), _rand(2, 240, 320, seed=20)
    module = FovealPatches("fine")
    assert module.scale is FINE and "num_patches=64" in repr(module)
    assert list(module.parameters()) == []
    torch.testing.assert_close(module(first, second), extract_patches(first, second, FINE), rtol=0, atol=0)


# ---------------------------------------------------------------------------------------------
# Validation


def test_validation_errors():
    good = torch.rand(1, 240, 320)
    with pytest.raises(ValueError, match=r"first must have shape \[B, H, W\].*\(240, 320\)"):
        extract_patches(torch.rand(240, 320), good, COARSE)
    with pytest.raises(ValueError, match=r"second must have shape .*\(1, 1, 240, 320\)"):
        extract_patches(good, torch.rand(1, 1, 240, 320), COARSE)
    with pytest.raises(ValueError, match=r"first and second must have the same shape.*\(2, 240, 320\)"):
        extract_patches(good, torch.rand(2, 240, 320), COARSE)
    with pytest.raises(ValueError, match=r"first and second of shape \(1, 100, 320\).*128x128"):
        small = torch.rand(1, 100, 320)
        extract_patches(small, small, COARSE)
    small = torch.rand(1, 100, 100)
    assert extract_patches(small, small, FINE).shape == (1, 64, 200)  # 100 >= 80 is enough
    with pytest.raises(TypeError, match=r"first has dtype torch.uint8: expected a floating-point image in \[0, 1\]; convert uint8 with x.float\(\) / 255"):
        extract_patches(torch.zeros(1, 240, 320, dtype=torch.uint8), good, COARSE)
    with pytest.raises(TypeError, match=r"second has dtype torch.bool"):
        extract_patches(good, torch.zeros(1, 240, 320, dtype=torch.bool), COARSE)
    with pytest.raises(TypeError, match=r"first and second must share dtype"):
        extract_patches(good, good.double(), COARSE)
    with pytest.raises(ValueError, match="scale must be"):
        extract_patches(good, good, "medium")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_inputs(bad):
    good = torch.rand(2, 240, 320)
    broken = good.clone()
    broken[1, 0, 0] = bad  # outside the crop: only the explicit check can see it
    with pytest.raises(ValueError, match="second contains non-finite"):
        extract_patches(good, broken, FINE)
    with pytest.raises(ValueError, match="first contains non-finite"):
        extract_patches(broken, good, FINE)
    out = extract_patches(broken, good, FINE, check_finite=False)  # skipped on request
    assert torch.isfinite(out).all()


# ---------------------------------------------------------------------------------------------
# torch.compile, doctests, properties


def _compile_pair():
    return _rand(2, 240, 320, seed=21, dtype=torch.float32), _rand(2, 240, 320, seed=22, dtype=torch.float32)


def test_torch_compile_fullgraph_matches_eager():
    # fullgraph=True fails on any graph break; aot_eager traces the whole graph (dynamo + AOT
    # autograd) without the C++ code generation, which keeps this test at a few seconds.
    torch._dynamo.reset()
    first, second = _compile_pair()

    def both(a, b):
        return (
            extract_patches(a, b, COARSE, check_finite=False),
            extract_patches(a, b, FINE, check_finite=True),  # skipped while compiling: no break
        )

    compiled = torch.compile(both, fullgraph=True, dynamic=False, backend="aot_eager")
    for got, want in zip(compiled(first, second), both(first, second)):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-5)


@pytest.mark.slow  # the cold inductor build takes ~30 s on one CPU core
def test_torch_compile_inductor_matches_eager():
    torch._dynamo.reset()
    first, second = _compile_pair()
    compiled = torch.compile(extract_patches, fullgraph=True, dynamic=False)
    got = compiled(first, second, COARSE, check_finite=False)
    torch.testing.assert_close(got, extract_patches(first, second, COARSE), rtol=0, atol=1e-5)


def test_docstring_examples_run():
    result = doctest.testmod(patches_module, extraglobs={"torch": torch}, optionflags=doctest.ELLIPSIS)
    assert result.attempted >= 8 and result.failed == 0


def _image_batch(kind: str, b: int, h: int, w: int, seed: int, dtype) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(b, h, w, generator=g, dtype=dtype)
    if kind == "flat":
        x = torch.rand(b, 1, 1, generator=g, dtype=dtype).expand(b, h, w).contiguous()
    elif kind == "half-flat":
        x[:, :, : w // 2] = torch.rand(b, 1, 1, generator=g, dtype=dtype)
    elif kind == "smooth":
        ramp = torch.linspace(0, 1, w, dtype=dtype)
        x = 0.25 + 0.5 * ramp.expand(b, h, w) + 1e-3 * x
    return x


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(128, 300),
    w=st.integers(128, 300),
    b=st.integers(1, 3),
    kinds=st.tuples(*[st.sampled_from(["noise", "flat", "half-flat", "smooth"])] * 2),
    seed=st.integers(0, 2**31 - 1),
    double=st.booleans(),
    scale=st.sampled_from(SCALES),
)
def test_property_halves_unit_or_zero(h, w, b, kinds, seed, double, scale):
    dtype = torch.float64 if double else torch.float32
    first = _image_batch(kinds[0], b, h, w, seed, dtype)
    second = _image_batch(kinds[1], b, h, w, seed + 1, dtype)
    out = extract_patches(first, second, scale)
    assert out.shape == (b, scale.num_patches, scale.dim) and out.dtype == dtype
    assert torch.isfinite(out).all()
    halves = out.view(-1, scale.dim // 2)
    zero = (halves == 0).all(-1)
    unit = ((halves.mean(-1).abs() < 1e-6) & ((halves.norm(dim=-1) - 1).abs() < 1e-5))
    assert (zero | unit).all()
    if "flat" == kinds[0]:
        assert zero.view(b, -1, 2)[..., 0].all()
    if kinds[0] in ("noise", "smooth"):
        assert unit.view(b, -1, 2)[..., 0].all()


@pytest.mark.parametrize("flip, swap", [(True, False), (False, True), (True, True)])
def test_patch_permutation_is_the_symmetry_of_the_two_images(flip, swap):
    from aectorch.coding.patches import patch_permutation

    # Without a pyramid reduction the patches of mirrored images are the mirrored patches, with
    # the grid's columns reversed (the reduce keeps even samples, so with one it is only close).
    scale = Scale("plain", crop=20, downsample=1, patch_size=5, stride=5)
    gen = torch.Generator().manual_seed(0)
    first, second = torch.rand(2, 3, 24, 30, generator=gen).unbind(0)
    perm = patch_permutation(5, flip=flip, swap=swap)
    assert torch.equal(perm[perm], torch.arange(50))
    x = extract_patches(first, second, scale)
    pair = (second, first) if swap else (first, second)
    if flip:
        pair = tuple(image.flip(-1) for image in pair)
    y = extract_patches(*pair, scale).view(3, 4, 4, 50)
    y = (y.flip(2) if flip else y).reshape(3, 16, 50)
    torch.testing.assert_close(y, x[..., perm])
    with pytest.raises(ValueError, match="patch_size"):
        patch_permutation(0)


@pytest.mark.parametrize("name", ["wide", "coarse", "fine"])
def test_reduced_patches_cut_what_extract_patches_cuts_from_the_reduced_crops(name):
    import dataclasses

    from aectorch.coding.patches import as_scale, reduced_patches

    scale = dataclasses.replace(as_scale(name), centred=True)
    g = torch.Generator().manual_seed(0)
    first, second = torch.rand(2, 3, 240, 320, generator=g, dtype=torch.float64)
    top, left = (240 - scale.crop) // 2, (320 - scale.crop) // 2
    crop = lambda x: x[:, top:top + scale.crop, left:left + scale.crop]  # noqa: E731
    reduced = [pyramid_down(crop(x), scale.levels, centred=True) for x in (first, second)]
    torch.testing.assert_close(reduced_patches(*reduced, scale), extract_patches(first, second, scale))
    with pytest.raises(ValueError, match=rf"\[B, {scale.side}, {scale.side}\]"):
        reduced_patches(first, second, scale)


def test_encoder_reads_images_at_each_scales_resolution():
    from aectorch.coding import BinocularEncoder

    encoder = BinocularEncoder(generator=torch.Generator().manual_seed(0))
    first, second = torch.rand(2, 2, 240, 320, generator=torch.Generator().manual_seed(1))
    crops = {}
    for which, images in (("first", first), ("second", second)):
        crops[which] = {s.name: pyramid_down(images[:, 56:184, 96:224][:, (128 - s.crop) // 2:(128 + s.crop) // 2,
                                                                        (128 - s.crop) // 2:(128 + s.crop) // 2], s.levels,
                                             centred=s.centred)
                        for s in encoder.scales}
    with torch.no_grad():
        whole = encoder(first, second)
        reduced = encoder(crops["first"], crops["second"])
        pairs = encoder.encode({k: torch.stack((crops["first"][k], crops["second"][k]), 1) for k in crops["first"]})
        window = encoder.encode({"window": torch.stack((first, second), 1)})
    torch.testing.assert_close(pairs.features, reduced.features, rtol=0, atol=0)
    torch.testing.assert_close(window.features, whole.features, rtol=0, atol=0)
    torch.testing.assert_close(reduced.features, whole.features)
    torch.testing.assert_close(reduced.reward, whole.reward)


# --------------------------------------------------------------------------- patch_energy


@pytest.mark.parametrize("scale", [WIDE, COARSE, FINE, FULL], ids=lambda s: s.name)
def test_patch_energy_is_zero_on_a_flat_image_and_the_patch_variance_otherwise(scale):
    from aectorch.coding.patches import patch_energy

    side = scale.side
    flat = torch.full((3, 2, side, side), 0.37, dtype=torch.float64)
    assert patch_energy(flat, scale).abs().max().item() < 1e-24
    # A linear ramp along x, 1 grey level per pixel: every patch row is p consecutive values,
    # whose variance is (p^2 - 1) / 12, whatever the patch's place.
    p = scale.patch_size
    ramp = torch.arange(side, dtype=torch.float64).expand(1, 2, side, side) / side
    assert patch_energy(ramp, scale).item() == pytest.approx((p * p - 1) / 12 / side**2)
    # Oracle: numpy over the scale's own grid, on noise; energy scales with contrast squared.
    noise = torch.rand(2, 2, side, side, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    x = noise.numpy()
    g, s, o = scale.grid, scale.stride, scale.offset
    want = [np.mean([x[b, k, o + i * s:o + i * s + p, o + j * s:o + j * s + p].var()
                     for k in range(2) for i in range(g) for j in range(g)]) for b in range(2)]
    np.testing.assert_allclose(patch_energy(noise, scale).numpy(), want, rtol=1e-12)
    np.testing.assert_allclose(patch_energy(0.5 + 0.1 * noise, scale).numpy(), np.array(want) * 0.01, rtol=1e-9)
    # One image per row ([B, side, side]) is the same as K = 1.
    assert torch.equal(patch_energy(noise[:, 0], scale), patch_energy(noise[:, :1], scale))
    with pytest.raises(ValueError, match=f"pair at scale '{scale.name}'"):
        patch_energy(torch.zeros(1, 2, side + 1, side + 1), scale)
