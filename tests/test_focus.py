"""The world's defocus: an eye focused off the object sees it blurred by a disc of angular diameter
aperture x |1/d - focus|, in both renderers; a pinhole, or eyes focused on the object, see today's images."""

import math
from dataclasses import replace

import pytest
import torch

from aectorch.coding.patches import DEFAULT_SCALES, as_scale
from aectorch.sim import ActiveDepthEnv, TextureBank
from aectorch.sim.perturbations import NEUTRAL
from aectorch.sim.protocol import DEFAULT_APERTURE_M, TrialProtocol

torch.set_num_threads(1)
SCALES = [as_scale(s) for s in DEFAULT_SCALES]


@pytest.fixture(scope="module")
def bank():
    return TextureBank((TextureBank.procedural(3, size=(256, 256), seed=7).textures * 255).round() / 255)


def observe(env):
    return {**env.stereo_observation(SCALES, window=True)}


def test_an_eye_out_of_focus_sees_what_anisometropia_of_that_disc_shows(bank):
    """Oracle: the world's defocus of each environment is the perturbation's image blur of the same
    disc (which tests/test_perturbations.py checks against the sharp image convolved with it)."""
    distances = torch.tensor([1.0, 2.0, 3.0])
    env = ActiveDepthEnv(3, textures=bank, distances_m=[1.0, 2.0, 3.0], fixation_iterations=2, seed=0)
    env.set_trial(torch.tensor([0, 1, 2]), distances)
    focus = torch.stack((1.0 / distances + torch.tensor([2.0, 1.0, 0.5]), 1.0 / distances), -1)  # left eye off
    env.set_focus(focus)
    blurred = observe(env)
    arcmin = DEFAULT_APERTURE_M * torch.tensor([2.0, 1.0, 0.5]) * 180 * 60 / math.pi
    assert abs(float(arcmin[2]) - 27.5) < 0.1  # 16 mm x 0.5 D = 8 mrad
    for b in range(3):
        alone = ActiveDepthEnv(1, textures=bank, distances_m=[1.0, 2.0, 3.0], fixation_iterations=2, seed=0)
        alone.set_trial(torch.tensor([b]), distances[b:b + 1])
        alone.set_optics(replace(NEUTRAL, blur_arcmin=(float(arcmin[b]), 0.0)))
        reference = observe(alone)
        for name, image in reference.items():
            torch.testing.assert_close(blurred[name][b:b + 1], image, rtol=0, atol=2e-6, msg=name)
    env.set_focus(None)
    sharp = observe(env)
    assert (sharp["fine"][0, 0] - blurred["fine"][0, 0]).abs().mean() > 0.01  # the check can fail (2 D)
    torch.testing.assert_close(sharp["fine"][:, 1], blurred["fine"][:, 1], rtol=0, atol=0)


def test_a_pinhole_and_eyes_on_the_object_see_todays_images(bank):
    kwargs = dict(textures=bank, fixation_iterations=2, seed=4)
    today = observe(ActiveDepthEnv(2, **kwargs))
    pinhole = ActiveDepthEnv(2, aperture_m=0.0, **kwargs)
    pinhole.set_focus(0.0)  # focused at infinity, but a pinhole
    focused = ActiveDepthEnv(2, **kwargs)
    focused.set_focus(1.0 / focused.distance_m[:, None].expand(2, 2))
    for env in (pinhole, focused):
        for name, image in observe(env).items():
            torch.testing.assert_close(image, today[name], rtol=0, atol=1e-6, msg=name)
    assert not TrialProtocol().moving and ActiveDepthEnv(1, **kwargs).focus_dioptres is None


def test_both_renderers_blur_alike_and_the_focus_resumes(bank):
    envs = [ActiveDepthEnv(2, textures=bank, renderer=name, fixation_iterations=2, seed=5)
            for name in ("torch", "pyrender")]
    try:
        for env in envs:
            env.set_focus(torch.tensor([[0.0, 1.5], [2.0, 0.2]]))
        ours, theirs = observe(envs[0]), observe(envs[1])
        for name in ours:
            assert (ours[name] - theirs[name]).abs().mean() < 0.01, name
    finally:
        envs[1].close()
    copy = ActiveDepthEnv(2, textures=bank, fixation_iterations=2, seed=5)
    copy.load_state_dict(envs[0].state_dict())
    torch.testing.assert_close(copy.defocus_dioptres, envs[0].defocus_dioptres)
    torch.testing.assert_close(observe(copy)["fine"], ours["fine"])


def test_bad_focus_and_aperture_are_refused_by_name(bank):
    env = ActiveDepthEnv(2, textures=bank, fixation_iterations=2)
    for bad in (-1.0, torch.ones(3), float("nan")):
        with pytest.raises(ValueError, match="dioptres"):
            env.set_focus(bad)
    with pytest.raises(ValueError, match="aperture_m"):
        ActiveDepthEnv(1, textures=bank, aperture_m=-0.001)


# -- the reward that prefers focus (aectorch.coding.focus) -------------------------------------------
def test_the_focus_reward_peaks_at_zero_blur_where_the_coding_reward_does_not_on_constructed_images():
    """Pairs of 1/f noise blurred by discs of growing radius: the input's energy and the focus
    reward fall with the blur, while the coder's relative error does not rise with it."""
    from aectorch.coding.encoder import BinocularEncoder, EncoderConfig
    from aectorch.coding.focus import focus_reward, input_energy
    from aectorch.sim import pink_noise_images
    from aectorch.sim.perturbations import blur_margin, defocus

    scale = as_scale("full")
    sharp = pink_noise_images(8, 40 + 8, 40 + 8, generator=torch.Generator().manual_seed(3))
    encoder = BinocularEncoder(EncoderConfig(num_atoms=64), ("full",), generator=torch.Generator().manual_seed(0))
    rewards, coding, energies = [], [], []
    for radius in (0.0, 0.8, 1.5, 2.5, 3.5):
        m = blur_margin(radius)
        image = defocus(sharp, radius)[:, 4 - m:4 - m + 40, 4 - m:4 - m + 40]
        pair = torch.stack((image, image), 1)
        out = encoder.encode({"full": pair})
        energy = input_energy(pair, scale)
        energies.append(float(energy.mean()))
        rewards.append(float(focus_reward([energy], [out.codes[0].error]).mean()))
        coding.append(float(out.reward.mean()))
    assert rewards == sorted(rewards, reverse=True) and energies == sorted(energies, reverse=True)
    assert max(coding) > coding[0]  # the coding reward alone prefers some blur
    with pytest.raises(ValueError, match="pair must be \\[B, 2, 40, 40\\]"):
        input_energy(torch.rand(1, 2, 16, 16), scale)
