"""HOAP-3 head: URDF content, forward kinematics conventions, closed-form fixations vs FK."""

from __future__ import annotations

import doctest
import math
import re
import xml.etree.ElementTree as ET

import pytest
import pytorch_kinematics as pk
import torch

import aectorch.sim.hoap3 as hoap3
from aectorch.sim.hoap3 import DEFAULT_URDF_PATH, SIM_ONLY_JOINTS, HOAP3Head

torch.set_num_threads(1)

F64 = torch.float64
README = DEFAULT_URDF_PATH.parent / "README.md"


@pytest.fixture(scope="module")
def head64() -> HOAP3Head:
    return HOAP3Head(dtype=F64)


def _poses(head, shift, pan, roll=None, convention="ros", **neck):
    return head.camera_poses(shift, pan, roll, convention=convention, **neck)


def _zeros(b=1, dtype=F64):
    return torch.zeros(b, dtype=dtype), torch.zeros(b, 2, dtype=dtype)


def _t(*values):
    return torch.tensor(values, dtype=F64)


# ---------------------------------------------------------------------------------- the URDF


def test_urdf_every_movable_joint_has_axis_and_full_limit():
    robot = ET.parse(DEFAULT_URDF_PATH).getroot()
    movable = [j for j in robot.iter("joint") if j.get("type") != "fixed"]
    assert {j.get("name") for j in movable} == set(hoap3.JOINT_NAMES)
    for joint in movable:
        name = joint.get("name")
        axis = joint.find("axis")
        assert axis is not None and axis.get("xyz"), f"{name} has no explicit <axis xyz=...>"
        limit = joint.find("limit")
        assert limit is not None, f"{name} has no <limit>"
        for attribute in ("lower", "upper", "effort", "velocity"):
            assert limit.get(attribute) is not None, f"{name}'s <limit> lacks {attribute}"
        assert float(limit.get("lower")) < float(limit.get("upper"))


def test_urdf_numbers_and_tilt_limits():
    robot = ET.parse(DEFAULT_URDF_PATH).getroot()
    joints = {j.get("name"): j for j in robot.iter("joint")}
    tilt = joints["neck_tilt"].find("limit")
    assert float(tilt.get("lower")) == pytest.approx(-0.785398, abs=1e-6)  # 45 deg up
    assert float(tilt.get("upper")) == pytest.approx(0.261799, abs=1e-6)  # 15 deg down
    assert joints["body_shift"].get("type") == "prismatic"
    assert joints["body_shift"].find("axis").get("xyz").split() == ["0", "1", "0"]
    assert joints["waist_joint"].find("origin").get("xyz").split() == ["0", "0", "0.305"]


def test_sim_only_joints_are_marked_in_urdf_and_readme():
    text = DEFAULT_URDF_PATH.read_text()
    comments = " ".join(re.findall(r"<!--(.*?)-->", text, flags=re.DOTALL))
    assert "SIMULATION-ONLY" in comments
    readme = README.read_text()
    for name in SIM_ONLY_JOINTS:
        assert name in comments, f"{name} is not named in a URDF comment"
        assert name in readme, f"{name} is not listed in robots/hoap3/README.md"
    assert "body_shift" in SIM_ONLY_JOINTS and "neck_pan" not in SIM_ONLY_JOINTS


def test_exact_chain_matches_plain_pytorch_kinematics_parse(head64):
    # Guards the float64 re-read of the URDF origins (rpy order, axes) against pk's own parser.
    plain = pk.build_chain_from_urdf(DEFAULT_URDF_PATH.read_text())
    assert tuple(plain.get_joint_parameter_names()) == head64.joint_names
    th = (torch.rand(16, len(head64.joint_names), generator=torch.Generator().manual_seed(0)) - 0.5)
    ours = head64._chain.forward_kinematics(th.to(F64))
    theirs = plain.forward_kinematics(th)
    for name, transform in theirs.items():
        assert torch.allclose(ours[name].get_matrix().float(), transform.get_matrix(), atol=1e-5)


def test_origin_matrix_follows_urdf_rpy_like_pytorch_kinematics():
    g = torch.Generator().manual_seed(4)
    for _ in range(8):
        rpy = (torch.rand(3, generator=g) - 0.5) * 6.0
        xyz = torch.rand(3, generator=g) - 0.5
        xyz_text, rpy_text = (" ".join(map(str, v.tolist())) for v in (xyz, rpy))
        origin = ET.fromstring(f'<origin xyz="{xyz_text}" rpy="{rpy_text}"/>')
        ours = hoap3._origin_matrix(origin)
        theirs = pk.transforms.Transform3d(
            rot=pk.transforms.quaternion_from_euler(rpy, "sxyz"), pos=xyz
        ).get_matrix()[0]
        assert torch.allclose(ours.float(), theirs, atol=1e-6)
    assert torch.equal(hoap3._origin_matrix(None), torch.eye(4, dtype=F64))


# ---------------------------------------------------------------------------------- FK conventions


def test_zero_pose_eye_centres_and_geometry(head64):
    shift, _ = _zeros()
    centres = head64.eye_centres(shift)[0]
    expected = _t([0.03, 0.03, 0.529], [0.03, -0.03, 0.529])
    assert torch.allclose(centres, expected, rtol=0, atol=1e-15)  # exact float64 geometry
    assert head64.baseline_m == pytest.approx(0.06, abs=1e-15)
    assert head64.eye_height_m == pytest.approx(0.529, abs=1e-15)
    assert head64.eye_x_m == pytest.approx(0.03, abs=1e-15)


def test_zero_pose_optical_frames(head64):
    shift, pan = _zeros()
    ros = _poses(head64, shift, pan, convention="ros")[0]
    gl = _poses(head64, shift, pan, convention="opengl")[0]
    ex, ey, ez = torch.eye(3, dtype=F64)
    for eye in range(2):
        R = ros[eye, :3, :3]
        assert torch.allclose(R[:, 2], ex, atol=1e-12)  # optical axis forward
        assert torch.allclose(R[:, 0], -ey, atol=1e-12)  # image x to the right
        assert torch.allclose(R[:, 1], -ez, atol=1e-12)  # image y down
        G = gl[eye, :3, :3]
        assert torch.allclose(-G[:, 2], ex, atol=1e-12)  # OpenGL looks along -z
        assert torch.allclose(G[:, 1], ez, atol=1e-12)  # y up
        assert torch.allclose(G[:, 0], -ey, atol=1e-12)  # x right
        assert torch.allclose(ros[eye, :, 3], gl[eye, :, 3], atol=0)  # same optical centre
        assert torch.allclose(torch.linalg.det(R), torch.ones((), dtype=F64))
    assert torch.allclose(ros[:, 3], _t([0, 0, 0, 1], [0, 0, 0, 1]))


def test_body_shift_moves_both_eyes_along_y(head64):
    shift = _t(0.0, 0.1, -0.2, 0.037)
    centres = head64.eye_centres(shift)
    delta = centres - centres[:1]
    expected = torch.stack([torch.zeros_like(shift), shift - shift[0], torch.zeros_like(shift)], 1)
    assert torch.allclose(delta, expected.unsqueeze(1).expand(-1, 2, -1), atol=1e-15)


def test_pan_rotates_optical_axis_about_world_z_positive_to_the_left(head64):
    pan = _t([30.0, -20.0], [0.0, 90.0])
    shift = torch.zeros(2, dtype=F64)
    T = _poses(head64, shift, pan)
    rad = torch.deg2rad(pan)
    axis = torch.stack([torch.cos(rad), torch.sin(rad), torch.zeros_like(rad)], -1)
    assert torch.allclose(T[..., :3, 2], axis, atol=1e-12)
    assert torch.allclose(T[..., :3, 3], head64.eye_centres(shift), atol=1e-15)  # centre fixed
    assert T[0, 0, 1, 2] > 0  # positive pan looks toward +y (left)


def test_roll_turns_image_axes_about_the_optical_axis(head64):
    roll_deg = 20.0
    shift, pan = _zeros()
    roll = _t([roll_deg, -roll_deg])
    T = _poses(head64, shift, pan, roll)[0]
    r = math.radians(roll_deg)
    ex = _t(1.0, 0.0, 0.0)
    assert torch.allclose(T[0, :3, 2], ex, atol=1e-12)  # optical axis unchanged
    assert torch.allclose(T[1, :3, 2], ex, atol=1e-12)
    # positive roll lifts the camera's left side, so its right side (image +x) goes down
    assert torch.allclose(T[0, :3, 0], _t(0.0, -math.cos(r), -math.sin(r)), atol=1e-12)
    assert torch.allclose(T[1, :3, 0], _t(0.0, -math.cos(r), math.sin(r)), atol=1e-12)
    # roll after pan still turns about the (panned) optical axis
    pan = _t([25.0, -10.0])
    axis_no_roll = _poses(head64, shift, pan)[0, :, :3, 2]
    axis_roll = _poses(head64, shift, pan, roll)[0, :, :3, 2]
    assert torch.allclose(axis_no_roll, axis_roll, atol=1e-12)


def test_neck_tilt_positive_looks_down_and_neck_pan_turns_about_neck_axis(head64):
    shift, pan = _zeros(2)
    tilt = _t(15.0, -45.0)
    T = _poses(head64, shift, pan, neck_tilt_deg=tilt, neck_pan_deg=torch.zeros(2, dtype=F64))
    t = torch.deg2rad(tilt)
    assert T[0, 0, 2, 2] < 0 and T[1, 0, 2, 2] > 0  # +15 (upper limit) down, -45 up
    assert torch.allclose(T[:, 0, :3, 2], torch.stack([t.cos(), 0 * t, -t.sin()], -1), atol=1e-12)
    # neck pan by 90 deg: the left eye swings around the neck axis at x = -0.035 m
    centres = head64.eye_centres(shift[:1], neck_pan_deg=_t(90.0))[0]
    x_pan, y_rel = -0.035, 0.03
    forward = 0.03 - x_pan  # eye centre in front of the neck pan axis
    assert torch.allclose(centres[0], _t(x_pan - y_rel, forward, 0.529), atol=1e-12)
    assert torch.allclose(centres[1], _t(x_pan + y_rel, forward, 0.529), atol=1e-12)


def test_upper_tilt_limit_is_the_downward_one(head64):
    low, high = head64.limits_deg["neck_tilt"]
    assert low == pytest.approx(-45.0) and high == pytest.approx(15.0)
    shift, pan = _zeros()
    down = _poses(head64, shift, pan, neck_tilt_deg=_t(high), neck_pan_deg=_t(0.0))
    assert down[0, 0, 2, 2] < 0


# ---------------------------------------------------------------------------------- closed forms


def _random(n, seed):
    g = torch.Generator().manual_seed(seed)
    return lambda lo, hi: lo + (hi - lo) * torch.rand(n, generator=g, dtype=F64)


def test_pursuit_pan_points_the_optical_axis_at_the_target(head64):
    n = 256
    draw = _random(n, 1)
    shift = draw(-0.2, 0.2)
    target = torch.stack([head64.eye_x_m + draw(0.5, 5.0), draw(-1.0, 1.0), draw(0.0, 1.5)], 1)
    left = head64.pursuit_pan_deg(target, shift)
    right = head64.pursuit_pan_deg(target, shift, eye="right")
    T = _poses(head64, shift, torch.stack([left, right], 1))
    flat = target.clone()
    flat[:, 2] = head64.eye_height_m  # pan acts in the horizontal plane: the height is ignored
    for eye in range(2):
        origin, axis = T[:, eye, :3, 3], T[:, eye, :3, 2]
        to_target = flat - origin
        miss = torch.linalg.cross(to_target, axis).norm(dim=1)
        assert miss.max() < 1e-9
        assert ((to_target * axis).sum(1) > 0).all()  # in front, not behind


def test_pursuit_pan_paper_numbers(head64):
    d = _t(1.0, 2.0, 3.0)
    target = torch.stack([head64.eye_x_m + d, torch.full_like(d, 0.03), torch.zeros_like(d)], 1)
    pan = head64.pursuit_pan_deg(target, torch.full_like(d, 0.1))
    assert torch.allclose(pan, -torch.rad2deg(torch.atan(0.1 / d)), atol=1e-12)
    assert pan.tolist() == pytest.approx([-5.71, -2.86, -1.91], abs=0.005)  # aec-lineage.md
    assert torch.equal(head64.pursuit_pan_deg(target, torch.zeros_like(d)), torch.zeros_like(d))


def test_vergence_pan_fixates_the_left_eyes_point_on_the_plane(head64):
    n = 256
    draw = _random(n, 2)
    shift, left = draw(-0.2, 0.2), draw(-10.0, 10.0)
    plane_x = head64.eye_x_m + draw(0.5, 5.0)
    right = head64.vergence_pan_deg(left, plane_x, shift)
    T = _poses(head64, shift, torch.stack([left, right], 1))
    hits = []
    for eye in range(2):
        origin, axis = T[:, eye, :3, 3], T[:, eye, :3, 2]
        scale = (plane_x - origin[:, 0]) / axis[:, 0]
        assert (scale > 0).all()
        hits.append(origin + scale[:, None] * axis)
    assert (hits[0] - hits[1]).norm(dim=1).max() < 1e-9
    point = head64.plane_point_m(left, plane_x, shift)
    assert (point - hits[0]).norm(dim=1).max() < 1e-9


def test_vergence_paper_numbers_and_sign(head64):
    d = _t(1.0, 2.0, 3.0)
    zero = torch.zeros_like(d)
    right = head64.vergence_pan_deg(zero, head64.eye_x_m + d, zero)
    assert torch.allclose(right, torch.rad2deg(torch.atan(0.06 / d)), atol=1e-12)
    # aec-lineage.md lists 3.44 / 1.72 / 1.15 deg for a symmetric fixation, 2 atan(0.03 / d); with
    # the left eye straight ahead the whole vergence is on the right eye: atan(0.06 / d)
    assert right.tolist() == pytest.approx([3.4336, 1.7184, 1.1458], abs=1e-4)
    assert (HOAP3Head.vergence_deg(zero, right) > 0).all()  # converging is positive
    # a float plane position works as well as a tensor one
    one = head64.vergence_pan_deg(zero[:1], head64.eye_x_m + 1.0, zero[:1])
    assert torch.allclose(one, right[:1])


def test_closed_forms_are_differentiable(head64):
    g = torch.Generator().manual_seed(3)
    target = torch.stack(
        [1.0 + torch.rand(3, generator=g, dtype=F64), torch.rand(3, generator=g, dtype=F64),
         torch.zeros(3, dtype=F64)], 1
    ).requires_grad_()
    shift = (0.1 * torch.rand(3, generator=g, dtype=F64)).requires_grad_()
    left = torch.rand(3, generator=g, dtype=F64).requires_grad_()
    assert torch.autograd.gradcheck(head64.pursuit_pan_deg, (target, shift))
    plane = torch.full((3,), 1.5, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(head64.vergence_pan_deg, (left, plane, shift))


def test_camera_poses_are_differentiable_in_the_eye_angles(head64):
    shift = torch.tensor([0.05], dtype=F64)
    pan = torch.tensor([[3.0, -2.0]], dtype=F64, requires_grad=True)
    T = head64.camera_poses(shift, pan, convention="ros")
    T[0, 0, 1, 2].backward()  # y component of the left optical axis: d sin(p) / d p_deg
    expected = math.cos(math.radians(3.0)) * math.pi / 180
    assert pan.grad[0, 0].item() == pytest.approx(expected, rel=1e-9)
    assert pan.grad[0, 1].item() == pytest.approx(0.0, abs=1e-15)


# ---------------------------------------------------------------------------------- dtype, limits


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_output_dtype_follows_inputs(dtype):
    head = HOAP3Head(dtype=dtype)
    shift, pan = _zeros(3, dtype)
    assert head.camera_poses(shift, pan).dtype == dtype
    assert head.eye_centres(shift).dtype == dtype
    target = torch.tensor([[1.0, 0.0, 0.5]] * 3, dtype=dtype)
    assert head.pursuit_pan_deg(target, shift).dtype == dtype
    assert head.vergence_pan_deg(shift, 1.0, shift).dtype == dtype
    assert torch.allclose(head.eye_centres(shift)[0, 0].double(), _t(0.03, 0.03, 0.529), atol=1e-7)


def test_to_moves_the_chain_and_keeps_float64_exact():
    head = HOAP3Head()
    shift, pan = _zeros(2)
    with pytest.raises(TypeError, match=r"shift_m.*head\.to"):
        head.camera_poses(shift, pan)
    assert head.to(F64) is head and head.dtype == F64
    z = head.eye_centres(shift)[:, :, 2]
    assert torch.allclose(z, torch.full_like(z, 0.529), rtol=0, atol=1e-15)
    head.float()
    assert head.dtype == torch.float32
    assert head.camera_poses(shift.float(), pan.float()).dtype == torch.float32
    head.double()  # back from float32: rebuilt from the float64 master, no float32 rounding
    assert head.eye_centres(shift)[0, 0, 2].item() == pytest.approx(0.529, abs=1e-15)
    assert head.state_dict() == {}  # the URDF, not the checkpoint, defines the head


def test_clamp_pan_and_limits(head64):
    assert head64.limits_deg["left_eye_pan"] == pytest.approx((-45.0, 45.0))
    assert head64.limits_deg["neck_pan"] == pytest.approx((-60.0, 60.0))
    assert "body_shift" not in head64.limits_deg
    assert head64.shift_limits_m == pytest.approx((-0.2, 0.2))
    assert head64.limits["neck_tilt"] == pytest.approx((-math.pi / 4, math.pi / 12))
    pan = torch.tensor([[50.0, -3.0], [-90.0, 44.0]])
    assert torch.equal(head64.clamp_pan_deg(pan), torch.tensor([[45.0, -3.0], [-45.0, 44.0]]))
    assert head64.clamp_pan_deg(pan.double()).dtype == F64


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.cuda
def test_cuda():
    head = HOAP3Head(device="cuda")
    shift, pan = (x.cuda().float() for x in _zeros(4))
    T = head.camera_poses(shift, pan)
    assert T.device.type == "cuda" and T.dtype == torch.float32
    target = torch.tensor([[1.0, 0.0, 0.5]] * 4, device="cuda")
    assert head.pursuit_pan_deg(target, shift).device.type == "cuda"
    cpu = HOAP3Head()
    assert torch.allclose(T.cpu(), cpu.camera_poses(shift.cpu(), pan.cpu()), atol=1e-6)
    head.cpu()
    assert head.device.type == "cpu"
    assert head.camera_poses(shift.cpu(), pan.cpu()).device.type == "cpu"


# ---------------------------------------------------------------------------------- errors


def test_bad_inputs_raise_with_the_argument_name(head64):
    shift, pan = _zeros(3)
    with pytest.raises(ValueError, match=r"pan_deg.*shift_m.*\[3\].*\[2, 2\]"):
        head64.camera_poses(shift, pan[:2])
    with pytest.raises(ValueError, match="roll_deg"):
        head64.camera_poses(shift, pan, torch.zeros(3, dtype=F64))
    with pytest.raises(ValueError, match="neck_tilt_deg"):
        head64.camera_poses(shift, pan, neck_tilt_deg=torch.zeros(2, dtype=F64))
    with pytest.raises(TypeError, match="shift_m"):
        head64.camera_poses(torch.zeros(3, dtype=torch.long), pan)
    with pytest.raises(TypeError, match="pan_deg"):
        head64.camera_poses(shift, [[0.0, 0.0]] * 3)
    with pytest.raises(TypeError, match="pan_deg.*float32.*shift_m"):
        head64.camera_poses(shift, pan.float())
    with pytest.raises(ValueError, match=r"convention.*opengl.*ros"):
        head64.camera_poses(shift, pan, convention="pyrender")
    with pytest.raises(ValueError, match="shift_m"):
        head64.eye_centres(shift[:, None])
    with pytest.raises(ValueError, match="target_m"):
        head64.pursuit_pan_deg(torch.zeros(3, 2, dtype=F64), shift)
    with pytest.raises(ValueError, match="eye"):
        head64.pursuit_pan_deg(torch.zeros(3, 3, dtype=F64), shift, eye="both")
    with pytest.raises(ValueError, match="left_pan_deg"):
        head64.vergence_pan_deg(torch.zeros(4, dtype=F64), 1.0, shift)
    with pytest.raises(ValueError, match="plane_x_m"):
        head64.vergence_pan_deg(shift, torch.ones(2, dtype=F64), shift)
    with pytest.raises(ValueError, match="pan_deg"):
        head64.clamp_pan_deg(torch.zeros(3))
    with pytest.raises(ValueError, match="right_pan_deg"):
        HOAP3Head.vergence_deg(torch.zeros(2), torch.zeros(3))


def test_urdf_path_argument_and_missing_file(tmp_path):
    assert HOAP3Head(str(DEFAULT_URDF_PATH)).baseline_m == pytest.approx(0.06)
    missing = tmp_path / "nowhere.urdf"
    with pytest.raises(FileNotFoundError, match="nowhere.urdf"):
        HOAP3Head(missing)
    broken = tmp_path / "broken.urdf"
    broken.write_text(DEFAULT_URDF_PATH.read_text().replace('"right_eye_roll"', '"r_roll"'))
    with pytest.raises(ValueError, match="right_eye_roll"):
        HOAP3Head(broken)


def test_docstring_examples_run():
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(verbose=False)
    report: list[str] = []
    for test in finder.find(hoap3, hoap3.__name__, globs=vars(hoap3).copy()):
        runner.run(test, out=report.append)
    failed, attempted = runner.summarize(verbose=False)
    assert attempted > 0 and failed == 0, "".join(report)


def test_robot_readme_usage_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "robots/hoap3/README.md has no python code block"
    namespace: dict = {}
    exec(compile(blocks[0], str(README), "exec"), namespace)
    assert tuple(namespace["poses"].shape) == (1, 2, 4, 4)
    assert namespace["left"].item() == pytest.approx(-math.degrees(math.atan(0.1)), abs=1e-12)
