"""TextureBank: procedural 1/f textures, folders of photographs, default splits, indexing."""

from __future__ import annotations

import doctest
import itertools
import re

import numpy as np
import pytest
import torch
from PIL import Image, ImageOps

import aectorch.sim.textures as textures_module
from aectorch.sim.textures import bank, files, procedural, storage
from aectorch.sim.textures import IMAGE_EXTENSIONS, TextureBank, pink_noise_images


@pytest.fixture(autouse=True)
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


# ---------------------------------------------------------------------- helpers


def _radial_amplitude_slope(image: np.ndarray) -> float:
    """Log-log slope of the radially averaged amplitude spectrum (numpy only, integer rings)."""
    h, w = image.shape
    amplitude = np.abs(np.fft.fft2(image - image.mean()))
    fy = np.fft.fftfreq(h) * h
    fx = np.fft.fftfreq(w) * w
    ring = np.rint(np.hypot(fy[:, None], fx[None, :])).astype(int)
    sums = np.bincount(ring.ravel(), weights=amplitude.ravel())
    counts = np.bincount(ring.ravel())
    radii = np.arange(2, min(h, w) // 2 - 8)  # skip the lowest rings and the corners
    mean = sums[radii] / counts[radii]
    slope, _ = np.polyfit(np.log(radii), np.log(mean), 1)
    return float(slope)


def _pillow_oracle(file, height: int, width: int) -> np.ndarray:
    """Pillow alone, in 8 bits: convert("L"), then ImageOps.fit (cover-resize and centre crop)."""
    grey = Image.open(file).convert("L")
    fitted = ImageOps.fit(grey, (width, height), method=Image.Resampling.LANCZOS)
    return np.asarray(fitted, dtype=np.float32) / 255


def _smooth_rgb(rng: np.random.Generator, width: int, height: int, channels: int = 3) -> np.ndarray:
    """A random image with some structure (upsampled noise), uint8 [height, width, channels]."""
    coarse = rng.integers(0, 256, size=(height // 4 + 1, width // 4 + 1, channels), dtype=np.uint8)
    image = Image.fromarray(coarse.squeeze(-1) if channels == 1 else coarse)
    return np.asarray(image.resize((width, height), Image.Resampling.BILINEAR))


@pytest.fixture
def image_folder(tmp_path):
    """Images of several modes, formats, sizes and aspect ratios, plus files to be ignored."""
    rng = np.random.default_rng(0)
    Image.fromarray(_smooth_rgb(rng, 80, 60)).save(tmp_path / "a_rgb.png")
    Image.fromarray(_smooth_rgb(rng, 50, 120, 1)).save(tmp_path / "b_grey_tall.png")
    rgba = _smooth_rgb(rng, 64, 64, 4)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "c_rgba.PNG")
    Image.fromarray(_smooth_rgb(rng, 100, 70)).save(tmp_path / "d_rgb.jpg", quality=95)
    Image.fromarray(_smooth_rgb(rng, 20, 30, 1)).save(tmp_path / "E_small_grey.JPEG")
    Image.fromarray(_smooth_rgb(rng, 90, 40)).convert("P").save(tmp_path / "f_palette.png")
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "._a_rgb.png").write_bytes(b"\x00\x05\x16\x07 macOS resource fork")
    (tmp_path / "sub").mkdir()
    Image.fromarray(_smooth_rgb(rng, 40, 40)).save(tmp_path / "sub" / "g_nested.png")
    return tmp_path


# ---------------------------------------------------------------------- procedural


def test_procedural_shape_range_names_and_seed():
    bank = TextureBank.procedural(num=6, size=(24, 40), seed=3)
    assert len(bank) == 6 and bank.size == (24, 40)
    assert bank.textures.shape == (6, 24, 40) and bank.textures.dtype == torch.float32
    assert torch.equal(bank.textures.amin(dim=(-2, -1)), torch.zeros(6))
    assert torch.equal(bank.textures.amax(dim=(-2, -1)), torch.ones(6))
    assert bank.names == [f"pink-3-{i}" for i in range(6)]
    again = TextureBank.procedural(num=6, size=(24, 40), seed=3)
    other = TextureBank.procedural(num=6, size=(24, 40), seed=4)
    assert torch.equal(bank.textures, again.textures)
    assert not torch.allclose(bank.textures, other.textures, atol=0.05)
    flat = bank.textures.flatten(1)
    assert torch.cdist(flat, flat).add(torch.eye(6) * 1e9).min() > 1.0  # six distinct textures


def test_procedural_prefix_stable_and_dtype_independent():
    small = TextureBank.procedural(num=3, size=16, seed=1)
    large = TextureBank.procedural(num=7, size=16, seed=1, dtype=torch.float64)
    assert large.textures.dtype == torch.float64
    assert torch.equal(small.textures, large.textures[:3].float())


@pytest.mark.parametrize("alpha", [0.8, 1.0, 1.5])
def test_procedural_amplitude_spectrum_slope(alpha):
    bank = TextureBank.procedural(num=1, size=(256, 256), alpha=alpha, seed=11, dtype=torch.float64)
    slope = _radial_amplitude_slope(bank.textures[0].numpy())
    assert slope == pytest.approx(-alpha, abs=0.1)


def test_spectrum_slope_oracle_tells_white_noise_from_pink():
    white = np.random.default_rng(0).random((256, 256))
    assert _radial_amplitude_slope(white) == pytest.approx(0.0, abs=0.1)


def test_procedural_alpha_range_lies_between_its_ends():
    bank = TextureBank.procedural(num=4, size=(128, 128), alpha=(1.0, 1.2), seed=0, dtype=torch.float64)
    slopes = [_radial_amplitude_slope(t.numpy()) for t in bank.textures]
    assert all(-1.25 < s < -0.95 for s in slopes), slopes
    assert max(slopes) - min(slopes) > 0.005  # the exponent varies from texture to texture


def test_procedural_rejects_bad_arguments():
    with pytest.raises(TypeError, match="num"):
        TextureBank.procedural(num=2.0, size=8)
    with pytest.raises(ValueError, match="num"):
        TextureBank.procedural(num=0, size=8)
    with pytest.raises(ValueError, match="alpha"):
        TextureBank.procedural(num=1, size=8, alpha=(1.3, 1.0))
    with pytest.raises(ValueError, match="alpha"):
        TextureBank.procedural(num=1, size=8, alpha=float("nan"))
    with pytest.raises(TypeError, match="dtype"):
        TextureBank.procedural(num=1, size=8, dtype=torch.int64)


@pytest.mark.parametrize(
    "size, error",
    [((0, 5), ValueError), ((1, 8), ValueError), ((8,), ValueError), ("abc", ValueError),
     ((2.5, 3), TypeError), ((True, 4), TypeError), (None, ValueError)],
)
def test_bad_size_argument(size, error, tmp_path):
    with pytest.raises(error, match="size"):
        TextureBank.procedural(num=1, size=size)
    with pytest.raises(error, match="size"):
        TextureBank.from_folder(tmp_path, size=size)


def test_pink_noise_images_lives_here():
    assert pink_noise_images.__module__ == "aectorch.sim.textures.procedural"


# ---------------------------------------------------------------------- from_folder


def test_from_folder_shapes_order_and_ignored_files(image_folder):
    bank = TextureBank.from_folder(image_folder, size=(32, 48))
    expected = sorted(["a_rgb.png", "b_grey_tall.png", "c_rgba.PNG", "d_rgb.jpg",
                       "E_small_grey.JPEG", "f_palette.png"])
    assert bank.names == expected  # .txt, hidden files and subfolders left out
    assert bank.names[0] == "E_small_grey.JPEG"  # plain str order: capitals first
    assert bank.textures.shape == (6, 32, 48) and bank.textures.dtype == torch.float32
    assert 0.0 <= float(bank.textures.min()) and float(bank.textures.max()) <= 1.0
    assert "folder" in repr(bank) and "N=6" in repr(bank)

    nested = TextureBank.from_folder(image_folder, size=(32, 48), recursive=True)
    assert nested.names == sorted(expected + ["sub/g_nested.png"])
    only_jpeg = TextureBank.from_folder(image_folder, size=8, extensions=("JPG", ".jpeg"))
    assert only_jpeg.names == ["E_small_grey.JPEG", "d_rgb.jpg"]


@pytest.mark.parametrize("size", [(32, 48), (48, 32), (64, 64), (90, 70)])
def test_from_folder_matches_pillow_grey_and_fit(image_folder, size):
    bank = TextureBank.from_folder(image_folder, size=size)
    for name, texture in zip(bank.names, bank.textures):
        oracle = _pillow_oracle(image_folder / name, *size)
        # The bank resamples in float, Pillow's "L" resize rounds each of its two passes to
        # 8 bits: they differ by rounding only.
        np.testing.assert_allclose(texture.numpy(), oracle, atol=2 / 255, err_msg=name)
        assert np.abs(texture.numpy() - oracle).mean() < 0.5 / 255, name


def test_from_folder_crop_only_and_same_size_are_exact(tmp_path):
    rng = np.random.default_rng(2)
    wide = rng.integers(0, 256, size=(20, 36), dtype=np.uint8)  # 8 extra columns each side
    tall = rng.integers(0, 256, size=(30, 20), dtype=np.uint8)  # 5 extra rows top and bottom
    exact = rng.integers(0, 256, size=(20, 20, 3), dtype=np.uint8)
    Image.fromarray(wide).save(tmp_path / "1_wide.png")
    Image.fromarray(tall).save(tmp_path / "2_tall.png")
    Image.fromarray(exact).save(tmp_path / "3_exact.png")
    bank = TextureBank.from_folder(tmp_path, size=(20, 20))
    np.testing.assert_allclose(bank.textures[0].numpy(), wide[:, 8:28] / 255, atol=1e-6)
    np.testing.assert_allclose(bank.textures[1].numpy(), tall[5:25] / 255, atol=1e-6)
    grey = np.asarray(Image.fromarray(exact).convert("L"), dtype=np.float32) / 255
    np.testing.assert_allclose(bank.textures[2].numpy(), grey, atol=1e-6)


def test_from_folder_grey_conversion_is_itu_601_luma(tmp_path):
    colours = {"red.png": (255, 0, 0), "green.png": (0, 255, 0), "blue.png": (0, 0, 255),
               "grey.png": (200, 200, 200)}
    for name, rgb in colours.items():
        Image.new("RGB", (10, 12), rgb).save(tmp_path / name)
    bank = TextureBank.from_folder(tmp_path, size=(6, 6))
    for name, texture in zip(bank.names, bank.textures):
        r, g, b = colours[name]
        luma = (299 * r + 587 * g + 114 * b) / 1000 / 255
        assert torch.allclose(texture, torch.full((6, 6), luma), atol=0.5 / 255), name


def test_from_folder_keeps_16_bit_grey_range(tmp_path):
    ramp = np.linspace(0, 65535, 32 * 32).reshape(32, 32).astype(np.uint16)
    Image.fromarray(ramp).save(tmp_path / "deep.png")
    bank = TextureBank.from_folder(tmp_path, size=(32, 32))  # no resize: same size
    np.testing.assert_allclose(bank.textures[0].numpy(), ramp / 65535, atol=1e-6)


def test_from_folder_sklearn_photographs(tmp_path):
    datasets = pytest.importorskip("sklearn.datasets")
    photos = datasets.load_sample_images()
    for name, array in zip(photos.filenames, photos.images):
        Image.fromarray(array).save(tmp_path / name.replace("\\", "/").rsplit("/", 1)[-1], quality=95)
    bank = TextureBank.from_folder(tmp_path, size=(120, 160), progress=True)
    assert bank.names == ["china.jpg", "flower.jpg"]
    assert bank.textures.shape == (2, 120, 160)
    for name, texture in zip(bank.names, bank.textures):
        np.testing.assert_allclose(texture.numpy(), _pillow_oracle(tmp_path / name, 120, 160),
                                   atol=2 / 255, err_msg=name)
        assert float(texture.std()) > 0.1  # a photograph, not a flat field
    # Real photographs have a roughly 1/f amplitude spectrum too.
    slope = _radial_amplitude_slope(
        TextureBank.from_folder(tmp_path, size=(256, 256)).textures[0].double().numpy()
    )
    assert -1.8 < slope < -0.7


def test_from_folder_float64_and_path_as_str(image_folder):
    bank32 = TextureBank.from_folder(image_folder, size=16)
    bank64 = TextureBank.from_folder(str(image_folder), size=16, dtype=torch.float64)
    assert bank64.dtype == torch.float64
    assert torch.allclose(bank64.textures.float(), bank32.textures)


# ---------------------------------------------------------------------- from_folder errors


def test_missing_folder(tmp_path):
    missing = tmp_path / "nope"
    with pytest.raises(FileNotFoundError, match="nope"):
        TextureBank.from_folder(missing)


def test_file_instead_of_folder(tmp_path):
    file = tmp_path / "picture.png"
    Image.new("L", (4, 4)).save(file)
    with pytest.raises(NotADirectoryError, match="picture.png"):
        TextureBank.from_folder(file)


def test_empty_folder_and_folder_without_images(tmp_path):
    with pytest.raises(ValueError, match=r"no image file.*\.png.*\.jpg.*\.jpeg"):
        TextureBank.from_folder(tmp_path)
    (tmp_path / "readme.txt").write_text("hello")
    (tmp_path / "photos").mkdir()
    Image.new("L", (4, 4)).save(tmp_path / "photos" / "deep.png")
    with pytest.raises(ValueError, match="no image file") as info:
        TextureBank.from_folder(tmp_path)
    assert str(tmp_path) in str(info.value)


def test_corrupt_image_names_the_file(tmp_path):
    Image.new("L", (8, 8), 3).save(tmp_path / "good.png")
    (tmp_path / "broken.png").write_bytes(np.random.default_rng(0).bytes(300))
    with pytest.raises(ValueError, match=r"broken\.png.*cannot identify image file"):
        TextureBank.from_folder(tmp_path, size=8)


def test_truncated_jpeg_names_the_file(tmp_path):
    Image.fromarray(_smooth_rgb(np.random.default_rng(1), 64, 64)).save(tmp_path / "cut.jpg")
    data = (tmp_path / "cut.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.jpg"):
        TextureBank.from_folder(tmp_path, size=8)


@pytest.mark.parametrize("name, content", [("empty.png", b""), ("notes.jpg", b"a text file, not an image\n")])
def test_a_file_that_is_not_an_image_names_the_file(tmp_path, name, content):
    Image.new("L", (16, 16), 100).save(tmp_path / "good.png")
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ValueError, match=rf"cannot read image file .*{re.escape(name)}"):
        TextureBank.from_folder(tmp_path, size=8)


def test_an_exif_rotated_photograph_is_read_upright(tmp_path):
    # A portrait stored sideways with EXIF orientation 6 (rotate 90 deg clockwise to view): dark top half.
    upright = np.zeros((40, 20), np.uint8)
    upright[20:] = 255
    stored = Image.fromarray(upright).transpose(Image.Transpose.ROTATE_90)  # as a camera writes it
    exif = Image.Exif()
    exif[0x0112] = 6
    stored.save(tmp_path / "portrait.jpg", exif=exif, quality=95)
    texture = TextureBank.from_folder(tmp_path, size=(40, 20)).textures[0]
    assert float(texture[:18].mean()) < 0.1 and float(texture[22:].mean()) > 0.9


def test_bad_extensions(tmp_path):
    with pytest.raises(ValueError, match="extensions"):
        TextureBank.from_folder(tmp_path, extensions=())
    with pytest.raises(ValueError, match="extensions"):
        TextureBank.from_folder(tmp_path, extensions=(".",))
    assert IMAGE_EXTENSIONS == (".png", ".jpg", ".jpeg")


# ---------------------------------------------------------------------- constructor


def test_constructor_accepts_valid_textures():
    bank = TextureBank(torch.rand(3, 5, 7, dtype=torch.float64), ["x", "y", "z"], source="unit")
    assert len(bank) == 3 and bank.size == (5, 7) and bank.names == ["x", "y", "z"]
    assert TextureBank(torch.zeros(1, 2, 2)).names == ["texture-0"]
    assert "source='unit'" in repr(bank)


def test_constructor_wrong_shape_says_expected_and_received():
    with pytest.raises(ValueError, match=r"\[N, H, W\].*\(5, 7\).*unsqueeze\(0\)"):
        TextureBank(torch.rand(5, 7))
    with pytest.raises(ValueError, match=r"\[N, H, W\].*\(2, 1, 5, 7\).*squeeze\(1\)"):
        TextureBank(torch.rand(2, 1, 5, 7))
    with pytest.raises(ValueError, match=r"\[N, H, W\].*\(2, 3, 5, 7\)"):
        TextureBank(torch.rand(2, 3, 5, 7))
    with pytest.raises(ValueError, match=r"N >= 1.*\(0, 5, 7\)"):
        TextureBank(torch.rand(0, 5, 7))
    with pytest.raises(ValueError, match=r"H, W >= 2.*\(2, 1, 7\)"):
        TextureBank(torch.rand(2, 1, 7))


def test_constructor_rejects_bad_values_types_and_names():
    with pytest.raises(ValueError, match=r"\[0, 1\].*1\.5"):
        TextureBank(torch.full((1, 3, 3), 1.5))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        TextureBank(torch.full((1, 3, 3), -0.1))
    with pytest.raises(ValueError, match="finite"):
        TextureBank(torch.tensor([[[0.5, float("nan")], [0.1, 0.2]]]))
    with pytest.raises(TypeError, match="uint8.*255"):
        TextureBank(torch.zeros(1, 3, 3, dtype=torch.uint8))
    with pytest.raises(TypeError, match="torch.Tensor"):
        TextureBank(np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="expected 2, got 1"):
        TextureBank(torch.rand(2, 3, 3), ["only-one"])
    with pytest.raises(TypeError, match="names"):
        TextureBank(torch.rand(2, 3, 3), ["a", 2])


# ---------------------------------------------------------------------- default, spec


def test_default_train_and_test_sets():
    train = TextureBank.default("train", size=(32, 32))
    test = TextureBank.default("test", size=(32, 32))
    assert len(train) == 100 and len(test) == 40
    assert train.size == test.size == (32, 32)
    assert torch.equal(train.textures, TextureBank.default(size=(32, 32)).textures)
    assert torch.equal(test.textures, TextureBank.default("test", size=(32, 32)).textures)
    assert set(train.names).isdisjoint(test.names)
    every = torch.cat([train.textures, test.textures]).flatten(1).double()
    distance = torch.cdist(every, every) + torch.eye(140, dtype=torch.float64) * 1e9
    assert float(distance.min()) > 1.0  # no two of the 140 textures are alike
    with pytest.raises(ValueError, match="split"):
        TextureBank.default("validation", size=8)


def test_from_spec(image_folder, tmp_path):
    for keyword in ("default", "procedural", "Procedural"):
        bank = TextureBank.from_spec(keyword, split="test", size=8)
        assert torch.equal(bank.textures, TextureBank.default("test", size=8).textures)
    folder = TextureBank.from_spec(str(image_folder), size=8)
    assert folder.names == TextureBank.from_folder(image_folder, size=8).names
    assert len(TextureBank.from_spec(image_folder, size=8)) == 6  # a Path works too
    with pytest.raises(FileNotFoundError, match="procedral.*'default'"):
        TextureBank.from_spec("procedral", size=8)
    with pytest.raises(TypeError, match="spec"):
        TextureBank.from_spec(3, size=8)


# ---------------------------------------------------------------------- split, subset, to


def test_split_disjoint_deterministic_and_covering():
    bank = TextureBank.procedural(num=11, size=8)
    train, test = bank.split(0.2, seed=5)
    assert (len(train), len(test)) == (9, 2)
    assert set(train.names).isdisjoint(test.names)
    assert sorted(train.names + test.names) == sorted(bank.names)
    for part in (train, test):  # each keeps the bank's order, and its textures
        positions = [bank.names.index(n) for n in part.names]
        assert positions == sorted(positions)
        assert torch.equal(part.textures, bank.textures[positions])
    again = bank.split(0.2, seed=5)
    assert again[0].names == train.names and again[1].names == test.names
    splits = {tuple(bank.split(0.2, seed=s)[1].names) for s in range(6)}
    assert len(splits) > 1  # the seed matters


def test_split_keeps_one_in_each_and_rejects_impossible():
    bank = TextureBank.procedural(num=3, size=8)
    assert [len(b) for b in bank.split(0.01)] == [2, 1]
    assert [len(b) for b in bank.split(0.99)] == [1, 2]
    with pytest.raises(ValueError, match="test_fraction"):
        bank.split(0.0)
    with pytest.raises(ValueError, match="test_fraction"):
        bank.split(1.0)
    with pytest.raises(ValueError, match="need >= 2"):
        TextureBank.procedural(num=1, size=8).split(0.5)


def test_subset_and_to():
    bank = TextureBank.procedural(num=5, size=8)
    sub = bank.subset(torch.tensor([4, 0, -1]))
    assert sub.names == ["pink-0-4", "pink-0-0", "pink-0-4"]
    assert torch.equal(sub.textures, bank.textures[[4, 0, 4]])
    with pytest.raises(IndexError, match="indices"):
        bank.subset([5])
    with pytest.raises(ValueError, match="at least one"):
        bank.subset([])
    as64 = bank.to(dtype=torch.float64)
    assert as64.dtype == torch.float64 and bank.dtype == torch.float32
    assert as64.names == bank.names and torch.equal(as64.textures.float(), bank.textures)
    with pytest.raises(TypeError, match="dtype"):
        bank.to(dtype=torch.int32)


# ---------------------------------------------------------------------- indexing and sampling


def test_getitem_with_int_list_and_long_tensor():
    bank = TextureBank.procedural(num=4, size=(6, 10))
    assert bank[2].shape == (6, 10) and torch.equal(bank[2], bank.textures[2])
    assert torch.equal(bank[-1], bank.textures[3])
    index = torch.tensor([3, 3, 0])
    assert bank[index].shape == (3, 6, 10)
    assert torch.equal(bank[index], bank.textures[[3, 3, 0]])
    assert torch.equal(bank[[1, 2]], bank.textures[1:3])
    assert torch.equal(bank[1:3], bank.textures[1:3])
    assert torch.equal(bank[torch.tensor([1], dtype=torch.int32)], bank.textures[1:2])


@pytest.mark.parametrize("index", [4, -5, torch.tensor([0, 4]), torch.tensor([-5]), [0, 7]])
def test_getitem_out_of_range(index):
    bank = TextureBank.procedural(num=4, size=8)
    with pytest.raises(IndexError, match=r"\[-4, 4\)"):
        bank[index]


def test_getitem_wrong_index_type():
    bank = TextureBank.procedural(num=4, size=8)
    with pytest.raises(TypeError, match="integer tensor"):
        bank[torch.tensor([0.0, 1.0])]
    with pytest.raises(TypeError, match="integer tensor"):
        bank[torch.tensor([True, False, True, False])]
    with pytest.raises(TypeError):
        bank[1.0]


def test_sample_indices_seeded_uniform():
    bank = TextureBank.procedural(num=5, size=8)
    first = bank.sample_indices(4000, torch.Generator().manual_seed(3))
    again = bank.sample_indices(4000, torch.Generator().manual_seed(3))
    other = bank.sample_indices(4000, torch.Generator().manual_seed(4))
    assert first.shape == (4000,) and first.dtype == torch.int64
    assert torch.equal(first, again) and not torch.equal(first, other)
    counts = torch.bincount(first, minlength=5)
    assert counts.numel() == 5 and int(counts.min()) > 700 and int(counts.max()) < 900
    assert bank[first[:3]].shape == (3, 8, 8)
    with pytest.raises(ValueError, match="batch"):
        bank.sample_indices(0, torch.Generator())
    with pytest.raises(TypeError, match="generator"):
        bank.sample_indices(2, 0)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_bank_sampling_and_indexing():
    bank = TextureBank.procedural(num=6, size=16).to("cuda")
    assert bank.device.type == "cuda"
    generator = torch.Generator("cuda").manual_seed(0)
    index = bank.sample_indices(5, generator)
    assert index.device.type == "cuda" and bank[index].device.type == "cuda"
    assert torch.equal(bank[index].cpu(), TextureBank.procedural(num=6, size=16)[index.cpu()])
    on_gpu = TextureBank.procedural(num=6, size=16, device="cuda")
    assert torch.equal(on_gpu.textures.cpu(), bank.textures.cpu())


# ---------------------------------------------------------------------- docstrings


def test_textures_module_doctests():
    # tests/project/test_doctests.py collects aectorch.coding only; run this module's examples here.
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(verbose=False)
    report: list[str] = []
    for module in (bank, files, procedural, storage):
        for test in finder.find(module, module.__name__, globs=vars(module).copy()):
            runner.run(test, out=report.append)
    failed, attempted = runner.summarize(verbose=False)
    assert attempted > 10
    assert failed == 0, "".join(report)


def test_every_public_callable_has_an_example():
    public = [TextureBank, pink_noise_images] + [
        getattr(TextureBank, name)
        for name in ("procedural", "default", "from_folder", "from_spec", "sample_indices",
                     "subset", "split")
    ]
    for obj in public:
        assert ">>>" in (obj.__doc__ or ""), obj.__name__
    assert not list(itertools.filterfalse(str.isidentifier, textures_module.__all__))


def test_dead_leaves_have_flat_regions_sharp_edges_and_a_falling_spectrum():
    from aectorch.sim import dead_leaves_image

    g = torch.Generator().manual_seed(0)
    flat = dead_leaves_image(256, 256, generator=g, inner_contrast=0.0, dtype=torch.float64)
    assert float(flat.amin()) == 0.0 and float(flat.amax()) == 1.0
    steps = (flat[:, 1:] - flat[:, :-1]).abs()
    assert float((steps == 0).double().mean()) > 0.6  # inside a disc nothing changes ...
    assert float((steps > 0.1).double().mean()) > 0.05  # ... and its edge is a jump
    power = torch.fft.rfft2(flat - flat.mean()).abs().square()
    low, high = power[1:4, 1:4].mean(), power[60:64, 60:64].mean()
    assert float(low / high) > 100
    bank = TextureBank.dead_leaves(3, 64, seed=5)
    assert torch.equal(bank.textures[:2], TextureBank.dead_leaves(2, 64, seed=5).textures)
    assert TextureBank.from_spec("dead-leaves", split="test", size=32).names[0] == "leaves-2018-0"
    with pytest.raises(ValueError, match="radius_px"):
        dead_leaves_image(8, 8, generator=g, radius_px=(3, 1))


def _mapped_texture_files() -> int:
    """How many texture files (`empty_textures`) this process has mapped."""
    with open("/proc/self/maps") as maps:
        return len({line.split()[-2] if line.rstrip().endswith("(deleted)") else line.split()[-1]
                    for line in maps if "aectorch-textures-" in line})


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/maps"), reason="needs Linux's /proc")
def test_a_bank_over_the_ram_limit_is_mapped_from_a_file_and_reads_the_same(image_folder, monkeypatch):
    from aectorch.sim.render_torch import mipmap_atlas, texture_atlas

    in_ram = TextureBank.from_folder(image_folder, size=(24, 40))
    background = torch.rand(24, 40)
    atlas, mip = texture_atlas(in_ram.textures, background), mipmap_atlas(in_ram.textures, background)
    before = _mapped_texture_files()
    monkeypatch.setenv("AECTORCH_TEXTURE_RAM", "1000")
    mapped = TextureBank.from_folder(image_folder, size=(24, 40))
    assert _mapped_texture_files() == before + 1
    assert torch.equal(mapped.textures, in_ram.textures)
    mapped_atlas, mapped_mip = texture_atlas(mapped.textures, background), mipmap_atlas(mapped.textures, background)
    assert _mapped_texture_files() == before + 3 and torch.equal(mapped_atlas, atlas)
    assert torch.equal(mapped_mip.packed, mip.packed) and torch.equal(mapped_mip.origins, mip.origins)
    monkeypatch.setenv("AECTORCH_TEXTURE_RAM", "lots")
    with pytest.raises(ValueError, match="AECTORCH_TEXTURE_RAM must be a number of bytes"):
        TextureBank.from_folder(image_folder, size=(24, 40))


def test_the_mipmap_atlas_built_in_chunks_equals_the_whole_pyramid(monkeypatch):
    import aectorch.sim.render_torch as render_torch

    textures, background = torch.rand(5, 12, 20), torch.rand(12, 20)
    whole = render_torch.mipmap_atlas(textures, background)
    monkeypatch.setattr(render_torch, "_MIP_CHUNK_TEXELS", 2 * 12 * 20)  # two layers at a time
    chunked = render_torch.mipmap_atlas(textures, background)
    assert torch.equal(whole.packed, chunked.packed) and torch.equal(whole.sizes, chunked.sizes)
    levels = render_torch.mipmap_levels(torch.cat((textures, background[None])))
    for (top, left), (h, w), level in zip(whole.origins.tolist(), whole.sizes.tolist(), levels):
        assert torch.equal(whole.packed[:, top:top + h, left:left + w], level)


_TEN_THOUSAND = r"""
import os, sys, torch
from aectorch.sim import ActiveDepthEnv, TextureBank
def anon_mib():
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("RssAnon:")) / 1024
torch.set_num_threads(1)
start = anon_mib()
bank = TextureBank.from_folder(sys.argv[1], size=64, progress=True)
env = ActiveDepthEnv(4, textures=bank, seed=0)
env.reset()
assert all(bool(x.isfinite().all()) for x in env.stereo_observation().values())
print(len(bank), bank.textures.numel() * 4 / 2**20, anon_mib() - start, float(bank[9999].mean()))
"""


@pytest.mark.integration
@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/status"), reason="needs Linux's /proc")
def test_a_folder_of_ten_thousand_images_loads_in_bounded_memory_with_a_progress_bar(tmp_path):
    import os
    import subprocess
    import sys

    folder = tmp_path / "photos"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(10_000):  # smooth images, small PNGs: about 4 s to write
        image = np.repeat(np.repeat(rng.integers(0, 256, (8, 8), dtype=np.uint8), 8, 0), 8, 1)
        Image.fromarray(image).save(folder / f"{i:05d}.png", compress_level=1)
    env = dict(os.environ, AECTORCH_TEXTURE_RAM=str(2**20), OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", _TEN_THOUSAND, str(folder)], capture_output=True, text=True,
                          env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    count, bank_mib, grown_mib, last_mean = done.stdout.split()
    assert int(count) == 10_000 and float(bank_mib) > 150
    # The bank (156 MiB) and the renderer's atlas (1.5x) live in mapped files (measured: +29 MiB), not in the
    # process's anonymous memory, which grows by what torch and Pillow need for a few images.
    assert float(grown_mib) < 0.4 * float(bank_mib), done.stdout  # in RAM: 2.2x
    assert abs(float(last_mean) - float(np.asarray(Image.open(folder / "09999.png")).mean()) / 255) < 1e-6
    assert "textures: 100%" in done.stderr and "10000/10000" in done.stderr


def test_a_larger_generated_world_begins_with_the_default_set_and_only_sizes_generated_sets(tmp_path):
    from aectorch.runtime import ExperimentConfig, build_textures
    from aectorch.runtime.config import EnvConfig

    default = TextureBank.default("train", size=8)
    larger = TextureBank.default("train", size=8, num=130)
    assert len(larger) == 130 and torch.equal(larger.textures[:100], default.textures)
    assert larger.names[:100] == default.names
    leaves = TextureBank.from_spec("dead-leaves", size=8, num=3)
    assert torch.equal(leaves.textures, TextureBank.from_spec("dead-leaves", size=8).textures[:3])
    # env.num_textures sizes the training set only; the test set stays the default's 40
    cfg = ExperimentConfig(env=EnvConfig(num_textures=105))
    assert len(build_textures(None, "train", cfg)) == 105 and len(build_textures(None, "test", cfg)) == 40
    with pytest.raises(ValueError, match=r"env.num_textures=5 sizes a generated texture set.*folder"):
        EnvConfig(textures=str(tmp_path), num_textures=5)
    with pytest.raises(ValueError, match=r"env.num_textures must be"):
        EnvConfig(num_textures=0)
