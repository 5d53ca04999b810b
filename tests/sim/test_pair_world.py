"""Stereo photographs as a world: the readers of both layouts, the fixation points and the eyes'
windows (aectorch.sim.stereo_pairs, aectorch.sim.pair_world)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from aectorch.coding.patches import as_scale
from aectorch.sim import PinholeCamera
from aectorch.sim.env import pyramid_blur
from aectorch.sim.pair_world import StereoPairWorld, area_windows, eye_extent_px
from aectorch.sim.stereo_pairs import StereoPair, pick_fixations, read_pair, read_pairs, read_pfm

SCALES = [as_scale(s) for s in ("wide", "coarse", "fine", "full")]


def photo(h: int = 220, w: int = 320, seed: int = 0) -> torch.Tensor:
    """A textured grey photograph in [0, 1] (noise smoothed over 3 px)."""
    noise = torch.rand(1, 1, h, w, generator=torch.Generator().manual_seed(seed))
    return torch.nn.functional.avg_pool2d(noise, 3, 1, 1, count_include_pad=False)[0, 0]


def shifted(image: torch.Tensor, k: int) -> torch.Tensor:
    """The right photograph of a scene at disparity ``k`` everywhere: ``right[x - k] = left[x]``."""
    return torch.cat((image[:, k:], image[:, -1:].expand(-1, k)), 1)


def write_pfm(path, array: np.ndarray, little_endian: bool = True) -> None:
    rows = np.ascontiguousarray(array[::-1], dtype="<f4" if little_endian else ">f4")  # bottom row first
    header = f"Pf\n{array.shape[1]} {array.shape[0]}\n{-1.0 if little_endian else 1.0}\n".encode()
    path.write_bytes(header + rows.tobytes())


def save_png(path, image: np.ndarray) -> None:
    Image.fromarray((np.clip(image, 0, 1) * 255).round().astype(np.uint8)).save(path)


@pytest.mark.parametrize("little_endian", [True, False])
def test_pfm_is_read_top_row_first_in_either_byte_order(tmp_path, little_endian):
    array = np.arange(12, dtype=np.float32).reshape(3, 4)
    array[0, 1] = np.inf
    write_pfm(tmp_path / "d.pfm", array, little_endian)
    np.testing.assert_array_equal(read_pfm(tmp_path / "d.pfm"), array)
    (tmp_path / "bad.pfm").write_bytes(b"P5\n2 2\n255\n" + bytes(4))
    with pytest.raises(ValueError, match="not a PFM file"):
        read_pfm(tmp_path / "bad.pfm")
    (tmp_path / "short.pfm").write_bytes(b"Pf\n4 3\n-1\n" + bytes(8))
    with pytest.raises(ValueError, match="4 x 3 x 1 values expected, found 2"):
        read_pfm(tmp_path / "short.pfm")


def test_middlebury_layout_reads_inf_and_zero_as_unknown(tmp_path):
    left, right = np.random.default_rng(0).random((2, 6, 8))
    save_png(tmp_path / "im0.png", left)
    save_png(tmp_path / "im1.png", right)
    disparity = np.full((6, 8), 3.5, np.float32)
    disparity[0, 0], disparity[1, 2] = np.inf, 0.0
    write_pfm(tmp_path / "disp0.pfm", disparity)
    pair = read_pair(tmp_path)
    assert pair.name == tmp_path.name and pair.left.shape == (6, 8)
    np.testing.assert_allclose(pair.left.numpy(), np.round(left * 255) / 255, atol=1e-6)
    assert pair.known.sum() == 46 and not pair.known[0, 0] and not pair.known[1, 2]
    assert float(pair.disparity[2, 2]) == 3.5


def test_plain_layout_reads_nan_as_unknown_and_a_folder_of_pairs(tmp_path):
    for name, value in (("b", 2.0), ("a", 1.0)):
        folder = tmp_path / name
        folder.mkdir()
        save_png(folder / "left.png", np.full((5, 7), 0.5))
        Image.fromarray(np.full((5, 7, 3), 100, np.uint8)).save(folder / "right.jpg")  # any format, in colour
        disparity = np.full((5, 7), value)
        disparity[4, 6] = np.nan
        np.save(folder / "disparity.npy", disparity)
    pairs = read_pairs(tmp_path)
    assert [p.name for p in pairs] == ["a", "b"]  # sorted
    assert float(pairs[1].disparity[0, 0]) == 2.0 and math.isnan(float(pairs[1].disparity[4, 6]))
    assert abs(float(pairs[0].right[0, 0]) - 100 / 255) < 1e-6
    assert [p.name for p in read_pairs(tmp_path / "a")] == ["a"]  # a pair's own folder


def test_bad_folders_are_named_with_what_they_lack(tmp_path):
    with pytest.raises(ValueError, match="no such folder"):
        read_pairs(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="holds no pair"):
        read_pairs(tmp_path)
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match=r"odd.*neither Middlebury's layout \(im0.png, im1.png, disp0.pfm\) nor "
                                         r"the plain one \(left.\*, right.\*, disparity.npy\)"):
        read_pairs(tmp_path)
    (tmp_path / "odd" / "notes.txt").unlink()
    save_png(tmp_path / "odd" / "im0.png", np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"Middlebury's layout\) lacks im1.png, disp0.pfm"):
        read_pairs(tmp_path)
    plain = tmp_path / "plain"
    plain.mkdir()
    save_png(plain / "left.png", np.zeros((4, 4)))
    save_png(plain / "right.png", np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"left and right must be \[H, W\] images of one size, got \(4, 4\) and \(4, 5\)"):
        read_pair(plain)  # without disparity.npy: a pair without ground truth, whose images must match too
    np.save(plain / "disparity.npy", np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"one size, got \(4, 4\), \(4, 5\) and \(4, 4\)"):
        read_pair(plain)
    save_png(plain / "right.png", np.zeros((4, 4)))
    np.save(plain / "disparity.npy", np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="no pixel of its disparity is known"):
        read_pair(plain)


@pytest.mark.parametrize("pair_scale", [1, 2])
def test_each_scale_is_the_area_average_of_the_photo_then_the_pyramid_blur(pair_scale):
    """The renderer's construction (`ActiveDepthEnv._render`): the crop with one more scale pixel
    on every side, averaged over each pixel's footprint, then `pyramid_blur`; with the same photo
    to both eyes at zero vergence the halves are identical."""
    image = photo(400, 440)
    x, y = 220, 200
    world = StereoPairWorld(StereoPair("same", image, image, torch.zeros_like(image)), torch.tensor([[x, y]]),
                            pair_scale=pair_scale)
    observation = world.stereo_observation(SCALES)
    for s in SCALES:
        half = (s.crop + 2 * s.downsample) // 2 * pair_scale
        crop = image[y - half:y + half, x - half:x + half]
        expected = pyramid_blur(torch.nn.functional.avg_pool2d(crop[None, None], s.downsample * pair_scale)[0],
                                s.levels)[0]
        assert observation[s.name].shape == (1, 2, s.side, s.side)
        torch.testing.assert_close(observation[s.name][0, 0], expected, atol=1e-6, rtol=0)
        assert torch.equal(observation[s.name][0, 0], observation[s.name][0, 1])


@pytest.mark.parametrize("pair_scale", [1, 2])
def test_a_shifted_pair_has_its_optimum_at_the_shift_and_no_error_there(pair_scale):
    k = 6
    image = photo(400, 480)
    pair = StereoPair("shifted", image, shifted(image, k), torch.full_like(image, float(k)))
    points = pick_fixations(pair, 3, half_extent_px=eye_extent_px(SCALES) * pair_scale, texture_half_px=20,
                            min_contrast=0.0)
    world = StereoPairWorld(pair, points, pair_scale=pair_scale)
    f = PinholeCamera().focal_px
    assert torch.allclose(world.ground_truth_px, torch.full((3,), k / pair_scale, dtype=torch.float64))
    assert torch.allclose(world.optimal_vergence_deg, torch.full((3,), math.degrees(math.atan(k / pair_scale / f)),
                                                                 dtype=torch.float64))
    # parallel eyes: the right window sits k photo px short of the match (under-converged)
    assert torch.allclose(world.vergence_error_px, torch.full((3,), -k / pair_scale, dtype=torch.float64))
    world.set_vergence_deg(world.optimal_vergence_deg)
    assert world.vergence_error_px.abs().max() < 1e-9 and world.vergence_error_deg.abs().max() < 1e-12
    for name, pair_images in world.stereo_observation(SCALES).items():
        torch.testing.assert_close(pair_images[:, 0], pair_images[:, 1], atol=1e-5, rtol=0, msg=name)
    world.apply_vergence(torch.full((3,), 0.5))  # past the optimum: positive error, f tan(v) eye px
    expected = f * math.tan(math.radians(float(world.optimal_vergence_deg[0]) + 0.5)) - k / pair_scale
    assert torch.allclose(world.vergence_error_px, torch.full((3,), expected, dtype=torch.float64))


def test_a_window_moved_by_a_fraction_of_a_pixel_averages_the_pixels_it_covers():
    image = torch.tensor([[0.0, 1.0, 4.0, 9.0, 16.0, 25.0]]).repeat(2, 1)  # two rows: one block high
    out = area_windows(image, torch.tensor([0]), torch.tensor([1.25]), 1, 2, 2)
    # [1.25, 3.25): 0.75 * 1 + 4 + 0.25 * 9; [3.25, 5.25): 0.75 * 9 + 16 + 0.25 * 25
    assert out[0, 0].tolist() == [(0.75 + 4 + 2.25) / 2, (6.75 + 16 + 6.25) / 2]
    # beyond the edges the edge columns repeat
    assert area_windows(image, torch.tensor([0]), torch.tensor([-3.0]), 1, 1, 2)[0, 0].tolist() == [0.0]
    assert area_windows(image, torch.tensor([0]), torch.tensor([5.5]), 1, 1, 2)[0, 0].tolist() == [25.0]


def test_fixation_points_are_reproducible_known_and_textured():
    image = photo(300, 400)
    image[:, :200] = 0.5  # a flat half
    disparity = torch.full_like(image, 4.0)
    disparity[150:, :] = math.nan
    pair = StereoPair("half", image, shifted(image, 4), disparity)
    points = pick_fixations(pair, 20, half_extent_px=60, texture_half_px=20, min_contrast=0.05, seed=3)
    assert torch.equal(points, pick_fixations(pair, 20, half_extent_px=60, texture_half_px=20, seed=3))
    assert not torch.equal(points, pick_fixations(pair, 20, half_extent_px=60, texture_half_px=20, seed=4))
    x, y = points[:, 0], points[:, 1]
    assert bool((x >= 190).all()) and bool((y <= 149).all()) and bool((y >= 60).all())
    assert bool((x <= 400 - 60).all())
    with pytest.raises(ValueError, match=r"pair 'flat' .* has no fixation point with contrast >= 0.05"):
        flat = torch.full((300, 400), 0.5)
        pick_fixations(StereoPair("flat", flat, flat, torch.zeros_like(flat)), 5, half_extent_px=60,
                       texture_half_px=20)
