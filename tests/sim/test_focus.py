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
    disc (which tests/sim/test_perturbations.py checks against the sharp image convolved with it)."""
    distances = torch.tensor([1.0, 2.0, 3.0])
    env = ActiveDepthEnv(3, protocol=TrialProtocol(fixation_iterations=2), textures=bank, distances_m=[1.0, 2.0, 3.0],
                         seed=0)
    env.set_trial(torch.tensor([0, 1, 2]), distances)
    focus = torch.stack((1.0 / distances + torch.tensor([2.0, 1.0, 0.5]), 1.0 / distances), -1)  # left eye off
    env.set_focus(focus)
    blurred = observe(env)
    arcmin = DEFAULT_APERTURE_M * torch.tensor([2.0, 1.0, 0.5]) * 180 * 60 / math.pi
    assert abs(float(arcmin[2]) - 27.5) < 0.1  # 16 mm x 0.5 D = 8 mrad
    for b in range(3):
        alone = ActiveDepthEnv(1, protocol=TrialProtocol(fixation_iterations=2), textures=bank,
                               distances_m=[1.0, 2.0, 3.0], seed=0)
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
    kwargs = dict(textures=bank, seed=4)
    today = observe(ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), **kwargs))
    pinhole = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2, aperture_m=0.0), **kwargs)
    pinhole.set_focus(0.0)  # focused at infinity, but a pinhole
    focused = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), **kwargs)
    focused.set_focus(1.0 / focused.distance_m[:, None].expand(2, 2))
    for env in (pinhole, focused):
        for name, image in observe(env).items():
            torch.testing.assert_close(image, today[name], rtol=0, atol=1e-6, msg=name)
    assert not TrialProtocol().moving and ActiveDepthEnv(1, protocol=TrialProtocol(fixation_iterations=2), **kwargs).focus_dioptres is None


def test_both_renderers_blur_alike_and_the_focus_resumes(bank):
    envs = [ActiveDepthEnv(2, protocol=TrialProtocol(renderer=name, fixation_iterations=2), textures=bank, seed=5)
            for name in ("torch", "pyrender")]
    try:
        for env in envs:
            env.set_focus(torch.tensor([[0.0, 1.5], [2.0, 0.2]]))
        ours, theirs = observe(envs[0]), observe(envs[1])
        for name in ours:
            assert (ours[name] - theirs[name]).abs().mean() < 0.01, name
    finally:
        envs[1].close()
    copy = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=bank, seed=5)
    copy.load_state_dict(envs[0].state_dict())
    torch.testing.assert_close(copy.defocus_dioptres, envs[0].defocus_dioptres)
    torch.testing.assert_close(observe(copy)["fine"], ours["fine"])


def test_bad_focus_and_aperture_are_refused_by_name(bank):
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=bank)
    for bad in (-1.0, torch.ones(3), float("nan")):
        with pytest.raises(ValueError, match="dioptres"):
            env.set_focus(bad)
    with pytest.raises(ValueError, match="aperture_m"):
        ActiveDepthEnv(1, protocol=TrialProtocol(aperture_m=-0.001), textures=bank)


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


# -- the accommodation cue --------------------------------------------------------------------------
def _accommodating(**fields):
    textures = torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(2))
    return ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3, accommodation_start_D=0.0, **fields),
                          textures=textures, seed=0)


def test_the_accommodation_cue_is_served_only_when_asked_and_moves_both_eyes_focus():
    plain = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3), textures=torch.rand(3, 64, 64), seed=0)
    assert "accommodation" not in plain.CUES and plain.end_iteration().extra_errors_deg is None
    env = _accommodating()
    assert list(env.CUES) == ["parallax", "stereo", "accommodation"]
    assert torch.equal(env.focus_dioptres, torch.zeros(2, 2))  # each fixation starts at infinity
    per_dioptre = math.degrees(env.aperture_m)  # 16 mm: 0.917 deg of blur per dioptre
    torch.testing.assert_close(env.cue("accommodation").error_deg(), -per_dioptre / env.distance_m)
    env.act("accommodation", torch.tensor([per_dioptre * 0.25, 0.0]))
    torch.testing.assert_close(env.focus_dioptres, torch.tensor([[0.25, 0.25], [0.0, 0.0]]))
    env.hold("accommodation")
    assert float(env.cue("accommodation").error_deg().abs().max()) < 1e-5
    assert float(env.defocus_dioptres.abs().max()) < 1e-5
    info = env.end_iteration()
    assert float(info.errors_deg["accommodation"].abs().max()) < 1e-5
    for _ in range(2):  # the fixation ends; the next starts at infinity again
        info = env.end_iteration()
    assert info.fixation_end and torch.equal(env.focus_dioptres, torch.zeros(2, 2))
    with pytest.raises(ValueError, match="accommodation_start_D needs aperture_m > 0"):
        _accommodating(aperture_m=0.0)


def test_each_eye_accommodates_apart_when_not_yoked():
    env = _accommodating(yoked_accommodation=False)
    assert list(env.CUES)[2:] == ["accommodation", "accommodation_right"]
    per_dioptre = math.degrees(env.aperture_m)
    env.act("accommodation", torch.full((2,), 0.5 * per_dioptre))
    env.act("accommodation_right", torch.full((2,), 0.2 * per_dioptre))
    torch.testing.assert_close(env.focus_dioptres, torch.tensor([[0.5, 0.2], [0.5, 0.2]]))
    env.hold("accommodation_right")
    errors = env.end_iteration().errors_deg
    assert float(errors["accommodation_right"].abs().max()) < 1e-5
    torch.testing.assert_close(errors["accommodation"], (0.5 - 1 / env.distance_m) * per_dioptre)


def test_the_learner_learns_accommodation_with_the_information_reward():
    from aectorch.coding.encoder import EncoderConfig
    from aectorch.coding.focus import focus_reward, input_energy
    from aectorch.framework import CueConfig, JointLearner, LearnerConfig, default_cues

    env = _accommodating()
    small = EncoderConfig(num_atoms=16, lr=0.0)  # no dictionary step: the reward is of the codes seen
    cues = {**default_cues(encoder=small),
            "accommodation": CueConfig(encoder=small, efficiency="information", actions_deg=[-0.2, 0.0, 0.2])}
    learner = JointLearner(LearnerConfig(cues=cues, active_cues=["stereo", "accommodation"]),
                           generator=torch.Generator().manual_seed(0))
    seen = {}
    record = learner.iteration(env, watch=lambda cue, observation: seen.setdefault(cue, observation))
    assert list(record.cues) == ["stereo", "accommodation"] and "accommodation" in record.errors_deg
    cue = learner.accommodation
    out = cue.encoder.encode(seen["accommodation"])
    expected = focus_reward([input_energy(seen["accommodation"][s.name], s) for s in cue.encoder.scales],
                            [c.error for c in out.codes])
    torch.testing.assert_close(record.accommodation.reward, expected)
    assert not torch.allclose(record.accommodation.reward, out.reward, atol=1.0)  # not -sum e
    moved = (record.accommodation.increments_deg / math.degrees(env.aperture_m)).clamp_min(0.0)
    torch.testing.assert_close(env.focus_dioptres, moved[:, None].expand(2, 2))  # its agent moves the focus


def test_the_experiment_adds_the_cue_and_the_evaluation_reports_dioptres_and_pixels():
    from aectorch.evaluation.evaluation import accommodation_report
    from aectorch.runtime.config import ExperimentConfig, to_experiment_config
    from aectorch.runtime.presets import ACCOMMODATION
    from omegaconf import OmegaConf

    nested = {}
    for key, value in ACCOMMODATION.items():  # as Hydra's config group merges it
        *path, last = key.split(".")
        node = nested
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value
    cfg = to_experiment_config(OmegaConf.merge(OmegaConf.structured(ExperimentConfig), nested))
    assert cfg.env.accommodation_start_D == 0.0 and cfg.learner.cues["accommodation"].efficiency == "information"
    assert cfg.learner.cues["accommodation"].features == "none"  # its agent senses the vergence angle and the focus
    assert list(cfg.learner.cues) == ["parallax", "stereo", "accommodation"]
    per_px = 0.2226  # the camera's degrees per pixel (rounded)
    report = accommodation_report(torch.tensor([0.0, 0.1 * per_px, -0.4 * per_px, 2 * per_px]), 0.016)
    assert report["within_0.25px"] == 0.5 and report["within_0.5px"] == 0.75
    assert report["mae_px"] == pytest.approx((0.1 + 0.4 + 2) / 4, rel=1e-3)
    assert report["mae_D"] == pytest.approx(report["mae_px"] * 0.22265 / math.degrees(0.016), rel=2e-3)
