"""A world with depth structure (`aectorch.sim.scene.SceneLayout`): a narrower object, moved
sideways and slanted, before a background at its own distance and texture. The torch renderer
against a pinhole computation in numpy, the two renderers against each other, the optimum on the
object, the plain world untouched, and bad values refused by name."""

import math

import numpy as np
import pytest
import torch

from aectorch.sim import ActiveDepthEnv, HOAP3Head, PlaneScene, TextureBank, TorchPlaneRenderer
from aectorch.sim.camera import PinholeCamera
from aectorch.sim.env import SCALE_FILTER
from aectorch.sim.protocol import TrialProtocol
from aectorch.sim.scene import Placement, SceneLayout, axis_point

torch.set_num_threads(1)

SIZE = 64
#: Object textures whose value is their column's centre (u) and background textures whose value
#: is their row's centre (v), so a pixel's value says which plane it sees and where.
RAMP_U = ((torch.arange(SIZE, dtype=torch.float64) + 0.5) / SIZE).expand(SIZE, SIZE)
RAMP_V = RAMP_U.T.contiguous()

DEPTH = SceneLayout(object_width_m=0.6, object_offset_m=[-0.2, 0.2], slant_deg=[-30, 30],
                    background_depth_m=[0.5, 3.0], background_texture="bank", background_width_m=8.0)


def reference(pose: np.ndarray, pixel: tuple[float, float], camera: PinholeCamera, plane_x: float, slant: float,
              offset: float, pivot_yz, object_m: float, extent: float, background_x: float, background_m: float):
    """The value a pixel sees in the ramp world, from the pinhole model in numpy: the ray through
    the pixel's centre, its hit on the slanted object (within its visible square), else on the
    background plane; the object's u ramp or the background's v ramp there."""
    cx, cy = camera.principal_point
    col, row = pixel
    ray_ros = np.array([(col + 0.5 - cx) / camera.focal_px, (row + 0.5 - cy) / camera.focal_px, 1.0])
    ray = pose[:3, :3] @ np.array([ray_ros[0], -ray_ros[1], -ray_ros[2]])  # OpenGL camera: y up, looking along -z
    eye = pose[:3, 3]
    normal = np.array([math.cos(slant), math.sin(slant), 0.0])
    along_axis = np.array([-math.sin(slant), math.cos(slant), 0.0])
    pivot = np.array([plane_x, *pivot_yz])
    t = normal @ (pivot - eye) / (normal @ ray)
    hit = eye + t * ray
    s = (hit - pivot) @ along_axis - offset
    up = hit[2] - pivot[2]
    if t > 0 and abs(s) <= extent / 2 and abs(up) <= extent / 2:
        return 0.5 - s / object_m, "object"
    t = (background_x - eye[0]) / ray[0]
    up = eye[2] + t * ray[2] - pivot_yz[1]
    return 0.5 - up / background_m, "background"


@pytest.fixture(scope="module")
def ramps():
    textures = torch.stack((RAMP_U, RAMP_V, RAMP_V))
    return textures


def test_the_torch_renderer_draws_the_slanted_object_and_its_background_where_a_pinhole_sees_them(ramps):
    camera = PinholeCamera()
    scene = PlaneScene(ramps, torch.rand(8, 8, dtype=torch.float64), object_extent_m=0.5,
                       object_center_yz_m=(0.03, 0.529), background_width_m=8.0)
    head = HOAP3Head().to(dtype=torch.float64)
    poses = head.camera_poses(torch.tensor([0.1, -0.05], dtype=torch.float64),
                              torch.tensor([[3.0, 5.0], [-4.0, -1.0]], dtype=torch.float64),
                              torch.zeros(2, 2, dtype=torch.float64), convention="opengl")
    plane_x = torch.tensor([1.2, 2.5], dtype=torch.float64)
    offset = torch.tensor([0.12, -0.1], dtype=torch.float64)
    placement = Placement(torch.deg2rad(torch.tensor([35.0, -20.0], dtype=torch.float64)),
                          torch.tensor([2.0, 4.5], dtype=torch.float64), torch.tensor([1, 2]))
    images = TorchPlaneRenderer(scene)(poses, plane_x, torch.zeros(2, dtype=torch.long), plane_y_m=offset,
                                       placement=placement)
    seen, wrong = {"object": 0, "background": 0}, 0
    for b in range(2):
        for eye in range(2):
            for row in range(0, camera.height, 7):
                for col in range(0, camera.width, 7):
                    value, where = reference(poses[b, eye].numpy(), (col, row), camera, float(plane_x[b]),
                                             float(placement.slant_rad[b]), float(offset[b]), (0.03, 0.529), 3.0,
                                             0.5, float(placement.background_x_m[b]), 8.0)
                    seen[where] += 1
                    value = min(max(value, 0.5 / SIZE), 1 - 0.5 / SIZE)  # clamp to the edge texels
                    wrong += abs(float(images[b, eye, row, col]) - value) > 1e-9
    assert seen["object"] > 200 and seen["background"] > 200  # both planes in view
    assert wrong <= 2  # (a pixel's centre exactly on an edge may fall either way)


def test_a_point_on_the_slanted_plane_projects_with_the_pinhole_disparity():
    """The optimal vergence (the rule: the right axis through where the left axis meets the
    object's plane) against numpy: both axes meet at that point, and its disparity at the other
    eye's image centre is zero there."""
    env = ActiveDepthEnv(3, layout=DEPTH, textures=torch.rand(4, 16, 16), dtype=torch.float64, seed=3)
    env.set_pan_deg(torch.tensor([[1.0, 4.0], [-2.0, 0.0], [0.5, 3.0]], dtype=torch.float64))
    right = env.optimal_right_pan_deg()
    slant = torch.deg2rad(env.layout_draws.draws[:, 1]).numpy()
    eyes = env.head.eye_centres(env.body_shift_m).numpy()
    for b in range(3):
        normal = np.array([math.cos(slant[b]), math.sin(slant[b]), 0.0])
        pivot = np.array([float(env.plane_x_m[b]), env.scene.object_center_yz_m[0], 0.0])
        points = []
        for eye, pan in ((eyes[b, 0], float(env.pan_deg[b, 0])), (eyes[b, 1], float(right[b]))):
            ray = np.array([1.0, math.tan(math.radians(pan)), 0.0])
            points.append(eye + (normal @ (pivot - eye * [1, 1, 0])) / (normal @ ray) * ray)
        np.testing.assert_allclose(points[0][:2], points[1][:2], atol=1e-9)
    # the fixation target is on the object's plane, at the trial's distance straight ahead of the left eye
    torch.testing.assert_close(env.target_m[:, 0], env.plane_x_m)
    torch.testing.assert_close(env.target_m[:, 1], torch.full((3,), env.scene.object_center_yz_m[0],
                                                              dtype=torch.float64))


def test_axis_point_is_the_plain_planes_without_slant():
    head = HOAP3Head()
    eye = head.eye_centres(torch.tensor([0.1]))[:, 0]
    got = axis_point(eye, torch.tensor([-4.0]), torch.tensor([2.03]), None, 0.0)
    torch.testing.assert_close(got, head.plane_point_m(torch.tensor([-4.0]), 2.03, torch.tensor([0.1])))
    slanted = axis_point(eye, torch.tensor([-4.0]), torch.tensor([2.03]), torch.tensor([0.0]), 0.0)
    torch.testing.assert_close(slanted, got)


@pytest.mark.parametrize("filter", ["linear", "trilinear"])
def test_pyrender_draws_the_layout_as_the_torch_renderer_does(filter):
    from aectorch.sim import PyrenderRenderer

    bank = TextureBank.procedural(3, size=(256, 256), seed=7).textures
    bank = (bank * 255).round() / 255
    scene = PlaneScene(bank, bank[0, :64, :64], object_extent_m=0.6, object_center_yz_m=(0.03, 0.529),
                       background_width_m=8.0)
    head = HOAP3Head()
    poses = head.camera_poses(torch.tensor([0.1, -0.05]), torch.tensor([[0.0, 3.0], [2.0, 4.0]]),
                              torch.zeros(2, 2), convention="opengl")
    plane_x, index, offset = torch.tensor([1.03, 2.53]), torch.tensor([0, 1]), torch.tensor([0.1, -0.05])
    placement = Placement(torch.tensor([0.5, -0.4]), torch.tensor([2.5, 5.0]), torch.tensor([2, 0]))
    camera = PinholeCamera()
    windows = [(camera.central_window(128), 8), (camera.central_window(80), 2), (camera.central_window(128), 1)]
    renderer = PyrenderRenderer(scene, **(SCALE_FILTER if filter == "trilinear" else {}))
    try:
        theirs = renderer.render_windows(poses, plane_x, index, windows, plane_y_m=offset, placement=placement)
        plain = renderer.render_windows(poses, plane_x, index, windows)
    finally:
        renderer.close()
    torch_renderer = TorchPlaneRenderer(scene, **(SCALE_FILTER if filter == "trilinear" else {}))
    ours = torch_renderer.render_windows(poses, plane_x, index, windows, plane_y_m=offset, placement=placement)
    for a, b, c in zip(ours, theirs, plain):
        difference = (a - b).abs().mean()
        assert difference <= 0.01
        assert (a - c).abs().mean() > 5 * difference  # the check can fail


def test_the_plain_layout_is_the_plain_world_bit_for_bit():
    bank = TextureBank.procedural(3, size=(64, 64), seed=7)
    protocol = TrialProtocol(fixation_iterations=3)
    envs = [ActiveDepthEnv(2, protocol=protocol, textures=bank, seed=4, **kw) for kw in ({}, dict(layout=SceneLayout()))]
    for _ in range(4):
        out = []
        for env in envs:
            first = env.parallax_observation()["window"]
            env.apply_pursuit(torch.tensor([0.1, -0.2]))
            second = env.stereo_observation()["window"]
            env.apply_vergence(torch.tensor([0.2, 0.05]))
            out.append((first, second, env.end_iteration().optimal_right_pan_deg, env._generator.get_state()))
        for a, b in zip(*out):
            assert torch.equal(a, b)
    assert envs[1].layout_draws.draws is None and "scene_layout" not in envs[1].state_dict()
    for name in ("object_width_m", "object_center_yz_m", "background_x_m", "background_width_m", "object_extent_m"):
        assert getattr(envs[1].scene, name) == getattr(envs[0].scene, name)


def test_zero_placement_renders_the_plain_scene():
    scene = PlaneScene(torch.rand(2, 64, 64), torch.rand(16, 16))
    head = HOAP3Head()
    poses = head.camera_poses(torch.zeros(1), torch.tensor([[1.0, 3.0]]), torch.zeros(1, 2), convention="opengl")
    renderer = TorchPlaneRenderer(scene, **SCALE_FILTER)
    window = PinholeCamera().central_window(128)
    plain = renderer(poses, torch.tensor([1.53]), torch.tensor([1]), window, downsample=4)
    zero = renderer(poses, torch.tensor([1.53]), torch.tensor([1]), window, downsample=4,
                    placement=Placement(torch.zeros(1), torch.tensor([scene.background_x_m])))
    torch.testing.assert_close(zero, plain, rtol=0, atol=1e-5)
    assert torch.equal(renderer(poses, torch.tensor([1.53]), torch.tensor([1]), window, downsample=4,
                                placement=Placement()), plain)


def test_the_draws_are_in_range_and_resume():
    bank = TextureBank.procedural(5, size=(32, 32), seed=7)
    kwargs = dict(protocol=TrialProtocol(fixation_iterations=2), textures=bank, layout=DEPTH, seed=1)
    env = ActiveDepthEnv(64, **kwargs)
    offset, slant, depth, behind = env.layout_draws.draws.unbind(-1)
    assert offset.abs().max() <= 0.2 and slant.abs().max() <= 30 and slant.std() > 5
    assert depth.min() >= 0.5 and depth.max() <= 3.0
    assert bool((behind != env.texture_index).all()) and behind.min() >= 0 and behind.max() < 5
    env.reset()
    state = env.state_dict()
    copy = ActiveDepthEnv(64, **{**kwargs, "seed": 9})
    copy.load_state_dict(state)
    torch.testing.assert_close(copy.layout_draws.draws, env.layout_draws.draws)
    torch.testing.assert_close(copy.stereo_observation()["window"], env.stereo_observation()["window"])


@pytest.mark.parametrize("kwargs, match", [
    (dict(object_width_m=0.0), "scene.object_width_m"),
    (dict(object_width_m=4.0), "scene.object_width_m"),
    (dict(object_width_m=0.4, object_offset_m=[-0.3, 0.0]), "scene.object_offset_m"),
    (dict(slant_deg=[10.0, -10.0]), "scene.slant_deg"),
    (dict(slant_deg=[0.0, 75.0]), "scene.slant_deg"),
    (dict(background_depth_m=[0.0, 1.0]), "scene.background_depth_m"),
    (dict(background_depth_m=[1.0]), "scene.background_depth_m"),
    (dict(background_texture="photo"), "scene.background_texture"),
    (dict(background_width_m=-1.0), "scene.background_width_m"),
])
def test_bad_layouts_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SceneLayout(**kwargs)


def test_the_config_names_the_option_and_the_environment_refuses_what_it_cannot_draw():
    from aectorch.runtime.config import to_experiment_config

    with pytest.raises(ValueError, match="env.scene.slant_deg"):
        to_experiment_config({"env": {"scene": {"slant_deg": [-70, 0]}}})
    with pytest.raises(ValueError, match="moving object"):
        ActiveDepthEnv(1, protocol=TrialProtocol(object_speed_deg=(0.0, 1.0)), textures=torch.rand(3, 8, 8),
                       layout=DEPTH)
    with pytest.raises(ValueError, match="background_texture"):
        ActiveDepthEnv(1, textures=torch.rand(1, 8, 8), layout=DEPTH)
    with pytest.raises(TypeError, match="layout"):
        ActiveDepthEnv(1, textures=torch.rand(2, 8, 8), layout={"slant_deg": [0, 1]})
    scene = PlaneScene(torch.rand(2, 8, 8), torch.rand(8, 8))
    poses = torch.eye(4).expand(2, 1, 4, 4)
    with pytest.raises(ValueError, match="placement.slant_rad"):
        TorchPlaneRenderer(scene)(poses, torch.ones(2), torch.zeros(2, dtype=torch.long),
                                  placement=Placement(torch.zeros(3)))
    with pytest.raises(ValueError, match="placement.background_index"):
        TorchPlaneRenderer(scene)(poses, torch.ones(2), torch.zeros(2, dtype=torch.long),
                                  placement=Placement(background_index=torch.tensor([0, 2])))
    with pytest.raises(ValueError, match="object_extent_m"):
        PlaneScene(torch.rand(2, 8, 8), torch.rand(8, 8), object_extent_m=3.5)
