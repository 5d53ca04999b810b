"""Perturbations as data: each kind changes the images or the geometry as specified, in
both renderers; events compose, are checked with errors that name the key, survive a resume
bit-identically and are logged; the recovery read-out; plasticity's floor and raise."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
import torch
import torch.nn.functional as F
from omegaconf import OmegaConf

from aectorch.coding.encoder import BinocularEncoder, EncoderConfig
from aectorch.coding.patches import as_scale
from aectorch.control import ActorCriticConfig, NaturalActorCritic
from aectorch.evaluation import adaptation, recovery_of
from aectorch.runtime import load_checkpoint, run_experiment
from aectorch.runtime.config import to_experiment_config
from aectorch.runtime.presets import REARING
from aectorch.runtime.perturbations import Schedule, resolve_events
from aectorch.sim import ActiveDepthEnv, TrialProtocol, pink_noise_images
from aectorch.sim.perturbations import (
    NEUTRAL, PERTURBATIONS, Optics, blur_margin, defocus, disc_kernel, make_perturbation, orientation_filter,
    scale_contrast,
)

RENDERERS = ["torch", "pyrender"]
SCALES = [as_scale(name) for name in ("wide", "coarse", "fine", "full")]
#: pyrender quantises textures and images to 8 bits
TOLERANCE = {"torch": 1e-5, "pyrender": 3 / 255}


@pytest.fixture(scope="module")
def textures():
    return pink_noise_images(3, 256, 256, generator=torch.Generator().manual_seed(0))


def _env(textures, renderer, **fields):
    return ActiveDepthEnv(2, protocol=TrialProtocol(renderer=renderer, **fields), textures=textures, distances_m=[1.0],
                          seed=1)


def _perturbed(env, kind, params, eye=1):
    env.set_optics(make_perturbation(kind, params).apply(NEUTRAL, eye))
    return env.stereo_observation(SCALES, window=True)


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / (a.norm() * b.norm()))


def _warp(image, theta):
    """``image`` [B, H, W] resampled at ``theta`` [2, 3] (normalised coordinates about the centre)."""
    grid = F.affine_grid(theta.expand(image.shape[0], 2, 3).to(image), (image.shape[0], 1, *image.shape[-2:]),
                         align_corners=False)
    return F.grid_sample(image[:, None], grid, align_corners=False)[:, 0]


def _unchanged_left(base, obs, renderer):
    for name in base:
        assert (obs[name][:, 0] - base[name][:, 0]).abs().max() <= TOLERANCE[renderer], name


# -- each kind, in both renderers ---------------------------------------------------------------
@pytest.mark.parametrize("renderer", RENDERERS)
def test_roll_rotates_the_image_about_its_centre(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    obs = _perturbed(env, "roll", {"deg": 10.0})
    _unchanged_left(base, obs, renderer)
    right, neutral = obs["window"][:, 1], base["window"][:, 1]
    angle = math.radians(10.0)
    # The rolled eye sees the unrolled image turned by 10 deg about its centre (sampling it at
    # positions turned the other way; rows run down).
    turned = _warp(neutral, torch.tensor([[math.cos(angle), -math.sin(angle), 0.0],
                                          [math.sin(angle), math.cos(angle), 0.0]]))
    inner = (slice(None), slice(24, -24), slice(24, -24))
    assert _corr(right[inner], turned[inner]) > 0.97 > _corr(right[inner], neutral[inner]) + 0.1
    env.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_strabismus_offsets_the_eye_and_the_vergence_it_needs(textures, renderer):
    env = _env(textures, renderer)
    base_optimum = env.optimal_right_pan_deg()
    obs = _perturbed(env, "strabismus", {"deg": 2.0})  # the right eye 2 deg inward: toward the robot's left
    twin = _env(textures, renderer)
    twin.set_pan_deg(twin.pan_deg + torch.tensor([0.0, 2.0]))
    expected = twin.stereo_observation(SCALES, window=True)
    for name in obs:
        assert (obs[name] - expected[name]).abs().max() <= TOLERANCE[renderer], name
    torch.testing.assert_close(env.eye_pan_deg, env.pan_deg + torch.tensor([0.0, 2.0]))
    torch.testing.assert_close(env.cue("stereo").to_optimum(), base_optimum - env.pan_deg[:, 1] - 2.0)
    env.apply_pursuit(torch.zeros(2))
    env.apply_vergence(env.cue("stereo").to_optimum())  # the command that puts the squinting eye on target
    assert float(env.end_iteration().vergence_error_deg.abs().max()) < 1e-4
    assert make_perturbation("strabismus", {"deg": 2.0}).apply(NEUTRAL, 0).pan_offset_deg == (-2.0, 0.0)
    env.close(), twin.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_anisometropia_blurs_one_eye_by_its_disc(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    arcmin = 120.0
    obs = _perturbed(env, "anisometropia", {"arcmin": arcmin})
    _unchanged_left(base, obs, renderer)
    radius = arcmin / 2 / (60 * env.camera.degrees_per_pixel)  # 4.5 full-resolution pixels
    right, neutral = obs["window"][:, 1], base["window"][:, 1]
    # The blurred eye is the sharp one convolved with the disc (away from the crop's border).
    margin = blur_margin(radius)
    expected = defocus(neutral, radius)
    assert (right[:, margin:-margin, margin:-margin] - expected).abs().max() <= 2 * TOLERANCE[renderer]
    for name in ("fine", "full"):  # the fine scales lose their detail; the means stay
        detail = lambda x: (x[..., 1:] - x[..., :-1]).abs().mean()  # noqa: E731
        assert detail(obs[name][:, 1]) < 0.75 * detail(base[name][:, 1])
        torch.testing.assert_close(obs[name][:, 1].mean(), base[name][:, 1].mean(), atol=0.01, rtol=0)
    env.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_refractive_error_is_the_world_s_defocus_of_one_eye(textures, renderer):
    env = ActiveDepthEnv(2, protocol=TrialProtocol(renderer=renderer), textures=textures, distances_m=[1.0, 2.5],
                         seed=1)
    base = env.stereo_observation(SCALES, window=True)
    obs = _perturbed(env, "refractive_error", {"dioptres": 2.0})
    _unchanged_left(base, obs, renderer)
    assert (obs["fine"][:, 1] - base["fine"][:, 1]).abs().max() > 0.02  # blurred where the coder sees it
    # The oracle: the eye focused 2 D nearer than each environment's object (the world's defocus).
    near = 1.0 / env.object_distance_m
    env.set_optics(NEUTRAL)
    env.set_focus(torch.stack((near, near + 2.0), dim=-1))
    expected = env.stereo_observation(SCALES, window=True)
    for name in obs:
        assert (obs[name] - expected[name]).abs().max() <= TOLERANCE[renderer], name
    env.close()


def test_refractive_error_adds_to_the_focus_and_needs_an_aperture(textures):
    env = ActiveDepthEnv(2, textures=textures, distances_m=[1.0, 2.5], seed=1)
    near = 1.0 / env.object_distance_m
    env.set_optics(make_perturbation("refractive_error", {"dioptres": 2.0}).apply(NEUTRAL, 1))
    torch.testing.assert_close(env.defocus_dioptres, torch.tensor([[0.0, 2.0], [0.0, 2.0]]))
    # With accommodation the error adds to the eye's focus, after its stop at 0 D (infinity).
    env.set_focus(0.0)
    torch.testing.assert_close(env.defocus_dioptres, torch.stack((-near, 2.0 - near), dim=-1))
    env.set_optics(make_perturbation("refractive_error", {"dioptres": -1.0}).apply(NEUTRAL, 0))
    torch.testing.assert_close(env.defocus_dioptres, torch.stack((-1.0 - near, -near), dim=-1))
    pinhole = ActiveDepthEnv(2, protocol=TrialProtocol(aperture_m=0.0), textures=textures, distances_m=[1.0], seed=1)
    with pytest.raises(ValueError, match=r"refraction_D=\(0.0, 2.0\).*aperture_m=0"):
        pinhole.set_optics(make_perturbation("refractive_error", {"dioptres": 2.0}).apply(NEUTRAL, 1))
    env.close(), pinhole.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_monocular_deprivation_scales_one_eye_s_contrast(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    half = _perturbed(env, "monocular_deprivation", {"contrast": 0.5})
    grey = _perturbed(env, "monocular_deprivation", {})
    _unchanged_left(base, grey, renderer)
    for name in base:
        neutral = base[name][:, 1]
        mean = neutral.mean(dim=(-2, -1), keepdim=True)
        assert (half[name][:, 1] - (mean + 0.5 * (neutral - mean))).abs().max() <= TOLERANCE[renderer], name
        assert float(grey[name][:, 1].std(dim=(-2, -1)).max()) < 1e-5, name  # uniform grey
        torch.testing.assert_close(grey[name][:, 1].mean(dim=(-2, -1)), mean[..., 0, 0])
    env.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_aniseikonia_magnifies_one_eye_s_image(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    obs = _perturbed(env, "aniseikonia", {"percent": 10.0})
    _unchanged_left(base, obs, renderer)
    right, neutral = obs["window"][:, 1], base["window"][:, 1]
    zoomed = _warp(neutral, torch.tensor([[1 / 1.1, 0.0, 0.0], [0.0, 1 / 1.1, 0.0]]))
    inner = (slice(None), slice(8, -8), slice(8, -8))
    assert _corr(right[inner], zoomed[inner]) > 0.98 > _corr(right[inner], neutral[inner]) + 0.05
    env.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_camera_shift_moves_one_camera(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    # Up by 4 pixels' worth at the plane's 1 m: the image moves down by 4 rows.
    rise = 4.0 / env.camera.focal_px * 1.0
    obs = _perturbed(env, "camera_shift", {"z_m": rise})
    _unchanged_left(base, obs, renderer)
    right, neutral = obs["window"][:, 1], base["window"][:, 1]
    assert (right[:, 4:] - neutral[:, :-4]).abs().max() <= 5e-3 + TOLERANCE[renderer]
    # Sideways, the ground truth follows the camera: the optimal pans are those of its new place.
    env.set_optics(make_perturbation("camera_shift", {"y_m": 0.01}).apply(NEUTRAL, 1))
    moved = ActiveDepthEnv(2, textures=textures, distances_m=[1.0], seed=1,
                           head=replace_eye(env.head, 1, 0.01))
    torch.testing.assert_close(env.optimal_right_pan_deg(), moved.optimal_right_pan_deg())
    env.close()


@pytest.mark.parametrize("renderer", RENDERERS)
def test_vertical_misalignment_turns_one_eye_up_and_no_command_undoes_it(textures, renderer):
    env = _env(textures, renderer)
    base = env.stereo_observation(SCALES, window=True)
    optimum = env.optimal_right_pan_deg()
    # Up by 4 pixels' worth: the right image moves down by 4 rows, the left stays.
    deg = math.degrees(math.atan(4.0 / env.camera.focal_px))
    obs = _perturbed(env, "vertical_misalignment", {"deg": deg})
    _unchanged_left(base, obs, renderer)
    right, neutral = obs["window"][:, 1], base["window"][:, 1]
    inner = (slice(None), slice(8, -8), slice(8, -8))
    moved = right[:, 4:][inner]
    assert _corr(moved, neutral[:, :-4][inner]) > 0.995 > _corr(right[inner], neutral[inner]) + 0.05
    assert (right[:, 4:] - neutral[:, :-4])[inner].abs().mean() <= 5e-3 + TOLERANCE[renderer]
    # The horizontal ground truth is the unperturbed robot's; down is the opposite turn.
    torch.testing.assert_close(env.optimal_right_pan_deg(), optimum)
    down = _perturbed(env, "vertical_misalignment", {"deg": -deg})["window"][:, 1]
    assert _corr(down[:, :-4][inner], neutral[:, 4:][inner]) > 0.995
    both = make_perturbation("vertical_misalignment", {"deg": 1.0})
    assert both.apply(both.apply(NEUTRAL, 1), 0).elevation_offset_deg == (1.0, 1.0)
    assert both.describe() == "vertical misalignment 1 deg up"
    assert not both.apply(NEUTRAL, 1).mounting_neutral
    # A checkpoint's optics from before the field existed read as no offset.
    old = {k: v for k, v in NEUTRAL.to_dict().items() if k != "elevation_offset_deg"}
    assert Optics.from_dict(old) == NEUTRAL
    env.close()


def replace_eye(head, eye, dy):
    """A copy of ``head`` with eye ``eye``'s centre ``dy`` metres further left."""
    import copy

    moved = copy.deepcopy(head)
    moved._eye_xyz = tuple(tuple(v + (dy if i == 1 else 0.0) for i, v in enumerate(xyz)) if e == eye else xyz
                           for e, xyz in enumerate(head._eye_xyz))
    return moved


@pytest.mark.parametrize("renderer", RENDERERS)
def test_orientation_rearing_filters_the_world(textures, renderer):
    env = _env(textures, renderer)
    grad = lambda x: ((x[..., :, 1:] - x[..., :, :-1]).pow(2).mean(), (x[..., 1:, :] - x[..., :-1, :]).pow(2).mean())  # noqa: E731
    across, down = grad(_perturbed(env, "orientation_rearing", {"orientation": "vertical"}, eye=None)["window"])
    assert across > 8 * down  # vertical stripes: the image changes across, not down
    across, down = grad(_perturbed(env, "orientation_rearing", {"orientation": "horizontal"}, eye=None)["window"])
    assert down > 8 * across
    env.set_optics(NEUTRAL)
    across, down = grad(env.stereo_observation()["window"])
    assert 0.5 < across / down < 2
    env.close()


def test_oblique_rearing_keeps_the_stripes_rising_to_the_right():
    y, x = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    rising = 0.5 + 0.25 * torch.sin((x - (63 - y)) * 0.7)  # constant along x = 63 - y: "/" with rows down
    falling = 0.5 + 0.25 * torch.sin((x - y) * 0.7)
    both = (rising + falling) / 2
    out = orientation_filter(both, [(45.0, 30.0)])
    assert _corr(out, rising) > 0.95 and abs(_corr(out, falling)) < 0.1


def test_the_image_functions():
    kernel = disc_kernel(1.5)
    assert kernel.shape == (5, 5) and math.isclose(float(kernel.sum()), 1.0, rel_tol=1e-6)
    assert torch.equal(disc_kernel(0.0), torch.ones(1, 1)) and blur_margin(2.6) == 3 and blur_margin(0.2) == 1
    # A disc within the centre pixel blurs too, more as it grows (the pixels' area averages): the
    # next column's share is the mean over the disc of the tent's x+ (the rows' tents sum to 1),
    # in closed form 2r / (3 pi) for a disc of radius r within the centre pixel.
    centres = [float(disc_kernel(r)[1, 1]) for r in (0.08, 0.1, 0.25, 0.4)]
    assert centres == sorted(centres, reverse=True) and centres[0] < 1.0
    for r in (0.1, 0.4):
        assert math.isclose(float(disc_kernel(r, subsamples=256)[:, 2].sum()), 2 * r / (3 * math.pi), rel_tol=0.02)
    impulse = torch.zeros(9, 9)
    impulse[4, 4] = 1
    expected = torch.zeros(5, 5)
    expected[:, :] = kernel  # the disc is symmetric: convolution and correlation agree
    torch.testing.assert_close(defocus(impulse, 1.5), expected)
    images = torch.rand(2, 5, 5)
    torch.testing.assert_close(scale_contrast(images, 1.0), images)
    assert float(scale_contrast(images, 0.0).std(dim=(-2, -1)).max()) < 1e-6


# -- composition, the schedule, errors ---------------------------------------------------------
def test_kinds_are_registered_by_name_and_compose():
    assert sorted(PERTURBATIONS) == sorted(["roll", "strabismus", "anisometropia", "refractive_error",
                                            "monocular_deprivation", "aniseikonia", "orientation_rearing",
                                            "camera_shift", "vertical_misalignment"])
    events = resolve_events([
        {"kind": "roll", "start": 10, "eye": "right", "params": {"deg": 3}},
        {"kind": "roll", "start": 20, "end": 40, "eye": "both", "params": {"deg": 2}},
        {"kind": "monocular_deprivation", "start": 0.5, "eye": "left", "params": {"contrast": 0.5}},
        {"kind": "monocular_deprivation", "start": 60, "eye": "left", "params": {"contrast": 0.5}},
        {"kind": "orientation_rearing", "start": 0, "params": {"orientation": 30, "bandwidth_deg": 20}},
        {"kind": "refractive_error", "start": 70, "end": 90, "eye": "both", "params": {"dioptres": 1.5}},
        {"kind": "refractive_error", "start": 80, "eye": "right", "params": {"dioptres": -0.5}},
    ], 100)
    schedule = Schedule(events)
    assert schedule.optics_at(9).roll_deg == (0.0, 0.0) and schedule.optics_at(10).roll_deg == (0.0, 3.0)
    assert schedule.optics_at(25).roll_deg == (2.0, 5.0) and schedule.optics_at(40).roll_deg == (0.0, 3.0)
    assert schedule.optics_at(55).contrast == (0.5, 1.0) and schedule.optics_at(60).contrast == (0.25, 1.0)
    assert schedule.optics_at(0).orientation_bands == ((30.0, 20.0),)
    assert schedule.optics_at(85).refraction_D == (1.5, 1.0) and schedule.optics_at(95).refraction_D == (0.0, -0.5)
    assert schedule.changes == [0, 10, 20, 40, 50, 60, 70, 80, 90]
    assert schedule.stretches(100)[-1] == (90, 100) and events[6].label == "right eye: refractive error -0.5 D"
    assert events[1].label == "both eyes: roll 2 deg" and events[4].eyes == (None,)
    state = Optics.from_dict(json.loads(json.dumps(schedule.optics_at(85).to_dict())))
    assert state == schedule.optics_at(85)


@pytest.mark.parametrize("entry, message", [
    ({"kind": "rol", "start": 1, "eye": "right"}, r"perturbations\[0\]\.kind must be one of 'roll'"),
    ({"kind": "roll", "start": 12, "eye": "right", "params": {"deg": 1}},
     r"perturbations\[0\]\.start=12 is at or after the run's end \(train.iterations=12\)"),
    ({"kind": "roll", "start": 2, "end": 13, "eye": "right", "params": {"deg": 1}}, r"perturbations\[0\]\.end=13"),
    ({"kind": "roll", "start": 1.5, "eye": "right", "params": {"deg": 1}}, r"perturbations\[0\]\.start must be"),
    ({"kind": "roll", "start": 2, "eye": "middle", "params": {"deg": 1}},
     r"perturbations\[0\]\.eye='middle' is not an eye of the robot: left, right or both"),
    ({"kind": "roll", "start": 2, "params": {"deg": 1}}, r"perturbations\[0\]\.eye is missing"),
    ({"kind": "orientation_rearing", "start": 2, "eye": "left"}, r"perturbations\[0\]\.eye='left': orientation_rearing"),
    ({"kind": "roll", "start": 2, "eye": "left", "params": {"degrees": 1}}, r"perturbations\[0\]\.params\.degrees is not"),
    ({"kind": "roll", "start": 2, "eye": "left"}, r"perturbations\[0\]\.params\.deg is missing"),
    ({"kind": "aniseikonia", "start": 2, "eye": "left", "params": {"percent": -100}},
     r"perturbations\[0\]\.params\.percent must be"),
    ({"kind": "orientation_rearing", "start": 2, "params": {"orientation": "diagonal"}},
     r"perturbations\[0\]\.params\.orientation must be one of"),
    ({"kind": "refractive_error", "start": 2, "eye": "right", "params": {"dioptres": float("nan")}},
     r"perturbations\[0\]\.params\.dioptres must be"),
    ({"kind": "refractive_error", "start": 2, "eye": "right"}, r"perturbations\[0\]\.params\.dioptres is missing"),
])
def test_bad_events_get_an_error_naming_the_key(entry, message):
    with pytest.raises(ValueError, match=message):
        to_experiment_config({"train": {"iterations": 12}, "perturbations": [entry]})


def test_a_refractive_error_needs_an_aperture():
    event = {"kind": "refractive_error", "start": 2, "eye": "right", "params": {"dioptres": 2.0}}
    with pytest.raises(ValueError, match=r"perturbations\[1\] is a refractive_error.*env.aperture_m=0"):
        to_experiment_config({"env": {"aperture_m": 0.0}, "train": {"iterations": 12},
                              "perturbations": [{**event, "kind": "roll", "params": {"deg": 1}}, event]})


# -- the environment's state --------------------------------------------------------------------
def test_env_state_holds_the_optics_and_the_first_image_s(textures):
    env = _env(textures, "torch", fixation_iterations=4)
    env.parallax_observation(SCALES)  # the fixation's first image: taken unperturbed
    optics = Schedule(resolve_events([
        {"kind": "roll", "start": 0, "eye": "left", "params": {"deg": 4}},
        {"kind": "anisometropia", "start": 0, "eye": "left", "params": {"arcmin": 60}},
        {"kind": "orientation_rearing", "start": 0}], 2)).optics_at(0)
    env.set_optics(optics)
    first = env.parallax_observation(SCALES)
    state = env.state_dict()
    assert state["first_optics"] == NEUTRAL.to_dict() and Optics.from_dict(state["optics"]) == optics
    twin = _env(textures, "torch", fixation_iterations=4)
    twin.load_state_dict(state)
    assert twin.optics == optics
    again = twin.parallax_observation(SCALES)
    for name in first:
        assert torch.equal(first[name], again[name]), name
    old = {**state, "optics": None, "first_optics": None}  # before optics were data (as migrated)
    twin.load_state_dict(old)
    assert twin.optics == replace(NEUTRAL, roll_deg=(4.0, 0.0))


# -- a run: logged, resumed bit-identically ------------------------------------------------------
TINY = [
    "env.num_envs=3", "env.fixation_iterations=3", "env.distances_m=[1.0,2.0]",
    "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16",
    "learner.depth_every_trials=10", "train.iterations=14", "train.log_every=2", "train.checkpoint_every=4",
    "train.progress=false", "train.figures=false", "train.tensorboard=false", "eval.enabled=false",
    "train.recent_window=6",
]
#: Events that start and end inside fixations, compose, and change the world mid-run.
EVENTS = [
    {"kind": "roll", "start": 4, "eye": "right", "params": {"deg": 5}},
    {"kind": "anisometropia", "start": 7, "end": 11, "eye": "left", "params": {"arcmin": 90}},
    {"kind": "orientation_rearing", "start": 8, "params": {"orientation": "vertical"}},
    {"kind": "strabismus", "start": 0.5, "eye": "both", "params": {"deg": 1}},
]


@pytest.fixture(scope="module")
def folder(tmp_path_factory, textures):
    """Three small textures as image files (a run's textures are a folder)."""
    from PIL import Image

    path = tmp_path_factory.mktemp("textures")
    for i, texture in enumerate(textures[:, :64, :64]):
        Image.fromarray((texture * 255).round().to(torch.uint8).numpy()).save(path / f"t{i}.png")
    return path


def _cfg(folder, *extra, events=EVENTS):
    node = OmegaConf.merge(OmegaConf.from_dotlist([*TINY, f"env.textures={folder}", *extra]),
                           {"perturbations": events, "plasticity": {"raise_to": 0.5}})
    return to_experiment_config(node)


def _lines(run):
    return [{k: v for k, v in json.loads(line).items() if k != "elapsed_s"}
            for line in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.integration
def test_events_are_logged_and_survive_a_resume_bit_identically(tmp_path, folder):
    from tests.runtime.test_train import _assert_same_state

    straight = tmp_path / "straight"
    run_experiment(_cfg(folder), straight)
    half = tmp_path / "half"

    def fail(done, record):
        if done == 9:
            raise RuntimeError("stopped")

    # Stopped in iteration 10: checkpoint 8 holds a fixation whose first image (iteration 6) was taken
    # before the events of iteration 7; the world changes in the first iteration resumed.
    with pytest.raises(RuntimeError, match="stopped"):
        run_experiment(_cfg(folder), half, callback=fail)
    assert load_checkpoint(half / "checkpoint.pt")["env"]["first_optics"]["roll_deg"] == [0.0, 5.0]
    run_experiment(_cfg(folder, f"train.resume={half}"), tmp_path / "ignored")
    a, b = load_checkpoint(straight / "checkpoint.pt"), load_checkpoint(half / "checkpoint.pt")
    _assert_same_state(a["learner"], b["learner"])
    _assert_same_state(a["env"], b["env"])
    assert _lines(straight) == _lines(half)
    lines = _lines(straight)
    assert lines[1]["perturbations"] == [] and lines[2]["perturbations"] == ["right eye: roll 5 deg"]
    assert lines[4]["perturbations"] == ["right eye: roll 5 deg", "left eye: anisometropia 90 arcmin",
                                         "orientation rearing vertical +-15 deg", "both eyes: strabismus 1 deg inward"]
    assert {"vergence_recent_deg", "vergence_recent_1px", "depth_recent_m"} <= set(lines[-1])
    summary = json.loads((straight / "summary.json").read_text())["perturbation"]
    assert [e["start"] for e in summary["events"]] == [4, 7, 8, 7]
    assert set(summary["recovery"]) == {"right eye: roll 5 deg",
                                        "left eye: anisometropia 90 arcmin + both eyes: strabismus 1 deg inward",
                                        "orientation rearing vertical +-15 deg",
                                        "left eye: anisometropia 90 arcmin ends"}
    assert summary["plasticity"]["raise_to"] == 0.5
    # The code at the correction, read in the iteration the resumed run trained through again.
    assert list(summary["code"]) == ["left eye: anisometropia 90 arcmin ends"]
    assert summary["code"] == json.loads((half / "summary.json").read_text())["perturbation"]["code"]
    assert summary["code"]["left eye: anisometropia 90 arcmin ends"]["iteration"] == 11


@pytest.mark.integration
def test_the_code_at_a_correction_is_the_code_of_a_run_that_stops_there(tmp_path, folder):
    """A run corrected at iteration 3 records the code it had then: that of the same run stopped
    at 3 (its final code), and not the code at its own end."""
    event = {"kind": "refractive_error", "start": 0, "end": 3, "eye": "right", "params": {"dioptres": 2.0}}
    run_experiment(_cfg(folder, "train.iterations=6", events=[event]), tmp_path / "corrected")
    run_experiment(_cfg(folder, "train.iterations=3", events=[event]), tmp_path / "stopped")
    corrected, stopped = (json.loads((tmp_path / name / "summary.json").read_text()) for name in ("corrected", "stopped"))
    at_end = corrected["perturbation"]["code"]["right eye: refractive error +2 D ends"]
    assert at_end["iteration"] == 3 and at_end["code"] == stopped["code"] != corrected["code"]
    assert "code" not in stopped["perturbation"]  # its event ends with the run: no correction trained


@pytest.mark.integration
def test_every_rearing_condition_runs(tmp_path, folder):
    """``rearing=<name>``: each condition's events run through a tiny training (smoke)."""
    from hydra import compose, initialize

    from aectorch.runtime.store import register_configs

    register_configs()
    small = [*TINY, f"env.textures={folder}", "env.num_envs=2", "env.fixation_iterations=2", "train.iterations=4"]
    with initialize(version_base=None, config_path=None):
        plain = to_experiment_config(compose(config_name="train", overrides=small))
        assert plain.learner.cues["stereo"].symmetry == "swap" and plain.learner.cues["stereo"].encoder.decay == 500
        ran = set()
        for name in REARING:
            cfg = to_experiment_config(compose(config_name="train", overrides=[*small, f"rearing={name}"]))
            assert len(cfg.events()) == len(REARING[name])
            # Every condition rears a plastic stereo code without the swap symmetry (REARING_SETTINGS).
            stereo = cfg.learner.cues["stereo"]
            assert (stereo.symmetry, stereo.encoder.decay, stereo.encoder.lr, cfg.train.keep_best) == (None, None, 16.0, False)
            assert (stereo.encoder.close_at, stereo.encoder.close_over) == (1200, 600)  # the critical period
            # Strabismus as the lineage has it: a vergence range that cannot undo the squint.
            squint = name.startswith("strabismus")
            assert list(cfg.env.vergence_range_deg) == ([0.0, 11.4] if squint else [-2.0, 40.0]), name
            kinds = tuple((e["kind"], "end" in e) for e in REARING[name])
            if kinds not in ran:  # one run per kind of events (early and late corrections run alike)
                ran.add(kinds)
                run_experiment(cfg, tmp_path / name)
                assert (tmp_path / name / "checkpoint.pt").is_file()


# -- the read-out, plasticity -------------------------------------------------------------------
def test_the_recovery_read_out():
    values = [0.1, 0.1, 0.5, 0.3, 0.11, 0.1, 0.4, 0.4]
    within = [1.0, 0.96, 0.2, 0.6, 0.97, 0.99, 0.5, 0.5]
    lines = [{"iteration": 10 * i, "vergence_recent_deg": v, "vergence_recent_1px": w, "depth_recent_m": 0.05,
              "vergence_mae_deg": 0.2} for i, (v, w) in enumerate(zip(values, within))]
    out = recovery_of(lines, "vergence_recent_deg", 10, 50, within_key="vergence_recent_1px")
    assert (out["before"], out["peak"], out["peak_ratio"], out["peak_iteration"]) == (0.1, 0.5, 5.0, 20)
    assert out["iterations_to_recover"] == 30 and out["final"] == 0.1
    assert (out["within_1px_before"], out["within_1px_min"], out["iterations_to_95pct"]) == (0.96, 0.2, 30)
    never = recovery_of(lines, "vergence_recent_deg", 50, 70, within_key="vergence_recent_1px")
    assert never["iterations_to_recover"] is None and never["iterations_to_95pct"] is None
    both = adaptation(lines, [(10, 50, "a"), (50, 70, "b")])
    assert both["a"]["vergence"] == out and both["a"]["depth"]["peak_ratio"] == 1.0


def test_plasticity_floor_and_raise():
    config = EncoderConfig(lr=0.1, decay=500, floor=0.5)
    assert config.rate(0) == 0.1 and config.rate(300) > 0.05 and config.rate(10_000) == 0.05
    encoder = BinocularEncoder(EncoderConfig(num_atoms=16, decay=500), ["coarse"], generator=torch.Generator())
    encoder.steps = 2000
    assert encoder.rate() == pytest.approx(0.02)
    assert encoder.raise_rate(0.5) == pytest.approx(0.05, rel=1e-2) and encoder.steps == 500
    assert encoder.raise_rate(0.1) == pytest.approx(0.05, rel=1e-2)  # a higher rate stays
    agent = NaturalActorCritic(4, (-1.0, 0.0, 1.0), ActorCriticConfig(actor_decay=100), generator=torch.Generator())
    agent.step_count.fill_(900.0)
    assert agent.raise_rate(0.5) == pytest.approx(0.5) and float(agent.step_count) == pytest.approx(100.0)
    with pytest.raises(ValueError, match="floor"):
        EncoderConfig(floor=0.0)
    with pytest.raises(ValueError, match="plasticity.raise_to"):
        to_experiment_config({"plasticity": {"raise_to": 2}})


def test_a_critical_period_closes_the_code_and_leaves_it_as_it_was():
    config = EncoderConfig(num_atoms=16, lr=2.0, decay=None, close_at=3, close_over=2)
    assert [config.rate(t) for t in range(6)] == [2.0, 2.0, 2.0, 2.0, 1.0, 0.0]
    assert EncoderConfig(lr=2.0, decay=None, close_at=3, floor=0.1).rate(50) == pytest.approx(0.2)  # adult plasticity
    assert EncoderConfig(lr=0.1, decay=100, close_at=0).rate(0) == 0.0  # closed from the start
    encoder = BinocularEncoder(config, ["coarse"], generator=torch.Generator().manual_seed(0))
    images = torch.rand(2, 2, 160, 160, generator=torch.Generator().manual_seed(1))
    atoms = []
    for _ in range(7):
        with torch.no_grad():
            encoder.learn_(encoder(*images))
        atoms.append(encoder.dictionaries["coarse"].atoms.detach().clone())
    assert not torch.equal(atoms[3], atoms[4])  # the last step of the closing period still learns
    assert all(torch.equal(atoms[4], later) for later in atoms[5:])  # closed: the code stays
    encoder.raise_rate(1.0)  # raising winds the clock back: the period opens again
    assert encoder.steps == 0 and encoder.rate() == 2.0
    for bad, key in (({"close_at": -1}, "close_at"), ({"close_over": 1.5}, "close_over")):
        with pytest.raises((ValueError, TypeError), match=key):
            EncoderConfig(**bad)


@pytest.mark.integration
def test_unperturbed_runs_log_what_they_did(tmp_path, folder):
    """No perturbation: no new keys in metrics.jsonl, no perturbation in the summary."""
    cfg = _cfg(folder, "train.iterations=4", events=[])
    run_experiment(cfg, tmp_path / "run")
    lines = _lines(tmp_path / "run")
    assert not any("recent" in k or k == "perturbations" for k in lines[-1])
    assert "perturbation" not in json.loads((tmp_path / "run" / "summary.json").read_text())
