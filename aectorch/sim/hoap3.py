"""HOAP-3 head kinematics: the two eye cameras' poses from the body shift and the eye angles.

The chain is read from ``robots/hoap3/hoap3_head.urdf`` (see ``robots/hoap3/README.md`` for every
number and its source) and evaluated with pytorch-kinematics, batched over environments. Frames
follow URDF/ROS: x forward, y left, z up, the soles at z = 0. Sign conventions of the joints:

- ``body_shift`` (metres, simulation only): positive moves the robot to its left (+y);
- ``neck_pan`` / ``*_eye_pan`` (degrees at the API): positive turns toward the robot's left
  (counter-clockwise seen from above);
- ``neck_tilt``: positive pitches the head DOWN (down is positive; rotation about +y);
- ``*_eye_roll`` (simulation only, the perturbation of the paper's section 4): rotation about the
  optical axis; positive lifts the camera's left side, i.e. the camera turns clockwise as seen from
  behind it and the image content appears to turn counter-clockwise.

Besides forward kinematics the module has the exact closed forms (neck at zero) of the two eye
movements the learner must find: the pan that keeps the dominant (left) eye on a target after a body
shift (smooth pursuit) and the right-eye pan that fixates the point the left eye looks at on a
fronto-parallel plane (vergence). They are the supervisor's "optimal" angles.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pytorch_kinematics as pk
import torch
from pytorch_kinematics.transforms import Transform3d
from torch import Tensor, nn

from aectorch._checks import is_int

__all__ = [
    "DEFAULT_URDF_PATH",
    "JOINT_NAMES",
    "SIM_ONLY_JOINTS",
    "CONVENTIONS",
    "HOAP3Head",
]

DEFAULT_URDF_PATH = Path(__file__).resolve().parents[2] / "robots" / "hoap3" / "hoap3_head.urdf"
"""The URDF shipped with the repository (found through the editable install)."""

JOINT_NAMES = (
    "body_shift",
    "neck_pan",
    "neck_tilt",
    "left_eye_pan",
    "left_eye_roll",
    "right_eye_pan",
    "right_eye_roll",
)
"""The movable joints the head needs; the chain's own order may differ and is never assumed."""

SIM_ONLY_JOINTS = ("body_shift", "left_eye_pan", "left_eye_roll", "right_eye_pan", "right_eye_roll")
"""Joints that exist only in simulation (the real HOAP-3 moves its neck, not its cameras)."""

CONVENTIONS = {
    "opengl": ("left_camera_optical_gl", "right_camera_optical_gl"),
    "ros": ("left_camera_optical_ros", "right_camera_optical_ros"),
}
"""Optical frame names (left, right) per camera convention: OpenGL/pyrender looks along -z with
y up and x right; ROS looks along +z with x right and y down."""

_EYE_FRAMES = ("left_eye", "right_eye")
_EYES = ("left", "right")


def _read_urdf(path: Path) -> str:
    if not path.is_file():
        raise FileNotFoundError(f"HOAP-3 URDF not found: urdf_path={str(path)!r} is not a file")
    return path.read_text()


def _floats(element: ET.Element | None, attribute: str, default: str) -> list[float]:
    text = default if element is None else element.get(attribute, default)
    return [float(v) for v in text.split()]


def _origin_matrix(origin: ET.Element | None) -> Tensor:
    """The URDF ``<origin xyz rpy>`` as a float64 4x4 (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    x, y, z = _floats(origin, "xyz", "0 0 0")
    roll, pitch, yaw = _floats(origin, "rpy", "0 0 0")
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return torch.tensor(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, x],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr, y],
            [-sp, cp * sr, cp * cr, z],
            [0.0, 0.0, 0.0, 1.0],
        ],
        dtype=torch.float64,
    )


def _exact_chain(urdf_text: str) -> pk.Chain:
    """Build the chain with pytorch-kinematics, with its joint geometry in exact float64.

    pytorch-kinematics (0.10) parses URDF origins into float32, so a chain moved to float64 still
    carries float32 rounding (the eye height reads 0.52900000708). The joint offsets and axes are
    therefore re-read from the XML in float64 and the chain is rebuilt from the same frames.
    """
    chain = pk.build_chain_from_urdf(urdf_text)
    joints = {j.get("name"): j for j in ET.fromstring(urdf_text).iter("joint")}
    frame_names = chain.get_frame_names(exclude_fixed=False)
    for name in frame_names:
        frame = chain.find_frame(name)
        if frame.link.offset is not None:
            frame.link.offset = frame.link.offset.to(device="cpu", dtype=torch.float64)
        element = joints.get(frame.joint.name)
        if element is None:  # the root frame has no joint
            continue
        frame.joint.offset = Transform3d(matrix=_origin_matrix(element.find("origin")).unsqueeze(0))
        axis_element = element.find("axis")
        if axis_element is not None:
            axis = torch.tensor(_floats(axis_element, "xyz", "1 0 0"), dtype=torch.float64)
            frame.joint.axis = axis / axis.norm()
        else:
            frame.joint.axis = frame.joint.axis.to(torch.float64)
    return pk.Chain(chain.find_frame(frame_names[0]), dtype=torch.float64, device="cpu")


def _check_tensor(x: object, name: str) -> None:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got dtype {x.dtype}")


def _check_shift(shift_m: object) -> int:
    _check_tensor(shift_m, "shift_m")
    if shift_m.dim() != 1:
        raise ValueError(f"shift_m must have shape [B], got shape {tuple(shift_m.shape)}")
    return shift_m.shape[0]


def _check_like(x: object, name: str, tail: tuple[int, ...], shift_m: Tensor) -> None:
    """``x`` must be a float tensor of shape ``[B, *tail]`` with shift_m's B, dtype and device."""
    _check_tensor(x, name)
    expected = (shift_m.shape[0], *tail)
    if tuple(x.shape) != expected:
        dims = ", ".join(["B", *map(str, tail)])
        raise ValueError(
            f"{name} must have shape [{dims}] = {list(expected)} to match shift_m of shape "
            f"{list(shift_m.shape)}, got {name} of shape {list(x.shape)}"
        )
    if x.dtype != shift_m.dtype:
        raise TypeError(f"{name} has dtype {x.dtype} but shift_m has dtype {shift_m.dtype}")
    if x.device != shift_m.device:
        raise ValueError(f"{name} is on {x.device} but shift_m is on {shift_m.device}")


def _check_eye(eye: str) -> int:
    if eye not in _EYES:
        raise ValueError(f"eye must be one of {list(_EYES)}, got {eye!r}")
    return _EYES.index(eye)


class HOAP3Head(nn.Module):
    """The HOAP-3 head: batched camera poses from pytorch-kinematics and closed-form fixations.

    The chain is built once from the URDF (joint geometry in exact float64) and kept in the head's
    dtype and device; ``head.to(torch.float64)``, ``head.double()`` or ``head.to("cuda")`` move it
    like any module. Forward kinematics does NOT convert: inputs in another dtype or on another
    device than the head raise a clear error (move the head instead). The closed forms
    (:meth:`pursuit_pan_deg`, :meth:`vergence_pan_deg`, :meth:`plane_point_m`) are pure torch with
    the zero-pose geometry as Python floats, so their dtype and device simply follow the inputs.

    Camera poses are camera-to-world transforms: ``T @ [p_cam; 1] = [p_world; 1]``. Index 0 of the
    eye axis is the left (dominant) eye, index 1 the right eye. The optical centre is the eye's
    rotation centre, so eye pan and roll never move it.

    Args:
        urdf_path: the URDF to read; default :data:`DEFAULT_URDF_PATH`. It must have the joints of
            :data:`JOINT_NAMES` and the frames ``left_eye``, ``right_eye`` and the optical frames
            of :data:`CONVENTIONS`.
        dtype: floating dtype of the chain (keyword-only).
        device: device of the chain (keyword-only); default CPU.

    Raises:
        FileNotFoundError: the URDF does not exist (the message names the path).
        ValueError: a required joint or frame is missing, or at zero pose the optical axes do not
            look along world +x (the closed forms assume they do).

    Example:
        >>> head = HOAP3Head(dtype=torch.float64)
        >>> round(head.baseline_m, 9), round(head.eye_height_m, 9), round(head.eye_x_m, 9)
        (0.06, 0.529, 0.03)
        >>> shift = torch.tensor([0.0, 0.1], dtype=torch.float64)
        >>> pan = torch.zeros(2, 2, dtype=torch.float64)
        >>> head.camera_poses(shift, pan).shape
        torch.Size([2, 2, 4, 4])
        >>> head.eye_centres(shift)[1, 0]  # left eye after a 0.1 m shift to the left
        tensor([0.0300, 0.1300, 0.5290], dtype=torch.float64)
    """

    def __init__(
        self,
        urdf_path: str | Path | None = None,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
            raise TypeError(f"dtype must be a floating torch.dtype, got {dtype!r}")
        path = DEFAULT_URDF_PATH if urdf_path is None else Path(urdf_path)
        self.urdf_path = path
        chain64 = _exact_chain(_read_urdf(path))

        names = tuple(chain64.get_joint_parameter_names())
        missing = [n for n in JOINT_NAMES if n not in names]
        if missing:
            raise ValueError(f"URDF {str(path)!r} lacks the joints {missing}; it has {list(names)}")
        frames = set(chain64.get_frame_names(exclude_fixed=False))
        needed = [*_EYE_FRAMES, *(f for pair in CONVENTIONS.values() for f in pair)]
        missing = [f for f in needed if f not in frames]
        if missing:
            raise ValueError(f"URDF {str(path)!r} lacks the frames {missing}")
        self._joint_names = names
        self._joint_index = {n: i for i, n in enumerate(names)}
        low, high = chain64.get_joint_limits()
        self._limits = {n: (float(lo), float(hi)) for n, lo, hi in zip(names, low, high)}
        self._chain64 = chain64

        # Zero-pose geometry, read from forward kinematics in float64 (not hard-coded).
        zero = torch.zeros(1, len(names), dtype=torch.float64)
        eyes = self._fk(chain64, zero, _EYE_FRAMES)[0, :, :3, 3]
        self._eye_xyz = tuple(tuple(float(v) for v in eye) for eye in eyes)
        optical = self._fk(chain64, zero, CONVENTIONS["ros"])[0, :, :3, 2]
        forward = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
        if not torch.allclose(optical, forward.expand(2, 3), rtol=0.0, atol=1e-9):
            raise ValueError(
                f"URDF {str(path)!r}: at zero pose the optical axes must look along world +x, "
                f"got {optical.tolist()}"
            )

        pan_low = [math.degrees(self._limits[f"{e}_eye_pan"][0]) for e in _EYES]
        pan_high = [math.degrees(self._limits[f"{e}_eye_pan"][1]) for e in _EYES]
        # Non-persistent: they come from the URDF, not from training, and stay out of checkpoints.
        # They also carry the module's dtype/device, which _apply hands on to the chain.
        self.register_buffer(
            "_pan_low_deg", torch.tensor(pan_low, dtype=dtype, device=device), persistent=False
        )
        self.register_buffer(
            "_pan_high_deg", torch.tensor(pan_high, dtype=dtype, device=device), persistent=False
        )
        self._chain = self._converted_chain()

    # ------------------------------------------------------------------ module plumbing

    def _converted_chain(self) -> pk.Chain:
        # Always from the float64 master: float32 -> float64 would keep float32 rounding.
        ref = self._pan_low_deg
        return copy.deepcopy(self._chain64).to(dtype=ref.dtype, device=ref.device)

    def _apply(self, fn, recurse=True):
        super()._apply(fn, recurse)
        if (self._pan_low_deg.dtype, self._pan_low_deg.device) != (self.dtype, self.device):
            self._chain = self._converted_chain()
        return self

    @property
    def dtype(self) -> torch.dtype:
        """Floating dtype of the chain (follows ``.to()``)."""
        return self._chain.dtype

    @property
    def device(self) -> torch.device:
        """Device of the chain (follows ``.to()``)."""
        return torch.device(self._chain.device)

    def extra_repr(self) -> str:
        return f"urdf_path={str(self.urdf_path)!r}, dtype={self.dtype}, device={self.device}"

    # ------------------------------------------------------------------ geometry at zero pose

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Movable joints in the chain's own order (the columns of its joint vector)."""
        return self._joint_names

    @property
    def limits(self) -> dict[str, tuple[float, float]]:
        """Joint limits (lower, upper) from the URDF in SI units: radians, or metres for
        ``body_shift``."""
        return dict(self._limits)

    @property
    def limits_deg(self) -> dict[str, tuple[float, float]]:
        """Limits (lower, upper) of the revolute joints in degrees. ``neck_tilt`` is (-45, 15):
        45 degrees up to 15 degrees down (down is positive)."""
        return {
            n: (math.degrees(lo), math.degrees(hi))
            for n, (lo, hi) in self._limits.items()
            if n != "body_shift"
        }

    @property
    def shift_limits_m(self) -> tuple[float, float]:
        """Limits (lower, upper) of the simulation-only ``body_shift`` joint in metres."""
        return self._limits["body_shift"]

    @property
    def baseline_m(self) -> float:
        """Distance between the two eye centres at zero pose (0.06 m)."""
        return math.dist(*self._eye_xyz)

    @property
    def eye_height_m(self) -> float:
        """Height of the eye centres above the soles at zero pose (0.529 m)."""
        return 0.5 * (self._eye_xyz[0][2] + self._eye_xyz[1][2])

    @property
    def eye_x_m(self) -> float:
        """World x of the eye centres at zero pose and shift (0.03 m in front of the waist)."""
        return 0.5 * (self._eye_xyz[0][0] + self._eye_xyz[1][0])

    # ------------------------------------------------------------------ forward kinematics

    @staticmethod
    def _fk(chain: pk.Chain, th: Tensor, frames: tuple[str, ...]) -> Tensor:
        """Transforms ``[B, len(frames), 4, 4]`` of the named frames for joint vectors ``th``."""
        fk = chain.forward_kinematics(th, frame_indices=chain.get_frame_indices(*frames))
        return torch.stack([fk[f].get_matrix() for f in frames], dim=1)

    def _check_head(self, x: Tensor, name: str) -> None:
        if x.dtype != self.dtype:
            raise TypeError(
                f"{name} has dtype {x.dtype} but the HOAP3Head chain is {self.dtype}; "
                f"move the head with head.to({x.dtype})"
            )
        if x.device != self.device:
            raise ValueError(
                f"{name} is on {x.device} but the HOAP3Head chain is on {self.device}; "
                f"move the head with head.to({str(x.device)!r})"
            )

    def _joints(
        self,
        shift_m: Tensor,
        pan_deg: Tensor | None = None,
        roll_deg: Tensor | None = None,
        neck_pan_deg: Tensor | None = None,
        neck_tilt_deg: Tensor | None = None,
    ) -> Tensor:
        """The joint vector ``[B, n_joints]`` in the chain's order, built by joint name."""
        zero = torch.zeros_like(shift_m)
        values = {"body_shift": shift_m}
        if neck_pan_deg is not None:
            values["neck_pan"] = torch.deg2rad(neck_pan_deg)
        if neck_tilt_deg is not None:
            values["neck_tilt"] = torch.deg2rad(neck_tilt_deg)
        for i, eye in enumerate(_EYES):
            if pan_deg is not None:
                values[f"{eye}_eye_pan"] = torch.deg2rad(pan_deg[:, i])
            if roll_deg is not None:
                values[f"{eye}_eye_roll"] = torch.deg2rad(roll_deg[:, i])
        return torch.stack([values.get(n, zero) for n in self._joint_names], dim=1)

    def _check_neck(
        self, shift_m: Tensor, neck_pan_deg: Tensor | None, neck_tilt_deg: Tensor | None
    ) -> None:
        if neck_pan_deg is not None:
            _check_like(neck_pan_deg, "neck_pan_deg", (), shift_m)
        if neck_tilt_deg is not None:
            _check_like(neck_tilt_deg, "neck_tilt_deg", (), shift_m)

    def camera_poses(
        self,
        shift_m: Tensor,
        pan_deg: Tensor,
        roll_deg: Tensor | None = None,
        *,
        neck_pan_deg: Tensor | None = None,
        neck_tilt_deg: Tensor | None = None,
        convention: str = "opengl",
    ) -> Tensor:
        """Camera-to-world transforms of both eyes' optical frames, batched through the chain.

        Joint values are used as given: nothing is clamped (see :meth:`clamp_pan_deg`).

        Args:
            shift_m: lateral body shift in metres, positive = leftward (+y).
            pan_deg: eye pans in degrees, ``[:, 0]`` left eye, ``[:, 1]`` right eye; positive turns
                the eye toward the robot's left.
            roll_deg: eye rolls about the optical axis in degrees (the section-4 perturbation),
                same layout as ``pan_deg``; default zeros.
            neck_pan_deg: neck pan in degrees, positive to the left; default zero.
            neck_tilt_deg: neck tilt in degrees, positive DOWN; default zero.
            convention: ``"opengl"`` (pyrender: -z forward, y up, x right) or ``"ros"``
                (z forward, x right, y down).

        Returns:
            Homogeneous camera-to-world transforms, dtype and device of the inputs (which must be
            those of the head).

        Shape:
            - shift_m: :math:`(B,)`; neck_pan_deg, neck_tilt_deg: :math:`(B,)`.
            - pan_deg, roll_deg: :math:`(B, 2)`.
            - output: :math:`(B, 2, 4, 4)`, eye index 0 = left, 1 = right.

        Example:
            >>> head = HOAP3Head()
            >>> T = head.camera_poses(torch.zeros(1), torch.tensor([[90.0, 0.0]]), convention="ros")
            >>> T[0, 0, :3, 2].round(decimals=6).abs()  # left optical axis now looks along +y
            tensor([0., 1., 0.])
        """
        if convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {list(CONVENTIONS)}, got {convention!r}")
        _check_shift(shift_m)
        _check_like(pan_deg, "pan_deg", (2,), shift_m)
        if roll_deg is not None:
            _check_like(roll_deg, "roll_deg", (2,), shift_m)
        self._check_neck(shift_m, neck_pan_deg, neck_tilt_deg)
        self._check_head(shift_m, "shift_m")
        th = self._joints(shift_m, pan_deg, roll_deg, neck_pan_deg, neck_tilt_deg)
        return self._fk(self._chain, th, CONVENTIONS[convention])

    def eye_centres(
        self,
        shift_m: Tensor,
        *,
        neck_pan_deg: Tensor | None = None,
        neck_tilt_deg: Tensor | None = None,
    ) -> Tensor:
        """World positions of the eye (and optical) centres; eye pan and roll do not move them.

        Args:
            shift_m: lateral body shift in metres, positive = leftward.
            neck_pan_deg: neck pan in degrees, positive to the left; default zero.
            neck_tilt_deg: neck tilt in degrees, positive down; default zero.

        Returns:
            Eye centres in metres, dtype and device of the inputs.

        Shape:
            - shift_m, neck_pan_deg, neck_tilt_deg: :math:`(B,)`.
            - output: :math:`(B, 2, 3)`, index 0 = left eye, 1 = right eye.

        Example:
            >>> HOAP3Head().eye_centres(torch.zeros(1))
            tensor([[[ 0.0300,  0.0300,  0.5290],
                     [ 0.0300, -0.0300,  0.5290]]])
        """
        _check_shift(shift_m)
        self._check_neck(shift_m, neck_pan_deg, neck_tilt_deg)
        self._check_head(shift_m, "shift_m")
        th = self._joints(shift_m, neck_pan_deg=neck_pan_deg, neck_tilt_deg=neck_tilt_deg)
        return self._fk(self._chain, th, _EYE_FRAMES)[..., :3, 3]

    # ------------------------------------------------------------------ limits

    def clamp_pan_deg(self, pan_deg: Tensor) -> Tensor:
        """Clamp eye pans to the URDF limits of ``left_eye_pan`` / ``right_eye_pan`` (+-45 deg).

        Args:
            pan_deg: eye pans in degrees, ``[:, 0]`` left, ``[:, 1]`` right.

        Returns:
            The clamped pans, same dtype and device as ``pan_deg``.

        Shape:
            - pan_deg: :math:`(B, 2)`; output: :math:`(B, 2)`.

        Example:
            >>> HOAP3Head().clamp_pan_deg(torch.tensor([[50.0, -3.0]]))
            tensor([[45., -3.]])
        """
        _check_tensor(pan_deg, "pan_deg")
        if pan_deg.dim() != 2 or pan_deg.shape[1] != 2:
            raise ValueError(f"pan_deg must have shape [B, 2], got shape {list(pan_deg.shape)}")
        low = self._pan_low_deg.to(pan_deg)
        high = self._pan_high_deg.to(pan_deg)
        return torch.minimum(torch.maximum(pan_deg, low), high)

    # ------------------------------------------------------------------ closed forms (neck at zero)

    def pursuit_pan_deg(self, target_m: Tensor, shift_m: Tensor, *, eye: str = "left") -> Tensor:
        """Exact pan that points an eye's optical axis at a world point, neck at zero.

        Pan turns the optical axis in the horizontal plane only, so the target's height is
        ignored: the axis passes through the target's (x, y), at eye height. For the dominant eye
        this is the smooth-pursuit optimum: after a body shift ``s`` the left eye keeps a point at
        distance ``d`` straight ahead with the pan ``-atan(s / d)``.

        Args:
            target_m: world points in metres (x forward, y left, z up), in front of the eye.
            shift_m: lateral body shift in metres, positive = leftward.
            eye: ``"left"`` (default, the dominant eye) or ``"right"``.

        Returns:
            The pan in degrees, positive toward the robot's left; dtype and device of the inputs.

        Shape:
            - target_m: :math:`(B, 3)`; shift_m: :math:`(B,)`; output: :math:`(B,)`.

        Example:
            >>> head = HOAP3Head()
            >>> target = torch.tensor([[head.eye_x_m + 1.0, 0.03, 0.0]])  # 1 m ahead, left eye
            >>> head.pursuit_pan_deg(target, torch.tensor([0.1]))
            tensor([-5.7106])
        """
        index = _check_eye(eye)
        _check_shift(shift_m)
        _check_like(target_m, "target_m", (3,), shift_m)
        x, y, _ = self._eye_xyz[index]
        return torch.rad2deg(torch.atan2(target_m[:, 1] - (y + shift_m), target_m[:, 0] - x))

    def plane_point_m(
        self, left_pan_deg: Tensor, plane_x_m: Tensor | float, shift_m: Tensor
    ) -> Tensor:
        """Where the left optical axis meets the fronto-parallel plane ``x = plane_x_m``, neck at 0.

        Args:
            left_pan_deg: left-eye pan in degrees, positive to the left, ``|pan| < 90``.
            plane_x_m: world x of the plane in metres (NOT the distance from the eyes: a plane
                ``d`` m ahead of the eyes is at ``head.eye_x_m + d``); a tensor or a number.
            shift_m: lateral body shift in metres, positive = leftward.

        Returns:
            The world point in metres (its z is the eye height); dtype and device of the inputs.

        Shape:
            - left_pan_deg, shift_m, plane_x_m (if a tensor): :math:`(B,)`; output: :math:`(B, 3)`.

        Example:
            >>> head = HOAP3Head()
            >>> head.plane_point_m(torch.zeros(1), head.eye_x_m + 1.0, torch.zeros(1))
            tensor([[1.0300, 0.0300, 0.5290]])
        """
        _check_shift(shift_m)
        _check_like(left_pan_deg, "left_pan_deg", (), shift_m)
        if is_int(plane_x_m) or isinstance(plane_x_m, float):  # a number, finite or not
            plane_x_m = torch.full_like(shift_m, float(plane_x_m))
        _check_like(plane_x_m, "plane_x_m", (), shift_m)
        x, y, z = self._eye_xyz[0]
        hit_y = y + shift_m + (plane_x_m - x) * torch.tan(torch.deg2rad(left_pan_deg))
        return torch.stack([plane_x_m, hit_y, torch.full_like(shift_m, z)], dim=1)

    def vergence_pan_deg(
        self, left_pan_deg: Tensor, plane_x_m: Tensor | float, shift_m: Tensor
    ) -> Tensor:
        """Exact right-eye pan that fixates where the left optical axis meets a plane, neck at zero.

        The left eye's axis hits the fronto-parallel plane ``x = plane_x_m`` at
        :meth:`plane_point_m`; this is the right-eye pan whose axis passes through the same point
        (the vergence optimum). With both eyes 1 m from the plane and the left pan 0 it is
        ``atan(0.06 / 1)`` = 3.43 degrees.

        Args:
            left_pan_deg: left-eye pan in degrees, positive to the left.
            plane_x_m: world x of the plane in metres (``head.eye_x_m + distance``).
            shift_m: lateral body shift in metres, positive = leftward.

        Returns:
            The right-eye pan in degrees, positive to the left; dtype and device of the inputs.

        Shape:
            - left_pan_deg, shift_m, plane_x_m (if a tensor): :math:`(B,)`; output: :math:`(B,)`.

        Example:
            >>> head = HOAP3Head()
            >>> head.vergence_pan_deg(torch.zeros(1), head.eye_x_m + 1.0, torch.zeros(1))
            tensor([3.4336])
        """
        point = self.plane_point_m(left_pan_deg, plane_x_m, shift_m)
        return self.pursuit_pan_deg(point, shift_m, eye="right")

    @staticmethod
    def vergence_deg(left_pan_deg: Tensor, right_pan_deg: Tensor) -> Tensor:
        """Vergence angle: right pan minus left pan, in degrees.

        Positive means the optical axes converge (cross in front of the eyes), zero parallel,
        negative diverge.

        Args:
            left_pan_deg: left-eye pan in degrees.
            right_pan_deg: right-eye pan in degrees, same shape.

        Returns:
            ``right_pan_deg - left_pan_deg``.

        Shape:
            - inputs and output: :math:`(B,)` (any equal shapes).

        Example:
            >>> HOAP3Head.vergence_deg(torch.tensor([-1.0]), torch.tensor([2.0]))
            tensor([3.])
        """
        _check_tensor(left_pan_deg, "left_pan_deg")
        _check_tensor(right_pan_deg, "right_pan_deg")
        if left_pan_deg.shape != right_pan_deg.shape:
            raise ValueError(
                f"left_pan_deg and right_pan_deg must have the same shape, got "
                f"{list(left_pan_deg.shape)} and {list(right_pan_deg.shape)}"
            )
        return right_pan_deg - left_pan_deg
