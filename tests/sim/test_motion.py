"""A moving object (`aectorch.sim.motion`): both renderers draw the moved plane alike, the
environment's ground truth follows the object, and the still object's defaults are untouched."""

import math

import pytest
import torch

from aectorch.sim import ActiveDepthEnv, HOAP3Head, PlaneScene, TextureBank, TorchPlaneRenderer
from aectorch.sim.env import SCALE_FILTER
from aectorch.sim.motion import object_place
from aectorch.sim.protocol import TrialProtocol

torch.set_num_threads(1)


def quantised(x):
    return (x * 255).round() / 255


@pytest.fixture(scope="module")
def bank():
    return TextureBank(quantised(TextureBank.procedural(3, size=(256, 256), seed=7).textures))


@pytest.fixture(scope="module")
def scene(bank):
    return PlaneScene(bank.textures, quantised(TextureBank.procedural(1, size=(64, 64), seed=8).textures[0]))


def poses_and_planes(dtype=torch.float64):
    head = HOAP3Head().to(dtype=dtype)
    poses = head.camera_poses(torch.tensor([0.1, -0.05], dtype=dtype), torch.tensor([[8.0, 9.0], [-20.0, -19.0]],
                              dtype=dtype), torch.zeros(2, 2, dtype=dtype), convention="opengl")
    return poses, torch.tensor([1.5, 2.5], dtype=dtype) + head.eye_x_m, torch.tensor([0.3, -1.2], dtype=dtype)


def test_a_plane_moved_sideways_is_the_cameras_moved_the_other_way(scene):
    """Oracle: where the object fills the view, moving it by y is moving the cameras by -y; the fused
    kernel and the torch code agree on it, and the background stays where it was."""
    import aectorch.sim.render_torch as render_torch
    from aectorch.sim.camera import PinholeCamera

    camera = PinholeCamera()
    crops = camera.central_window(64)
    poses, plane_x, y = poses_and_planes()
    index = torch.tensor([0, 2])
    renderer = TorchPlaneRenderer(scene, **SCALE_FILTER).double()
    moved = renderer(poses, plane_x, index, crops, plane_y_m=y)
    shifted = poses.clone()
    shifted[..., 1, 3] -= y[:, None]
    torch.testing.assert_close(moved, renderer(shifted, plane_x, index, crops), rtol=0, atol=1e-9)
    assert (moved - renderer(poses, plane_x, index, crops)).abs().mean() > 0.02  # it did move
    native = render_torch._native_trilinear
    try:
        render_torch._native_trilinear = lambda *args: False
        eager = renderer(poses, plane_x, index, crops, plane_y_m=y)
    finally:
        render_torch._native_trilinear = native
    torch.testing.assert_close(moved, eager, rtol=0, atol=1e-9)
    # The whole frame: the background did not move with the object.
    full_moved = renderer(poses, plane_x, index, plane_y_m=y)
    full_shifted = renderer(shifted, plane_x, index)
    assert (full_moved - full_shifted).abs().amax() > 0.1
    with pytest.raises(ValueError, match="plane_y_m"):
        renderer(poses, plane_x, index, crops, plane_y_m=y[:1])


def test_pyrender_draws_the_moved_plane_as_the_torch_renderer_does(scene):
    from aectorch.sim import PyrenderRenderer

    poses, plane_x, y = poses_and_planes(torch.float32)
    index = torch.tensor([0, 2])
    ours = TorchPlaneRenderer(scene)(poses, plane_x, index, plane_y_m=y)
    renderer = PyrenderRenderer(scene)
    try:
        theirs = renderer(poses, plane_x, index, plane_y_m=y)
        still = renderer(poses, plane_x, index)
    finally:
        renderer.close()
    difference = (ours - theirs).abs().mean()
    assert difference <= 0.01
    assert (ours - still).abs().mean() > 5 * difference  # the check can fail


def pursue(env, iterations):
    """Iterations with both eye movements at their optima; the infos."""
    infos = []
    for _ in range(iterations):
        env.parallax_observation()
        env.hold("parallax")
        env.stereo_observation()
        env.hold("stereo")
        infos.append(env.end_iteration())
    return infos


def test_the_ground_truth_follows_the_object(bank):
    protocol = TrialProtocol(fixation_iterations=4, shift_m=0.0, object_speed_deg=(-2.0, 2.0),
                             object_depth_speed_m=(-0.05, 0.0))
    env = ActiveDepthEnv(2, protocol=protocol, textures=bank, distances_m=[1.0, 2.0], seed=1)
    env.set_object_speed(torch.tensor([1.5, -0.5]), torch.tensor([-0.05, 0.0]))
    env.set_trial(torch.tensor([0, 1]), torch.tensor([1.0, 2.0]))
    infos = pursue(env, 8)
    # The left eye's pan after k steps: the target (the point straight ahead of it at the start,
    # carried with the object) seen from the left eye.
    eye_y = float(env.head.eye_centres(torch.zeros(1))[0, 0, 1])
    for k, info in enumerate(infos[:4], 1):
        distance, y = object_place(torch.tensor([1.0, 2.0], dtype=torch.float64),
                                   torch.tensor([[1.5, -0.05], [-0.5, 0.0]], dtype=torch.float64), k)
        expected = torch.rad2deg(torch.atan2(y, distance)).float()
        torch.testing.assert_close(info.optimal_left_pan_deg, expected, atol=1e-4, rtol=0)
        assert eye_y != 0 and info.pursuit_error_deg.abs().max() < 1e-4
        assert info.vergence_error_deg.abs().max() < 1e-4
    # Vergence follows the approaching object: it converges more at every step.
    vergence = torch.stack([i.optimal_right_pan_deg - i.optimal_left_pan_deg for i in infos[:4]])
    assert (vergence[1:, 0] > vergence[:-1, 0] + 0.05).all() and (vergence[1:, 1] - vergence[:-1, 1]).abs().max() < 1e-3
    # Each fixation starts from the trial's place; both end at the same distance, the depth's truth.
    torch.testing.assert_close(infos[4].optimal_left_pan_deg, infos[0].optimal_left_pan_deg)
    torch.testing.assert_close(infos[-1].distance_m, torch.tensor([0.8, 2.0]))
    # The image follows: the eye that keeps the target has the start image in its fovea (rotated and
    # scaled a little by the plane's motion), far closer than an eye that stays still.
    env.set_object_speed(torch.tensor([1.0, 1.0]), None)
    env.set_trial(torch.tensor([0, 1]), torch.tensor([1.0, 2.0]))
    pursue(env, 2)
    env.parallax_observation()
    env.hold("parallax")
    followed = env.parallax_observation()["window"][:, :, 40:88, 40:88]
    env.apply_pursuit(-env.left_pan_deg)
    stayed = env.parallax_observation()["window"][:, :, 40:88, 40:88]
    assert (followed[:, 0] - followed[:, 1]).abs().mean() < 0.3 * (stayed[:, 0] - stayed[:, 1]).abs().mean()


def test_draws_are_within_the_ranges_and_the_state_resumes(bank):
    kwargs = dict(textures=bank, seed=3, protocol=TrialProtocol(fixation_iterations=3, object_speed_deg=(0.5, 1.0),
                                                                object_depth_speed_m=(-0.02, -0.01)))
    env = ActiveDepthEnv(4, **kwargs)
    speeds = [env.motion.speed.clone()]  # fixations 0 and 1 of two trials
    for _ in range(3):
        pursue(env, 3)
        speeds.append(env.motion.speed.clone())
    speeds = torch.stack(speeds)
    assert (speeds[..., 0] >= 0.5).all() and (speeds[..., 0] <= 1.0).all()
    assert (speeds[..., 1] >= -0.02).all() and (speeds[..., 1] <= -0.01).all()
    assert not torch.equal(speeds[0, :, 0], speeds[1, :, 0])  # sideways: drawn per fixation
    torch.testing.assert_close(speeds[0, :, 1], speeds[1, :, 1])  # in depth: per trial
    assert not torch.equal(speeds[1, :, 1], speeds[2, :, 1])
    pursue(env, 1)
    state = env.state_dict()
    copy = ActiveDepthEnv(4, **kwargs)
    copy.load_state_dict(ActiveDepthEnv.join_states([ActiveDepthEnv.state_rows(state, 0, 2),
                                                     ActiveDepthEnv.state_rows(state, 2, 4)]))
    torch.testing.assert_close(copy.motion.plane_y_m, env.motion.plane_y_m)
    a, b = pursue(env, 5), pursue(copy, 5)
    for x, y in zip(a, b):
        torch.testing.assert_close(x.optimal_left_pan_deg, y.optimal_left_pan_deg)
    torch.testing.assert_close(env.stereo_observation()["window"], copy.stereo_observation()["window"])


def test_the_still_object_is_untouched(bank):
    """The default draws nothing more and renders as it always did: no sideways offset at all."""
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=bank, seed=0)
    pursue(env, 3)
    assert env.motion.speed is None and env.motion.plane_y_m is None and "object_speed" not in env.state_dict()
    torch.testing.assert_close(env.object_distance_m, env.distance_m, rtol=0, atol=0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(object_speed_deg=(1.0, -1.0)), "object_speed_deg"),
    (dict(object_speed_deg=3.0), "object_speed_deg"),
    (dict(object_depth_speed_m=("a", 0)), "object_depth_speed_m"),
    (dict(object_speed_deg=(-3.0, 3.0), fixation_iterations=30), "turns the object by 90"),
    (dict(object_depth_speed_m=(-0.05, 0.0), fixation_iterations=30), "object_depth_speed_m.*0.2"),
    (dict(object_depth_speed_m=(0.0, 0.2), fixation_iterations=30), "object_depth_speed_m"),
])
def test_bad_motions_are_refused_by_name(bank, kwargs, match):
    with pytest.raises(ValueError, match=match):
        ActiveDepthEnv(1, protocol=TrialProtocol(**kwargs), textures=bank)
    with pytest.raises(ValueError, match="speed_deg"):
        ActiveDepthEnv(1, textures=bank).set_object_speed(torch.ones(3))
    assert TrialProtocol(object_speed_deg=[-1, 1]).moving and not TrialProtocol().moving
    assert math.isfinite(TrialProtocol(object_depth_speed_m=(-0.01, 0.0)).object_depth_speed_m[0])


def test_the_tracking_test_tells_a_tracker_from_a_slow_eye(bank, tmp_path):
    """`run_tracking` on the classical matcher: unconstrained it follows a 1 deg/iteration object
    within 0.2 deg, limited to 0.2 deg steps it falls behind; the rows, the table per speed, the
    figure."""
    from aectorch.baselines import Matcher
    from aectorch.evaluation.trials import run_tracking, tracking_by_speed, tracking_rows
    from aectorch.figures import plot_tracking

    protocol = TrialProtocol(fixation_iterations=8, shift_m=0.0)  # the object alone moves
    textures = TextureBank(bank.textures[:2])
    out = {name: run_tracking(matcher, textures, speeds_deg=[0.0, 1.0], distances_m=[1.5], protocol=protocol, skip=3)
           for name, matcher in (("free", Matcher(actions_deg=None)), ("slow", Matcher(actions_deg=[-0.2, 0.0, 0.2])))}
    free, slow = (tracking_by_speed(out[name]) for name in ("free", "slow"))
    assert [row["speed_deg"] for row in free] == [0.0, 1.0] and free[1]["trials"] == 2
    assert free[1]["pursuit_tracking_deg"] < 0.2 and free[1]["vergence_tracking_deg"] < 0.2
    assert slow[1]["pursuit_tracking_deg"] > 1.0 > slow[0]["pursuit_tracking_deg"]
    # The slow eye falls behind (a negative lead) by 0.8 deg more every iteration; the free one keeps pace.
    assert slow[1]["pursuit_lead_tracking_deg"] < -1.0 and abs(free[1]["pursuit_lead_tracking_deg"]) < 0.2
    assert abs(slow[1]["pursuit_speed_tracking_deg"] - 0.8) < 0.05 and free[1]["pursuit_speed_tracking_deg"] < 0.2
    assert free[0]["pursuit_lead_tracking_deg"] == 0.0  # no sideways motion, nothing to lead
    rows = tracking_rows(out["free"], textures.names)
    assert [row["speed_deg"] for row in rows] == [0.0, 0.0, 1.0, -1.0]  # both directions
    assert len(rows[0]["pursuit_tracking_deg"]) == 2  # both fixations
    assert plot_tracking([free, slow], tmp_path / "tracking.png", target_deg=0.2).exists()
    with pytest.raises(ValueError, match="speeds_deg"):
        run_tracking(Matcher(), textures, speeds_deg=[-1.0], protocol=protocol)
    with pytest.raises(ValueError, match="skip"):
        run_tracking(Matcher(), textures, speeds_deg=[1.0], protocol=protocol, skip=8)


def test_the_environments_of_both_renderers_see_the_moving_object_alike(bank):
    """What the coder reads (every default scale) of a moving object, in both renderers."""
    from aectorch.coding.patches import DEFAULT_SCALES, as_scale

    scales = [as_scale(s) for s in DEFAULT_SCALES]
    envs = [ActiveDepthEnv(2, protocol=TrialProtocol(renderer=name, fixation_iterations=3, object_speed_deg=(-2.0, 2.0),
                                                     object_depth_speed_m=(-0.05, 0.05)), textures=bank, seed=5)
            for name in ("torch", "pyrender")]
    try:
        for _ in range(4):
            pairs = []
            for env in envs:
                first = env.parallax_observation(scales)
                env.hold("parallax")
                pairs.append((first, env.stereo_observation(scales)))
                env.hold("stereo")
                env.end_iteration()
            torch.testing.assert_close(envs[0].motion.plane_y_m, envs[1].motion.plane_y_m)
            for ours, theirs in zip(*pairs):
                for name in ours:
                    assert (ours[name] - theirs[name]).abs().mean() < 0.01, name
        assert envs[0].motion.plane_y_m.abs().min() > 0  # it moved
    finally:
        for env in envs:
            env.close()
