"""Cameras, the two plane renderers and ActiveDepthEnv: geometry, agreement and ground truth."""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys

import pytest
import torch

from aectorch.coding import extract_patches
from aectorch.sim import (
    ActiveDepthEnv,
    HOAP3Head,
    PinholeCamera,
    PixelWindow,
    PlaneScene,
    TextureBank,
    TorchPlaneRenderer,
    render_planes,
    sample_bilinear,
)
from aectorch.sim.protocol import TrialProtocol

torch.set_num_threads(1)
CAMERA = PinholeCamera()
CROPS = CAMERA.central_window(128)


def quantised(x: torch.Tensor) -> torch.Tensor:
    """Textures as pyrender stores them (8 bits), so both renderers see the same texels."""
    return (x * 255).round() / 255


@pytest.fixture(scope="module")
def bank():
    return TextureBank.procedural(3, size=(512, 512), seed=7)


@pytest.fixture(scope="module")
def scene(bank):
    background = quantised(TextureBank.procedural(1, size=(256, 256), seed=8).textures[0])
    return PlaneScene(quantised(bank.textures), background)


@pytest.fixture(scope="module")
def head():
    return HOAP3Head()


@pytest.fixture(scope="module")
def pyrender_renderer(scene):
    from aectorch.sim import PyrenderRenderer

    renderer = PyrenderRenderer(scene)
    yield renderer
    renderer.close()


def agreement_poses(head, dtype=torch.float32):
    """Shifted bodies and panned (and one rolled) eyes looking at planes at 1, 2 and 3 m."""
    shift = torch.tensor([0.1, -0.1, 0.05], dtype=dtype)
    pan = torch.tensor([[-5.7, -2.3], [2.9, 4.6], [-1.0, 0.3]], dtype=dtype)
    roll = torch.tensor([[0.0, 0.0], [0.0, 0.0], [3.0, -2.0]], dtype=dtype)
    poses = head.to(dtype=dtype).camera_poses(shift, pan, roll, convention="opengl")
    plane_x = torch.tensor([1.0, 2.0, 3.0], dtype=dtype) + head.eye_x_m
    return poses, plane_x


# --- camera -------------------------------------------------------------------------------------


def test_camera_defaults_are_the_aec_convention():
    assert CAMERA.focal_px == pytest.approx(257.34, abs=0.005)
    assert CAMERA.degrees_per_pixel == pytest.approx(0.2226, abs=5e-5)
    assert CAMERA.principal_point == (160.0, 120.0)


def test_camera_windows_match_extract_patches_crops():
    image = torch.rand(1, 240, 320)
    top, left, h, w = CROPS
    crop = image[:, top : top + h, left : left + w]
    for scale in ("coarse", "fine"):
        torch.testing.assert_close(
            extract_patches(image, image, scale), extract_patches(crop, crop, scale)
        )


def test_camera_rays_project_back_to_pixel_centres():
    rays = CAMERA.rays(PixelWindow(10, 20, 3, 4), dtype=torch.float64)
    cx, cy = CAMERA.principal_point
    cols = rays[..., 0] * CAMERA.focal_px + cx - 0.5
    rows = rays[..., 1] * CAMERA.focal_px + cy - 0.5
    torch.testing.assert_close(cols[0], torch.arange(20, 24, dtype=torch.float64))
    torch.testing.assert_close(rows[:, 0], torch.arange(10, 13, dtype=torch.float64))


@pytest.mark.parametrize(
    "kwargs, match",
    [({"width": 0}, "width"), ({"vfov_deg": 180.0}, "vfov_deg"), ({"cx": float("nan")}, "cx")],
)
def test_camera_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PinholeCamera(**kwargs)


def test_window_outside_the_image_is_rejected():
    with pytest.raises(ValueError, match="window"):
        CAMERA.check_window(PixelWindow(200, 0, 128, 128))


# --- torch renderer -----------------------------------------------------------------------------


def test_sample_bilinear_matches_grid_sample_border():
    textures = torch.rand(2, 7, 9, dtype=torch.float64)
    u = torch.rand(2, 5, 6, dtype=torch.float64) * 11 - 1  # beyond both edges
    v = torch.rand(2, 5, 6, dtype=torch.float64) * 9 - 1
    index = torch.tensor([1, 0])
    ours = sample_bilinear(textures, index, u, v)
    grid = torch.stack((2 * u / 9 - 1, 2 * v / 7 - 1), dim=-1)
    oracle = torch.nn.functional.grid_sample(
        textures[index, None], grid, mode="bilinear", padding_mode="border", align_corners=False
    )[:, 0]
    torch.testing.assert_close(ours, oracle)


def test_torch_renderer_maps_a_ramp_like_the_pinhole_model(head):
    """A horizontal ramp texture: each column's value follows from the pinhole projection."""
    width_px = 600
    ramp = ((torch.arange(width_px, dtype=torch.float64) + 0.5) / width_px).expand(300, width_px)
    scene = PlaneScene(ramp[None].clone(), torch.zeros(4, 4, dtype=torch.float64), object_width_m=3.0)
    shift = torch.tensor([0.0], dtype=torch.float64)
    pan = torch.zeros(1, 2, dtype=torch.float64)
    poses = head.to(dtype=torch.float64).camera_poses(shift, pan)
    d = 2.0
    image = render_planes(poses[:, :1], torch.tensor([head.eye_x_m + d], dtype=torch.float64),
                          torch.tensor([0]), scene, CAMERA, CROPS)[0, 0]
    # column c looks at y = y_eye - d (c + 0.5 - cx) / f; the ramp is 0 at y = +1.5, 1 at -1.5.
    cols = torch.arange(CROPS.left, CROPS.left + CROPS.width, dtype=torch.float64)
    y = 0.03 - d * (cols + 0.5 - CAMERA.principal_point[0]) / CAMERA.focal_px
    expected = (1.5 - y) / 3.0
    torch.testing.assert_close(image[0], expected, atol=1e-9, rtol=0)
    torch.testing.assert_close(image[-1], expected, atol=1e-9, rtol=0)


def test_torch_renderer_window_is_a_crop_of_the_full_frame(scene, head):
    poses, plane_x = agreement_poses(head, torch.float64)
    index = torch.tensor([0, 1, 2])
    scene64 = PlaneScene(scene.textures.double(), scene.background.double())
    full = render_planes(poses, plane_x, index, scene64, CAMERA)
    crop = render_planes(poses, plane_x, index, scene64, CAMERA, CROPS)
    top, left, h, w = CROPS
    torch.testing.assert_close(crop, full[..., top : top + h, left : left + w])


def test_torch_renderer_is_differentiable():
    textures = torch.rand(1, 6, 8, dtype=torch.float64, requires_grad=True)
    scene = PlaneScene(textures.detach(), torch.rand(4, 4, dtype=torch.float64), object_width_m=0.5)
    head = HOAP3Head(dtype=torch.float64)
    plane_x = torch.tensor([1.2], dtype=torch.float64, requires_grad=True)
    poses = head.camera_poses(torch.zeros(1, dtype=torch.float64), torch.zeros(1, 2, dtype=torch.float64))
    window = PixelWindow(115, 155, 6, 6)

    def f(tex, px):
        return render_planes(poses[:, :1], px, torch.tensor([0]), scene, CAMERA, window, textures=tex)

    assert torch.autograd.gradcheck(f, (textures, plane_x))


def test_torch_renderer_follows_dtype_and_device(scene, head):
    poses, plane_x = agreement_poses(head, torch.float64)
    renderer = TorchPlaneRenderer(scene)
    out = renderer(poses, plane_x, torch.tensor([0, 1, 2]), CROPS)
    assert out.dtype == torch.float64 and out.shape == (3, 2, 128, 128)
    assert 0.0 <= float(out.min()) and float(out.max()) <= 1.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_torch_renderer_on_cuda_matches_cpu(scene, head):
    poses, plane_x = agreement_poses(head)
    index = torch.tensor([0, 1, 2])
    cpu = TorchPlaneRenderer(scene)(poses, plane_x, index, CROPS)
    gpu = TorchPlaneRenderer(scene).cuda()(poses.cuda(), plane_x.cuda(), index.cuda(), CROPS)
    # float32 roundings differ between the devices: on an H200, 93 of 98,304 pixels differed by more
    # than 1e-5, at most by 2.1e-5 (images in [0, 1])
    torch.testing.assert_close(gpu.cpu(), cpu, atol=1e-4, rtol=0)
    assert float((gpu.cpu() - cpu).abs().gt(1e-5).float().mean()) < 0.01


# --- agreement with pyrender ----------------------------------------------------------------------


@pytest.mark.parametrize("window", ["full", "crops"])
def test_pyrender_and_torch_renderers_agree(scene, head, pyrender_renderer, window):
    """Mean |difference| <= 0.5 % of the range inside the object plane at 1, 2 and 3 m."""
    window = CAMERA.full_window if window == "full" else CROPS
    poses, plane_x = agreement_poses(head)
    index = torch.tensor([0, 1, 2])
    ours = TorchPlaneRenderer(scene)(poses, plane_x, index, window)
    theirs = pyrender_renderer(poses, plane_x, index, window)
    assert theirs.shape == ours.shape == (3, 2, window.height, window.width)
    # Pixels whose centre sees the object plane, away from its border by one pixel.
    inside = render_planes(
        poses, plane_x, index, PlaneScene(torch.ones(3, 4, 4), torch.zeros(4, 4)), CAMERA, window
    ) > 0.5
    inside = -torch.nn.functional.max_pool2d(-inside.float().flatten(0, 1), 3, 1, 1).view_as(inside) > 0
    difference = (ours - theirs).abs()
    for b in range(3):
        for eye in range(2):
            mask = inside[b, eye]
            assert mask.float().mean() > 0.5
            mad = difference[b, eye][mask].mean()
            assert mad <= 0.005, f"distance {b + 1} m eye {eye}: mean |diff| {mad:.4f}"
    # A wrong convention (mirrored texture) would be far off: the check can fail.
    assert (ours.flip(-1) - theirs).abs()[inside].mean() > 0.02


def test_pyrender_window_is_a_crop_of_its_full_frame(scene, head, pyrender_renderer):
    poses, plane_x = agreement_poses(head)
    index = torch.tensor([2, 0, 1])
    full = pyrender_renderer(poses[:1], plane_x[:1], index[:1])
    crop = pyrender_renderer(poses[:1], plane_x[:1], index[:1], CROPS)
    top, left, h, w = CROPS
    torch.testing.assert_close(crop, full[..., top : top + h, left : left + w], atol=1.5 / 255, rtol=0)


def test_pyrender_compiles_each_shader_once_across_renders_and_window_sizes(scene, head):
    """Regression: pyrender's program cache missed on every OSMesa draw (its context key is a
    fresh ctypes pointer each time), compiling and leaking a shader program per image."""
    from aectorch.sim import PyrenderRenderer

    renderer = PyrenderRenderer(scene)
    try:
        poses, plane_x = agreement_poses(head)
        index = torch.tensor([0, 1, 2])

        def programs():
            cache = renderer._gl_renderer._renderer._program_cache
            return len(cache._program_cache)

        first = renderer(poses, plane_x, index, CROPS)
        count = programs()
        assert count >= 1
        for _ in range(3):
            again = renderer(poses, plane_x, index, CROPS)
        assert programs() == count
        torch.testing.assert_close(again, first, atol=0, rtol=0)
        # A larger window makes a larger OSMesa context (smaller ones are then drawn into its
        # corner); rendering there and back still reuses programs and gives the same pixels,
        # but for llvmpipe's rasterisation in the larger buffer: at most one grey level on a
        # few pixels (31 of 98,304 measured).
        renderer(poses[:1], plane_x[:1], index[:1])
        back = renderer(poses, plane_x, index, CROPS)
        renderer(poses, plane_x, index, CROPS)
        assert programs() == count
        difference = (back - first).abs()
        assert difference.max() <= 1.5 / 255 and (difference > 0).float().mean() < 1e-3
    finally:
        renderer.close()


def test_pyrender_renders_odd_widths(head):
    scene = PlaneScene(torch.rand(1, 30, 37), torch.rand(5, 7))
    from aectorch.sim import PyrenderRenderer

    renderer = PyrenderRenderer(scene)
    try:
        poses, plane_x = agreement_poses(head)
        window = PixelWindow(100, 101, 13, 17)
        ours = TorchPlaneRenderer(scene)(poses[:1], plane_x[:1], torch.tensor([0]), window)
        theirs = renderer(poses[:1], plane_x[:1], torch.tensor([0]), window)
        assert (ours - theirs).abs().mean() < 0.01
    finally:
        renderer.close()


@pytest.mark.integration
def test_missing_osmesa_gets_an_install_hint():
    code = (
        "import ctypes\n"
        "original = ctypes.CDLL.__init__\n"
        "def refuse(self, name, *args, **kwargs):\n"
        "    if name and 'OSMesa' in str(name):\n"
        "        raise OSError('libOSMesa.so: cannot open shared object file')\n"
        "    original(self, name, *args, **kwargs)\n"
        "ctypes.CDLL.__init__ = refuse\n"
        "from aectorch.sim.render_pyrender import import_pyrender\n"
        "try:\n"
        "    import_pyrender('osmesa')\n"
        "except RuntimeError as error:\n"
        "    print(error)\n"
    )
    environment = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, timeout=120)
    assert "apt-get install libosmesa6" in result.stdout, result.stdout + result.stderr


def test_conflicting_opengl_platform_is_explained():
    from aectorch.sim.render_pyrender import import_pyrender

    other = "egl" if os.environ.get("PYOPENGL_PLATFORM", "osmesa") == "osmesa" else "osmesa"
    if "OpenGL" in sys.modules or "PYOPENGL_PLATFORM" in os.environ:
        with pytest.raises(RuntimeError, match="PYOPENGL_PLATFORM"):
            import_pyrender(other)
    with pytest.raises(ValueError, match="platform"):
        import_pyrender("wgl")


# --- ActiveDepthEnv -------------------------------------------------------------------------------


def _split(kwargs: dict) -> tuple[dict, dict]:
    """``kwargs`` as the trial protocol's fields and the environment's other arguments."""
    names = {f.name for f in dataclasses.fields(TrialProtocol)}
    return {k: v for k, v in kwargs.items() if k in names}, {k: v for k, v in kwargs.items() if k not in names}


def small_env(bank, **kwargs):
    fields, options = _split(kwargs)
    # These tests check the geometry step by step: the whole shift at once, pursuit by one eye.
    protocol = TrialProtocol(**{"fixation_iterations": 3, "shift_iterations": 1, "yoked_pursuit": False, **fields})
    return ActiveDepthEnv(3, protocol=protocol, textures=bank, **{"seed": 0, **options})


def vergence_step(env, delta):
    """Step 4 of an iteration and its end (ActiveDepthEnv.end_iteration)."""
    env.apply_vergence(delta)
    return env.end_iteration()


def run_iteration(env, pursuit, vergence):
    parallax = env.parallax_observation()["window"]
    env.apply_pursuit(pursuit)
    stereo = env.stereo_observation()["window"]
    env.apply_vergence(vergence)
    return parallax, stereo, env.end_iteration()


def test_the_window_key_the_env_writes_is_the_one_the_coder_reads(bank):
    # sim and coding stand side by side (neither imports the other): each names the key itself.
    from aectorch import coding, sim

    assert sim.WINDOW == coding.WINDOW
    env = small_env(bank)
    assert set(env.stereo_observation()) == set(env.parallax_observation()) == {coding.WINDOW}


def test_env_protocol_fixations_trials_and_q(bank):
    env = small_env(bank)
    distance = env.distance_m.clone()
    assert env.fixation == 0 and torch.all(env.body_shift_m == 0.1)
    infos = []
    for _ in range(6):
        infos.append(run_iteration(env, torch.full((3,), -0.1), torch.full((3,), 0.05))[2])
    assert [i.iteration for i in infos] == [0, 1, 2, 0, 1, 2]
    assert [i.fixation for i in infos] == [0, 0, 0, 1, 1, 1]
    assert [i.fixation_end for i in infos] == [False, False, True, False, False, True]
    assert [i.trial_end for i in infos] == [False] * 5 + [True]
    q = infos[-1].q_deg
    # Each fixation starts straight ahead and parallel: 3 x -0.1 pan, 3 x (0.05 + 0.1) vergence.
    torch.testing.assert_close(q, torch.tensor([[-0.3, 0.45, -0.3, 0.45]]).expand(3, 4))
    torch.testing.assert_close(infos[-1].distance_m, distance)
    assert env.fixation == 0 and env.iteration == 0  # a new trial began
    torch.testing.assert_close(env.pan_deg, torch.zeros(3, 2))


def test_env_ground_truth_is_the_closed_form_geometry(bank):
    env = small_env(bank, dtype=torch.float64)
    env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    info = run_iteration(env, torch.zeros(3), torch.zeros(3))[2]
    d = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    torch.testing.assert_close(info.optimal_left_pan_deg, -torch.rad2deg(torch.atan(0.1 / d)))
    torch.testing.assert_close(info.optimal_right_pan_deg, torch.rad2deg(torch.atan(0.06 / d)))
    torch.testing.assert_close(info.pursuit_error_deg, torch.rad2deg(torch.atan(0.1 / d)))


@pytest.mark.parametrize("fixation", [0, 1])
def test_env_optimal_pans_make_the_images_most_alike(bank, fixation):
    """The ground truth agrees with what the renderer shows: image mismatch is least there."""
    env = small_env(bank, dtype=torch.float64, fixation_iterations=1)
    env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    if fixation == 1:
        run_iteration(env, torch.zeros(3), torch.zeros(3))
    first = env.parallax_observation()["window"][:, 0]
    offsets = torch.linspace(-0.5, 0.5, 41, dtype=torch.float64)
    left = env.optimal_left_pan_deg()
    mismatch = []
    for offset in offsets:
        env.set_pan_deg(torch.stack((left + offset, left), -1))
        second = env.parallax_observation()["window"][:, 1]
        mismatch.append(((first - second)[:, 24:104, 24:104] ** 2).mean((1, 2)))
    best = offsets[torch.stack(mismatch).argmin(0)]
    assert best.abs().max() <= 0.06, f"pursuit mismatch is least at {best.tolist()} deg off"
    env.set_pan_deg(torch.stack((left, left), -1))
    right = env.optimal_right_pan_deg()
    mismatch = []
    for offset in offsets:
        env.set_pan_deg(torch.stack((left, right + offset), -1))
        pair = env.stereo_observation()["window"]
        mismatch.append(((pair[:, 0] - pair[:, 1])[:, 24:104, 24:104] ** 2).mean((1, 2)))
    best = offsets[torch.stack(mismatch).argmin(0)]
    assert best.abs().max() <= 0.06, f"vergence mismatch is least at {best.tolist()} deg off"


def test_env_perfect_controller_reaches_zero_error(bank):
    env = small_env(bank, fixation_iterations=40, dtype=torch.float64)
    for _ in range(40):
        env.parallax_observation()["window"]
        step = (env.optimal_left_pan_deg() - env.left_pan_deg).clamp(-0.2, 0.2)
        env.apply_pursuit(step)
        env.stereo_observation()["window"]
        info = vergence_step(env, (env.optimal_right_pan_deg() - env.right_pan_deg).clamp(-0.2, 0.2))
    assert info.fixation_end
    assert info.pursuit_error_deg.abs().max() < 1e-9 and info.vergence_error_deg.abs().max() < 1e-9


def _perfect_fixation(env, max_step_deg):
    """Run one fixation with a controller that knows the geometry and moves at most
    ``max_step_deg`` per step; the pursuit and vergence errors after every iteration."""
    errors = []
    for _ in range(env.fixation_iterations):
        env.parallax_observation()["window"]
        env.apply_pursuit((env.optimal_left_pan_deg() - env.left_pan_deg).clamp(-max_step_deg, max_step_deg))
        env.stereo_observation()["window"]
        info = vergence_step(env, 
            (env.optimal_right_pan_deg() - env.right_pan_deg).clamp(-max_step_deg, max_step_deg))
        errors.append((info.pursuit_error_deg.abs().max().item(), info.vergence_error_deg.abs().max().item()))
    return errors, info


def test_env_spread_shift_moves_the_body_linearly_then_holds(bank):
    assert small_env(bank, fixation_iterations=5, shift_iterations=20).shift_iterations == 5  # cut to h
    env = small_env(bank, fixation_iterations=30, shift_iterations=20, dtype=torch.float64)
    env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    shifts = []
    for fixation in (0, 1):
        for i in range(30):
            shifts.append(env.body_shift_m.clone())
            assert env.fixation == fixation and env.iteration == i
            run_iteration(env, torch.zeros(3), torch.zeros(3))
    shifts = torch.stack(shifts)[:, 0]
    expected = 0.1 * torch.tensor([min(1.0, (i + 1) / 20) for i in range(30)], dtype=torch.float64)
    torch.testing.assert_close(shifts[:30], expected)
    torch.testing.assert_close(shifts[30:], -expected)
    # the first image of the parallax pair stays the fixation's start (straight ahead, no shift)
    env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    first = env.parallax_observation()["window"][:, 0]
    run_iteration(env, torch.zeros(3), torch.zeros(3))
    torch.testing.assert_close(env.parallax_observation()["window"][:, 0], first, rtol=0, atol=0)
    zero = env.images.render(torch.zeros(3, dtype=torch.float64), torch.zeros(3, 2, dtype=torch.float64), slice(0, 1))["window"][:, 0]
    torch.testing.assert_close(first, zero, rtol=0, atol=0)


def test_env_paper_steps_follow_a_spread_shift_with_yoked_pursuit(bank):
    """The geometry of the protocol's reading (docs/paper-mapping.md): at 1 m an instant 0.1 m shift
    needs 5.7 deg of pursuit, 29 of the paper's 0.2 deg steps, and the right eye alone needs
    9.1 deg in the rightward fixation; spread over 20 iterations with both eyes pursuing, a
    controller limited to the paper's largest step tracks the target within a step all along and
    ends both fixations on target."""
    d = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    instant = small_env(bank, fixation_iterations=30, dtype=torch.float64)
    instant.set_trial(torch.tensor([0, 1, 2]), d)
    ideal = instant.ideal_q_deg()
    torch.testing.assert_close(ideal[0, 0], torch.tensor(-5.7106, dtype=torch.float64), atol=1e-3, rtol=0)
    assert abs(ideal[0, 2] + ideal[0, 3]) > 9.0  # the right eye's turn in the rightward fixation
    errors, _ = _perfect_fixation(instant, 0.2)
    assert errors[0][0] > 5.5 and errors[-1][0] < 1e-9  # 5.7 deg behind at first; 29 steps catch up
    errors, _ = _perfect_fixation(instant, 0.2)
    assert errors[-1][1] > 2.5  # 30 steps of 0.2 deg cannot turn the right eye 9.1 deg

    spread = small_env(bank, fixation_iterations=30, shift_iterations=20, yoked_pursuit=True, dtype=torch.float64)
    spread.set_trial(torch.tensor([0, 1, 2]), d)
    for fixation in (0, 1):
        errors, info = _perfect_fixation(spread, 0.2)
        assert info.fixation_end and info.fixation == fixation
        assert max(e[0] for e in errors) < 1.75  # the lag of 0.2 deg steps behind 0.29 deg per iteration
        assert errors[-1][0] < 1e-9 and errors[-1][1] < 1e-9
    assert info.trial_end
    torch.testing.assert_close(info.q_deg, ideal, atol=1e-9, rtol=0)


def test_env_yoked_pursuit_moves_both_eyes(bank):
    env = small_env(bank, yoked_pursuit=True)
    env.apply_pursuit(torch.tensor([0.2, -0.1, 0.0]))
    torch.testing.assert_close(env.pan_deg, torch.tensor([[0.2, 0.2], [-0.1, -0.1], [0.0, 0.0]]))
    env.apply_vergence(torch.tensor([0.05, 0.0, -0.05]))
    torch.testing.assert_close(env.vergence_deg, torch.tensor([0.05, 0.0, -0.05]))
    alone = small_env(bank)
    alone.apply_pursuit(torch.tensor([0.2, -0.1, 0.0]))
    torch.testing.assert_close(alone.right_pan_deg, torch.zeros(3))


def test_env_start_states_and_limits(bank):
    env = small_env(bank, pursuit_start_deg=(-1.0, 1.0), vergence_start_deg=(-2.0, 2.0))
    assert env.left_pan_deg.abs().max() <= 1.0 and env.vergence_deg.abs().max() <= 2.0
    assert env.left_pan_deg.unique().numel() == 3
    env.set_pan_deg(torch.tensor([[44.9, 0.0]] * 3))
    env.apply_pursuit(torch.full((3,), 0.2))
    assert env.left_pan_deg.max() <= 45.0  # the URDF's eye pan limit


def test_env_pursuit_start_error_starts_the_eyes_off_their_target_on_either_side(bank):
    env = ActiveDepthEnv(16, textures=bank, distances_m=[1.0, 2.0], seed=3, vergence_start_deg=(-1.0, 1.0),
                         pursuit_start_error_deg=2.0)
    on_target = ActiveDepthEnv(16, textures=bank, distances_m=[1.0, 2.0], seed=3, vergence_start_deg=(-1.0, 1.0))
    error = env.left_pan_deg - on_target.left_pan_deg
    assert error.abs().max() <= 2.0 and (error > 0.2).any() and (error < -0.2).any()
    # the same start without the error: the target, the first image's view, the vergence; the
    # pursuit error is the other's plus the drawn one
    torch.testing.assert_close(env.target_m, on_target.target_m)
    torch.testing.assert_close(env.vergence_deg, on_target.vergence_deg)
    torch.testing.assert_close(env.optimal_left_pan_deg(), on_target.optimal_left_pan_deg())
    first = env.parallax_observation(window=True)["window"][:, 0]
    torch.testing.assert_close(first, on_target.parallax_observation(window=True)["window"][:, 0])
    # pursuit that undoes the error leaves the eye where the on-target start is
    env.apply_pursuit(-error)
    torch.testing.assert_close(env.left_pan_deg, on_target.left_pan_deg, atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="pursuit_start_error_deg"):
        ActiveDepthEnv(2, textures=bank, pursuit_start_error_deg=-1.0)


def test_env_roll_changes_what_the_eye_sees(bank):
    env = small_env(bank)
    before = env.stereo_observation()["window"]
    env.set_roll(torch.tensor([0.0, 5.0]))
    after = env.stereo_observation()["window"]
    torch.testing.assert_close(after[:, 0], before[:, 0])
    assert (after[:, 1] - before[:, 1]).abs().mean() > 0.01


def test_env_is_seeded(bank):
    a, b, c = small_env(bank, seed=3), small_env(bank, seed=3), small_env(bank, seed=4)
    assert torch.equal(a.texture_index, b.texture_index) and torch.equal(a.distance_m, b.distance_m)
    assert not (torch.equal(a.texture_index, c.texture_index) and torch.equal(a.distance_m, c.distance_m))
    torch.testing.assert_close(a.stereo_observation()["window"], b.stereo_observation()["window"])


def test_env_torch_and_pyrender_observations_match(bank):
    textures = quantised(bank.textures)
    envs = [ActiveDepthEnv(2, protocol=TrialProtocol(renderer=name, fixation_iterations=2), textures=textures, seed=5)
            for name in ("torch", "pyrender")]
    generator = torch.Generator().manual_seed(0)
    for _ in range(5):
        actions = torch.randint(-2, 3, (2, 2), generator=generator) * 0.1
        out = [run_iteration(env, actions[0], actions[1]) for env in envs]
        (p0, s0, i0), (p1, s1, i1) = out
        assert (p0 - p1).abs().mean() < 0.005 and (s0 - s1).abs().mean() < 0.005
        torch.testing.assert_close(i0.pursuit_error_deg, i1.pursuit_error_deg)
    envs[1].renderer.close()


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"distances_m": [1.0, 0.0]}, ValueError, "distances_m"),
        ({"distances_m": [9.0]}, ValueError, "background"),
        ({"renderer": "blender"}, ValueError, "renderer must be one of"),
        ({"textures": torch.rand(64, 64)}, ValueError, r"\[N, H, W\]"),
        ({"window": "middle"}, ValueError, "window"),
        ({"fixation_iterations": 0}, ValueError, "fixation_iterations"),
        ({"shift_iterations": 0}, ValueError, "shift_iterations"),
        ({"yoked_pursuit": 1}, ValueError, "yoked_pursuit"),
    ],
)
def test_env_rejects_bad_configuration(bank, kwargs, error, match):
    fields, options = _split({"textures": bank, **kwargs})
    with pytest.raises(error, match=match):
        ActiveDepthEnv(2, protocol=TrialProtocol(**fields), **options)


def test_env_rejects_bad_calls(bank):
    env = small_env(bank)
    with pytest.raises(ValueError, match=r"delta_deg must have shape \[B\] = \[3\]"):
        env.apply_pursuit(torch.zeros(4))
    with pytest.raises(ValueError, match="distance_m must be > 0"):
        env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, -1.0, 2.0]))
    with pytest.raises(ValueError, match=r"shape \[B\] = \[3\]"):
        env.set_trial(torch.tensor([0, 1]), torch.tensor([1.0, 1.0]))
    with pytest.raises(IndexError, match="texture_index"):
        env.set_trial(torch.tensor([0, 1, 9]), torch.tensor([1.0, 1.0, 2.0]))
    with pytest.raises(ValueError, match="roll_deg"):
        env.set_roll(torch.zeros(3))
    with pytest.raises(ValueError, match=r"plane_x_m must have shape \[B\]"):
        env.renderer(torch.eye(4).expand(3, 2, 4, 4), torch.ones(2), torch.zeros(3, dtype=torch.long))


def test_env_reports_distance_in_metres_from_the_eyes(bank):
    env = small_env(bank)
    torch.testing.assert_close(env.plane_x_m, env.distance_m + 0.03)
    assert set(env.distance_m.tolist()) <= {round(1.0 + 0.1 * i, 1) for i in range(21)} | set(
        torch.tensor([round(1.0 + 0.1 * i, 1) for i in range(21)]).tolist()
    )
    assert math.isclose(env.head.eye_x_m, 0.03, abs_tol=1e-6)


def test_index_arithmetic_path_matches_the_atlas_path(scene, head, monkeypatch):
    """Banks too tall for a float32 atlas are sampled by index arithmetic: same images."""
    import aectorch.sim.render_torch as render_torch

    poses, plane_x = agreement_poses(head)
    index = torch.tensor([0, 1, 2])
    atlas = render_planes(poses, plane_x, index, scene, CAMERA, CAMERA.full_window)
    monkeypatch.setattr(render_torch, "_ATLAS_ROWS_FLOAT32", 0)
    gathered = render_planes(poses, plane_x, index, scene, CAMERA, CAMERA.full_window)
    torch.testing.assert_close(gathered, atlas, atol=2e-5, rtol=0)


def test_env_state_dict_resumes_exactly(bank, tmp_path):
    env = small_env(bank, pursuit_start_deg=(-1.0, 1.0))
    for _ in range(4):
        run_iteration(env, torch.full((3,), 0.1), torch.full((3,), -0.05))
    env.set_roll(torch.tensor([1.0, -2.0]))
    torch.save(env.state_dict(), tmp_path / "env.pt")
    twin = small_env(bank, pursuit_start_deg=(-1.0, 1.0), seed=99)
    twin.load_state_dict(torch.load(tmp_path / "env.pt"))
    for _ in range(6):  # crosses a trial boundary: the generator state matters
        a = run_iteration(env, torch.full((3,), 0.05), torch.zeros(3))
        b = run_iteration(twin, torch.full((3,), 0.05), torch.zeros(3))
        torch.testing.assert_close(a[0], b[0], rtol=0, atol=0)
        torch.testing.assert_close(a[2].vergence_error_deg, b[2].vergence_error_deg, rtol=0, atol=0)
    assert (env.iteration, env.fixation) == (twin.iteration, twin.fixation)
    torch.testing.assert_close(env.texture_index, twin.texture_index)
    with pytest.raises(ValueError, match="num_envs"):
        other = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3), textures=bank)
        other.load_state_dict(env.state_dict())


def test_torch_renderer_rejects_out_of_range_texture_indices(scene, head):
    poses, plane_x = agreement_poses(head)
    with pytest.raises(IndexError, match=r"texture_index must be in \[0, 3\)"):
        TorchPlaneRenderer(scene)(poses, plane_x, torch.tensor([0, 1, 3]))


def test_env_ideal_q_is_what_a_perfect_trial_ends_with(bank):
    env = small_env(bank, fixation_iterations=40, dtype=torch.float64)
    env.set_trial(torch.tensor([0, 1, 2]), torch.tensor([1.0, 1.7, 3.0], dtype=torch.float64))
    ideal = env.ideal_q_deg()
    torch.testing.assert_close(env.ideal_q_deg(torch.tensor([1.0, 1.7, 3.0])), ideal)
    for _ in range(80):
        env.apply_pursuit((env.optimal_left_pan_deg() - env.left_pan_deg).clamp(-0.5, 0.5))
        info = vergence_step(env, (env.optimal_right_pan_deg() - env.right_pan_deg).clamp(-0.5, 0.5))
    assert info.trial_end
    torch.testing.assert_close(info.q_deg, ideal, atol=1e-9, rtol=0)
    # vergence falls and the pursuit pans shrink with distance; the two fixations mirror
    assert bool((ideal[1:, 1] < ideal[:-1, 1]).all()) and bool((ideal[:, 0] < 0).all())
    torch.testing.assert_close(ideal[:, 2], -ideal[:, 0])
    with pytest.raises(ValueError, match="distance_m"):
        env.ideal_q_deg(torch.tensor([1.0, -2.0]))


# --- rendering at each foveal scale's resolution (mipmaps) -----------------------------------------


def _supersampled(poses, plane_x, index, scene, window, downsample, factor=4):
    """The exact area average: the window rendered ``factor`` times finer per side, block-averaged."""
    big = PinholeCamera(width=CAMERA.width * factor, height=CAMERA.height * factor, vfov_deg=CAMERA.vfov_deg)
    top, left, h, w = window
    fine = render_planes(poses, plane_x, index, scene, big,
                         PixelWindow(top * factor, left * factor, h * factor, w * factor))
    pooled = torch.nn.functional.avg_pool2d(fine.flatten(0, -3).unsqueeze(1), factor * downsample)
    return pooled.reshape(fine.shape[:-2] + pooled.shape[-2:])


def _photographs():
    from sklearn.datasets import load_sample_images

    images = [torch.tensor(image).float().mean(-1) / 255 for image in load_sample_images().images]
    return torch.stack([torch.nn.functional.interpolate(i[None, None], size=(512, 512), mode="area")[0, 0]
                        for i in images])


@pytest.mark.parametrize("source", ["textures", "photographs"])
def test_scale_rendering_is_within_half_a_percent_of_the_exact_area_average(head, source):
    """Each default scale rendered at its resolution (SCALE_FILTER) against 4 x 4 supersampling."""
    from aectorch.coding.patches import COARSE, FINE, WIDE
    from aectorch.sim.observations import _block_mean, _finer
    textures = TextureBank.default("test").textures[:4] if source == "textures" else _photographs()
    scene = PlaneScene(textures, TextureBank.procedural(1, size=(256, 256), seed=8).textures[0])
    n = len(textures)
    env = ActiveDepthEnv(n, textures=textures, background=scene.background, seed=0)
    for distance in (1.0, 2.0, 3.0):
        shift = torch.linspace(-0.1, 0.1, n)
        pan = torch.stack((torch.linspace(-3, 3, n), torch.linspace(-2, 4, n)), -1)
        poses = head.camera_poses(shift, pan, torch.zeros(n, 2), convention="opengl")
        plane_x = torch.full((n,), distance + head.eye_x_m)
        index = torch.arange(n)
        env.set_trial(index, plane_x - head.eye_x_m)
        env.stereo_observation(scales=(FINE,))  # builds the scale renderer
        windows = [(CAMERA.central_window(s.crop), s.downsample) for s in (WIDE, COARSE, FINE)]
        finer = [_finer(d) for _, d in windows]
        rendered = env.images.scale_renderer.render_windows(poses, plane_x, index, [(w, d // k) for (w, d), k in zip(windows, finer)])
        rendered = [_block_mean(image, k) for image, k in zip(rendered, finer)]
        for (window, downsample), ours in zip(windows, rendered):
            exact = _supersampled(poses, plane_x, index, env.scene, window, downsample)
            assert ours.shape == exact.shape
            mad = (ours - exact).abs().mean()
            assert mad <= 0.005, f"{source} at {distance} m, downsample {downsample}: {mad:.4f}"
            # One lookup per pixel without the bias (OpenGL's default) is measurably worse.
    plain = TorchPlaneRenderer(env.scene, filter="trilinear")(poses, plane_x, index, windows[1][0], downsample=8)
    assert (plain - _supersampled(poses, plane_x, index, env.scene, windows[1][0], 8)).abs().mean() > 0.006


def test_mipmap_levels_are_box_averages():
    from aectorch.sim.render_torch import mipmap_atlas, mipmap_levels

    x = torch.rand(2, 8, 16, dtype=torch.float64)
    levels = mipmap_levels(x)
    assert [tuple(level.shape[1:]) for level in levels] == [(8, 16), (4, 8), (2, 4), (1, 2), (1, 1)]
    torch.testing.assert_close(levels[1][0, 1, 2], x[0, 2:4, 4:6].mean())
    torch.testing.assert_close(levels[-1][:, 0, 0], x.mean((1, 2)))
    mip = mipmap_atlas(x, torch.rand(8, 16, dtype=torch.float64))
    for index, ((row, col), (h, w)) in enumerate(zip(mip.origins.tolist(), mip.sizes.tolist())):
        torch.testing.assert_close(mip.packed[:2, row:row + h, col:col + w], levels[index])


@pytest.mark.parametrize("samples", [1, 2])
def test_native_trilinear_kernel_matches_the_torch_code(scene, head, samples):
    import aectorch.sim.render_torch as render_torch
    from aectorch.ops import native

    # CI and `make test` must exercise the kernel (tests/ops/test_native.py asserts it builds too).
    assert native.available(), "the fused CPU kernels did not build (see the warning)"
    poses, plane_x = agreement_poses(head, torch.float64)
    index = torch.tensor([0, 1, 2])
    renderer = TorchPlaneRenderer(scene, filter="trilinear", lod_bias=-0.5, samples=samples).double()
    windows = [(CROPS, 16), (CROPS, 8), (CAMERA.central_window(80), 2), (CAMERA.full_window, 1)]
    fused = renderer.render_windows(poses, plane_x.double(), index, windows)
    torch_code = render_torch._native_trilinear
    try:
        render_torch._native_trilinear = lambda *args: False
        reference = renderer.render_windows(poses, plane_x.double(), index, windows)
    finally:
        render_torch._native_trilinear = torch_code
    for a, b in zip(fused, reference):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-9)
    # Differentiable: with gradients the torch code runs (the kernel has no backward).
    p = poses.clone().requires_grad_(True)
    renderer.render_windows(p, plane_x.double(), index, windows[:1])[0].sum().backward()
    assert p.grad is not None and p.grad.abs().sum() > 0


@pytest.mark.parametrize("samples", [1, 2, 3])
def test_native_trilinear_simd_blocks_tails_and_misses(scene, head, samples):
    """The kernel's vector path (blocks of 16 or 8 pixels, masks for each branch) against the torch
    code: rows whose pixel count is no multiple of the block (a tail, and fewer pixels than one
    block), pixels on neither plane or behind the camera, magnification (one level), the last level,
    many rows; float64 to 1e-9, float32 to float rounding."""
    import aectorch.sim.render_torch as render_torch
    from aectorch.ops import native
    from aectorch.sim.render_torch import pixel_rays

    assert native.available(), "the fused CPU kernels did not build (see the warning)"
    g = torch.Generator().manual_seed(3)
    base, plane_x = agreement_poses(head, torch.float64)  # [3, 2, 4, 4]
    poses = base.repeat(3, 1, 1, 1)  # 9 x 2 = 18 rows
    # Rotate every camera by up to ~90 degrees about a random axis and move it: rays that miss both
    # planes or point away from them, cameras beyond the object plane (it is behind them).
    axis = torch.nn.functional.normalize(torch.randn(18, 3, generator=g, dtype=torch.float64), dim=1)
    angle = (torch.rand(18, 1, 1, generator=g, dtype=torch.float64) * 2 - 1) * 1.6
    k = torch.zeros(18, 3, 3, dtype=torch.float64)
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k = k - k.transpose(1, 2)
    rot = torch.eye(3, dtype=torch.float64) + angle.sin() * k + (1 - angle.cos()) * k @ k
    poses = poses.clone().reshape(18, 4, 4)
    poses[:, :3, :3] = rot @ poses[:, :3, :3]
    poses[:, :3, 3] += torch.randn(18, 3, generator=g, dtype=torch.float64) * torch.tensor([0.3, 0.5, 0.5])
    poses = poses.reshape(9, 2, 4, 4)
    plane_x = plane_x.repeat(3) * torch.tensor([1, 1, 1, 0.5, 2, 1, 1, 0.05, 3], dtype=torch.float64)
    index = torch.tensor([0, 1, 2, 2, 1, 0, 1, 2, 0])
    renderer = TorchPlaneRenderer(scene, filter="trilinear").double()
    mip = renderer._atlas()
    rays = pixel_rays(CAMERA, [(CAMERA.central_window(80), 2), (CROPS, 8)], dtype=torch.float64)
    torch_code = render_torch._native_trilinear
    for pixels in (rays[0].shape[0] - 3, 37, 5):  # a tail after whole blocks; a short row
        some = tuple(r[:pixels] for r in rays)
        for lod_bias in (-0.5, -6.0, 6.0):  # as trained; magnified everywhere; the coarsest levels
            def render(p, dtype):
                return render_torch.render_rays(p.to(dtype), plane_x.to(dtype), index, scene,
                                                tuple(r.to(dtype) for r in some), atlas=mip, filter="trilinear",
                                                lod_bias=lod_bias, samples=samples)
            fused64, fused32 = render(poses, torch.float64), render(poses, torch.float32)
            try:
                render_torch._native_trilinear = lambda *args: False
                reference = render(poses, torch.float64)
            finally:
                render_torch._native_trilinear = torch_code
            where = f"{pixels} pixels, lod_bias {lod_bias}"
            assert (reference == 0).any() and (reference > 0).any(), where  # misses and hits
            torch.testing.assert_close(fused64, reference, rtol=0, atol=1e-9, msg=where)
            torch.testing.assert_close(fused32, reference.float(), rtol=0, atol=2e-4, msg=where)


def test_pyrender_and_torch_agree_at_every_scale(scene, head):
    """Both renderers with mipmaps at each default scale's resolution: mean |diff| <= 1 % (2.6 grey levels)."""
    from aectorch.coding.patches import COARSE, FINE, WIDE
    from aectorch.sim import PyrenderRenderer
    from aectorch.sim.env import SCALE_FILTER

    poses, plane_x = agreement_poses(head)
    poses = head.camera_poses(torch.zeros(3), torch.zeros(3, 2), torch.zeros(3, 2), convention="opengl")
    index = torch.tensor([0, 1, 2])
    windows = [(CAMERA.central_window(s.crop), s.downsample) for s in (WIDE, COARSE, FINE)]
    ours = TorchPlaneRenderer(scene, **SCALE_FILTER).render_windows(poses, plane_x, index, windows)
    renderer = PyrenderRenderer(scene, **SCALE_FILTER)
    try:
        theirs = renderer.render_windows(poses, plane_x, index, windows)
        # Windows of three sizes, drawn again: no new OpenGL context (each would upload every
        # texture again; regression: 0.8 iterations/s at B = 1).
        gl = renderer._gl_renderer
        created = []
        original = gl._create
        gl._create = lambda: (created.append(1), original())[1]
        again = renderer.render_windows(poses, plane_x, index, windows)
        assert not created
        for a, b in zip(theirs, again):  # (the first windows were drawn in a smaller context)
            torch.testing.assert_close(a, b, rtol=0, atol=1.5 / 255)
    finally:
        renderer.close()
    for a, b in zip(ours, theirs):
        assert a.shape == b.shape
        assert (a - b).abs().mean() <= 0.01
        assert (a.flip(-1) - b).abs().mean() > 2 * (a - b).abs().mean()  # the check can fail


def test_scale_observations_reuse_the_stereo_frame_exactly(bank):
    """The parallax pair's second image is the last stereo frame's left image when the eye has not moved."""
    from aectorch.coding.patches import COARSE, FINE

    scales = (COARSE, FINE)
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=4, shift_iterations=2, yoked_pursuit=True),
                         textures=bank, seed=1)
    fresh = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=4, shift_iterations=2, yoked_pursuit=True),
                           textures=bank, seed=1)
    reused = 0
    for it in range(8):
        for e in (env, fresh):
            e.images.last_left = None if e is fresh else e.images.last_left
        a, b = env.parallax_observation(scales=scales), fresh.parallax_observation(scales=scales)
        if env.images.last_left is not None and env.images.last_left[0] == env.images.view:
            reused += 1
        for name in a:
            torch.testing.assert_close(a[name], b[name], rtol=0, atol=0)
        delta = torch.tensor([0.1, -0.2]) * (it % 3 == 0)
        for e in (env, fresh):
            e.apply_pursuit(delta)
        s1, s2 = env.stereo_observation(scales=scales), fresh.stereo_observation(scales=scales)
        for name in s1:
            torch.testing.assert_close(s1[name], s2[name], rtol=0, atol=0)
        for e in (env, fresh):
            e.apply_vergence(torch.tensor([0.05, 0.0]))
            e.end_iteration()
    assert reused >= 2  # the held shift with no pursuit reuses frames


def test_scale_observations_have_the_pyramids_smoothness(head):
    """The env's scale images (area render + pyramid_blur) are close to the old pipeline's (128 px crop,
    then the centred pyramid), much closer than the unblurred area render."""
    import dataclasses

    from aectorch.coding.patches import COARSE, FINE, WIDE, pyramid_down

    scales = [dataclasses.replace(s, centred=True) for s in (WIDE, COARSE, FINE)]
    env = ActiveDepthEnv(6, textures=TextureBank.default("test").textures[:6], seed=0)
    env.set_trial(torch.arange(6), torch.tensor([1.0, 1.4, 1.8, 2.2, 2.6, 3.0]))
    env.apply_pursuit(torch.linspace(-2, 2, 6))
    ours = env.stereo_observation(scales=scales)
    crops = env.stereo_observation()["window"]
    for s in scales:
        top = (128 - s.crop) // 2
        old = pyramid_down(crops[..., top:top + s.crop, top:top + s.crop].flatten(0, 1), s.levels, centred=True)
        new = ours[s.name].flatten(0, 1)
        windows = [(CAMERA.central_window(s.crop), s.downsample)]
        raw = env.images.scale_renderer.render_windows(env.head.camera_poses(env.body_shift_m, env.pan_deg, env.roll_deg,
                                                                       convention="opengl"),
                                                 env.plane_x_m, env.texture_index, windows)[0].flatten(0, 1)
        assert new.shape == old.shape
        blurred, unblurred = (new - old).abs().mean(), (raw - old).abs().mean()
        assert blurred < 0.008 and blurred < 0.5 * unblurred, (s.name, blurred, unblurred)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_pyramid_blur_kernel_gives_the_torch_codes_bits_on_any_number_of_threads(dtype):
    """``aectorch::pyramid_blur`` (CPU, no gradient) computes what the torch code computes, operation by
    operation (bit for bit, on 1-3 threads), and both are scipy's 3-tap correlation of the valid region."""
    from scipy.ndimage import correlate1d

    from aectorch.ops import native
    from aectorch.coding.batch_omp import use_backend
    from aectorch.sim.env import pyramid_blur

    assert native.available(), "the fused CPU kernels did not build (see the warning)"
    g = torch.Generator().manual_seed(0)
    before = native.get_threads()
    try:
        # (the last shape holds more than 2^20 values: the kernel splits it over its threads)
        for shape in [(32, 2, 10, 10), (40, 2, 42, 42), (3, 5, 7), (2, 3, 3), (1, 2, 3, 9, 4), (300, 2, 42, 42)]:
            for levels in (1, 3) if shape[0] < 300 else (2,):
                images = torch.rand(*shape, generator=g, dtype=dtype) * 3 - 1
                with use_backend("torch"):
                    torch_code = pyramid_blur(images, levels)
                kernels = []
                for threads in (1, 2, 3):
                    native.set_threads(threads)
                    kernels.append(pyramid_blur(images, levels))
                assert all(torch.equal(k, torch_code) for k in kernels), (shape, levels)
                a = (5.0 / 12.0 * (1.0 - 4.0 ** -levels) - 1.0 / 12.0) / 2.0
                weights = [a, 1.0 - 2.0 * a, a]
                expected = correlate1d(correlate1d(images.double().numpy(), weights, axis=-1), weights, axis=-2)
                torch.testing.assert_close(kernels[0], torch.from_numpy(expected)[..., 1:-1, 1:-1].to(dtype))
        strided = torch.rand(2, 12, 15, generator=g, dtype=dtype)[..., 1:-2]  # not contiguous
        # (with a graph to build, the differentiable torch code runs)
        assert torch.equal(pyramid_blur(strided, 2), pyramid_blur(strided.clone().requires_grad_(True), 2).detach())
        assert pyramid_blur(torch.rand(4, 2, 5, dtype=dtype), 1).shape == (4, 0, 3)  # too small: the torch code
    finally:
        native.set_threads(before)
    from torch._subclasses.fake_tensor import FakeTensorMode

    with FakeTensorMode():
        assert torch.ops.aectorch.pyramid_blur(torch.empty(5, 12, 9), 0.8, 0.1).shape == (5, 10, 7)
    with pytest.raises(RuntimeError, match="expects images"):
        torch.ops.aectorch.pyramid_blur(torch.empty(5, 2, 9), 0.8, 0.1)


def test_both_renderers_satisfy_the_renderer_protocol_and_close_closes_both(bank):
    """The renderers' shared interface is stated (`aectorch.sim.Renderer`), and
    `ActiveDepthEnv.close()` frees the crops' renderer and the foveal scales' renderer."""
    from aectorch.coding.patches import as_scale
    from aectorch.sim import Renderer

    scales = [as_scale("coarse"), as_scale("fine")]
    for name in ("torch", "pyrender"):
        with small_env(bank, renderer=name) as env:
            env.stereo_observation()["window"]
            env.stereo_observation(scales=scales)  # builds the scale renderer
            assert isinstance(env.renderer, Renderer) and isinstance(env.images.scale_renderer, Renderer)
            renderers = (env.renderer, env.images.scale_renderer)
            if name == "pyrender":
                assert all(r._gl_renderer is not None for r in renderers)
        if name == "pyrender":
            assert all(r._gl_renderer is None for r in renderers)  # both OpenGL contexts freed
    assert not isinstance(object(), Renderer)


def test_q_is_the_mean_of_each_fixations_last_q_iterations():
    env = ActiveDepthEnv(3, protocol=TrialProtocol(fixation_iterations=5, q_iterations=3),
                         textures=torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(0)), seed=0)
    g = torch.Generator().manual_seed(1)
    seen = []
    for _ in range(10):
        env.apply_pursuit((torch.rand(3, generator=g) - 0.5))
        env.apply_vergence((torch.rand(3, generator=g) - 0.5))
        info = env.end_iteration()
        seen.append(torch.stack((info.left_pan_deg, info.right_pan_deg - info.left_pan_deg), -1))
    expected = torch.cat((torch.stack(seen[2:5]).mean(0), torch.stack(seen[7:10]).mean(0)), -1)
    torch.testing.assert_close(info.q_deg, expected)
    with pytest.raises(ValueError, match="q_iterations"):
        ActiveDepthEnv(1, protocol=TrialProtocol(q_iterations=0), textures=torch.rand(1, 8, 8))


# --- the oculomotor range ------------------------------------------------------------------------


def test_clamp_eyes_is_the_nearest_pair_within_the_range():
    from aectorch.sim import clamp_eyes

    g = torch.Generator().manual_seed(0)
    pan = (torch.rand(4000, 2, generator=g, dtype=torch.float64) - 0.5) * 120  # up to +-60 degrees
    pans, vergences = (-30.0, 40.0), (-2.0, 25.0)
    out = clamp_eyes(pan, pans, vergences)
    left, right = out.unbind(-1)
    vergence = right - left
    eps = 1e-12
    assert bool(((left >= pans[0] - eps) & (left <= pans[1] + eps)).all())
    assert bool(((right >= pans[0] - eps) & (right <= pans[1] + eps)).all())
    assert bool(((vergence >= vergences[0] - eps) & (vergence <= vergences[1] + eps)).all())
    # Pairs within the range are left alone; the left eye moves only to its own pan range, and the
    # right eye to the nearest pan that meets both (a brute-force search over a fine grid of pans).
    inside = (pan[:, 0].clamp(*pans) == pan[:, 0]) & (pan[:, 1].clamp(*pans) == pan[:, 1]) & \
        ((pan[:, 1] - pan[:, 0]).clamp(*vergences) == pan[:, 1] - pan[:, 0])
    assert inside.any() and torch.equal(out[inside], pan[inside])
    assert torch.equal(left, pan[:, 0].clamp(*pans))
    grid = torch.linspace(*pans, 70001, dtype=torch.float64)
    for i in range(0, 4000, 97):
        ok = grid[((grid - left[i]) >= vergences[0]) & ((grid - left[i]) <= vergences[1])]
        nearest = ok[(ok - pan[i, 1]).abs().argmin()]
        assert right[i].item() == pytest.approx(nearest.item(), abs=1e-3)
    with pytest.raises(ValueError, match=r"pan_deg must have shape \[B, 2\]"):
        clamp_eyes(torch.zeros(3), pans, vergences)


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(vergence_range_deg=(0.5, 3.0)), "vergence_range_deg must hold 0"),
    (dict(vergence_range_deg=(0.0, 0.0)), "vergence_range_deg must be wider than 0"),
    (dict(vergence_range_deg=(3.0, -1.0)), "vergence_range_deg must be two finite numbers with low <= high"),
    (dict(pan_range_deg=(-50.0, 10.0)), r"pan_range_deg must lie within the HOAP-3's eye pan limits \(-45, 45\)"),
    (dict(pan_range_deg=(float("nan"), 10.0)), "pan_range_deg must be two finite numbers"),
    (dict(pan_range_deg=5.0), r"pan_range_deg must be a \(low, high\) pair"),
])
def test_the_oculomotor_range_rejects_bad_values_by_name(kwargs, match):
    if "HOAP-3" in match:  # the head's joint limits are the environment's: its protocol holds any range
        protocol = TrialProtocol(**kwargs)
        with pytest.raises(ValueError, match=match):
            ActiveDepthEnv(1, protocol=protocol, textures=torch.rand(1, 32, 32))
    else:
        with pytest.raises(ValueError, match=match):
            TrialProtocol(**kwargs)


@pytest.mark.parametrize("renderer", ["torch", "pyrender"])
def test_every_movement_ends_within_the_oculomotor_range_in_both_renderers(renderer):
    """Vergence increments past the range stop at its bounds, the right eye's image is the one
    of the eyes put at the bound, and yoked pursuit stops at the pan range; the default range is
    -2 to 40 degrees of vergence and the HOAP-3's +-45 degrees of pan."""
    textures = quantised(torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(3)))
    options = dict(fixation_iterations=4, renderer=renderer)
    env = ActiveDepthEnv(3, protocol=TrialProtocol(**options), textures=textures)
    assert env.pan_range_deg == (-45.0, 45.0) and env.vergence_range_deg == (-2.0, 40.0)
    env.close()
    env = ActiveDepthEnv(3, protocol=TrialProtocol(pan_range_deg=(-20.0, 20.0), vergence_range_deg=(-1.0, 10.0),
                                                   **options),
                         textures=textures)
    env.set_trial(torch.tensor([0, 1, 0]), torch.tensor([1.0, 2.0, 3.0]))
    env.apply_pursuit(torch.zeros(3))
    env.apply_vergence(torch.tensor([-7.0, 15.0, 0.5]))
    assert torch.allclose(env.vergence_deg, torch.tensor([-1.0, 10.0, 0.5]))
    moved = env.stereo_observation()["window"]
    bound = ActiveDepthEnv(3, protocol=TrialProtocol(**options), textures=textures)
    bound.set_trial(torch.tensor([0, 1, 0]), torch.tensor([1.0, 2.0, 3.0]))
    bound.set_pan_deg(torch.tensor([[0.0, -1.0], [0.0, 10.0], [0.0, 0.5]]))
    assert torch.equal(moved, bound.stereo_observation()["window"])
    env.apply_pursuit(torch.tensor([30.0, -30.0, 5.0]))  # both eyes, yoked
    assert torch.allclose(env.left_pan_deg, torch.tensor([20.0, -20.0, 5.0]))
    assert bool((env.right_pan_deg <= 20.0).all() and (env.right_pan_deg >= -20.0).all())
    assert bool((env.vergence_deg >= -1.0 - 1e-6).all() and (env.vergence_deg <= 10.0 + 1e-6).all())
    for e in (env, bound):
        e.close()
