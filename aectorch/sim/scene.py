"""The scene every environment sees: a textured object plane and a background plane behind it.

By default the object plane is fronto-parallel and wide enough to fill the coder's crops, and the
background is one fixed texture at ``x = 8 m`` that the crops never reach. A :class:`SceneLayout`
gives the world depth structure, drawn per trial (`ActiveDepthEnv`, ``env.scene``): a narrower
object, moved sideways, slanted about a vertical axis, before a background at its own distance
with a texture of the bank; the renderers take each trial's draws as a :class:`Placement`.

World frame (URDF/ROS): x forward, y left, z up, origin on the floor under the robot's starting
position. Both planes are perpendicular to x and face the robot. A texture is mapped onto its
plane as a viewer standing at the robot sees it: texture column 0 on the plane's left edge
(largest y), row 0 on its top edge (largest z), texels square (the plane's height is its width
times the texture's aspect ratio ``H / W``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Optional

import torch
from torch import Tensor


__all__ = ["BACKGROUND_TEXTURES", "DEFAULT_EYE_HEIGHT_M", "LayoutDraws", "Placement", "PlaneScene", "SceneLayout",
           "axis_point"]

#: Height of HOAP-3's eye centres above the soles at zero pose (see robots/hoap3/README.md).
DEFAULT_EYE_HEIGHT_M = 0.529


def _as_textures(textures, name: str, ndim: int) -> Tensor:
    if hasattr(textures, "textures") and isinstance(textures.textures, Tensor):
        textures = textures.textures  # a TextureBank
    if not isinstance(textures, Tensor) or not textures.is_floating_point():
        raise TypeError(f"PlaneScene: {name} must be a floating tensor, got {type(textures).__name__}")
    expected = "[N, H, W]" if ndim == 3 else "[H, W]"
    if textures.ndim != ndim or textures.shape[-1] < 2 or textures.shape[-2] < 2:
        hint = " (a single texture needs .unsqueeze(0))" if ndim == 3 and textures.ndim == 2 else ""
        raise ValueError(
            f"PlaneScene: {name} must have shape {expected} with H, W >= 2, "
            f"got {tuple(textures.shape)}{hint}"
        )
    return textures


@dataclass
class PlaneScene:
    """Geometry and textures of the object plane and the background plane.

    The object plane's distance is per environment and per call (``plane_x_m`` of the renderers);
    everything else is fixed here.

    Args:
        textures: object textures ``[N, H, W]`` in [0, 1], or a :class:`TextureBank`.
        background: the background's texture ``[Hb, Wb]`` in [0, 1]; it is resampled
            (bilinear, antialiased) to the object textures' size ``[H, W]``.
        object_width_m: width of the object plane (>= 3 m fills the coder's crops at every
            distance up to 3 m and body shift up to 0.1 m).
        object_center_yz_m: ``(y, z)`` of the object plane's centre: straight ahead of the robot's
            starting position, at eye height.
        background_x_m: world x of the background plane; it must lie behind every object plane.
        background_width_m: width of the background plane (large enough to fill whole frames);
            its height is ``background_width_m * H / W``.
        background_center_yz_m: ``(y, z)`` of the background's centre.
        object_extent_m: the object's visible part: a square of this side around the object
            plane's centre, cut from it (its texels as large as on the whole plane; what lies
            outside it shows the background); ``None`` (default): the whole plane.

    Example:
        >>> scene = PlaneScene(torch.rand(3, 64, 64), torch.rand(32, 32))
        >>> scene.num_textures, scene.object_size_m
        (3, (3.0, 3.0))
    """

    textures: Tensor
    background: Tensor
    object_width_m: float = 3.0
    object_center_yz_m: tuple[float, float] = (0.0, DEFAULT_EYE_HEIGHT_M)
    background_x_m: float = 8.0
    background_width_m: float = 30.0
    background_center_yz_m: tuple[float, float] = field(default=(0.0, DEFAULT_EYE_HEIGHT_M))
    object_extent_m: float | None = None

    def __post_init__(self) -> None:
        self.textures = _as_textures(self.textures, "textures", 3)
        self.background = _as_textures(self.background, "background", 2)
        size = tuple(self.textures.shape[-2:])
        if tuple(self.background.shape) != size:
            # One texture size for everything lets both renderers treat the background as one
            # more texture (the torch renderer samples all of them from one atlas).
            self.background = torch.nn.functional.interpolate(
                self.background[None, None].to(self.textures), size=size, mode="bilinear",
                antialias=True, align_corners=False,
            )[0, 0].clamp(0.0, 1.0)
        for name in ("object_width_m", "background_width_m", "background_x_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"PlaneScene: {name} must be a number > 0, got {value!r}")
        if self.object_extent_m is not None:
            extent = self.object_extent_m
            if not (isinstance(extent, (int, float)) and 0 < extent <= min(self.object_size_m)):
                raise ValueError(f"PlaneScene: object_extent_m must be null or a number in (0, "
                                 f"{min(self.object_size_m):g}] (the object plane's sides), got {extent!r}")
            self.object_extent_m = float(extent)
        self.object_center_yz_m = tuple(float(v) for v in self.object_center_yz_m)  # type: ignore[assignment]
        self.background_center_yz_m = tuple(  # type: ignore[assignment]  # (a pair: the field's type)
            float(v) for v in self.background_center_yz_m)

    @property
    def num_textures(self) -> int:
        return self.textures.shape[0]

    @property
    def object_size_m(self) -> tuple[float, float]:
        """``(width, height)`` of the object plane in metres."""
        h, w = self.textures.shape[-2:]
        return float(self.object_width_m), float(self.object_width_m) * h / w

    @property
    def object_cut(self) -> tuple[float, float] | None:
        """The visible part's half sides as fractions of the object plane's ``(width, height)``
        (``None``: all of it is visible)."""
        if self.object_extent_m is None:
            return None
        width, height = self.object_size_m
        return 0.5 * self.object_extent_m / width, 0.5 * self.object_extent_m / height

    @property
    def background_size_m(self) -> tuple[float, float]:
        """``(width, height)`` of the background plane in metres."""
        h, w = self.background.shape[-2:]
        return float(self.background_width_m), float(self.background_width_m) * h / w

    def check_render_inputs(
        self, poses: Tensor, plane_x_m: Tensor, texture_index: Tensor, *, check_range: bool = True,
        plane_y_m: Tensor | None = None,
    ) -> int:
        """Validate what both renderers take; returns the batch size B.

        Args:
            poses: ``[B, ..., 4, 4]``.
            plane_x_m: ``[B]``.
            texture_index: integer ``[B]``, each in ``[0, num_textures)``.
            check_range: also check the index values (one host sync; callers that validated
                them already, such as :class:`ActiveDepthEnv` on every frame, pass ``False``).
            plane_y_m: ``[B]`` or ``None``: the object planes' sideways offsets (a moving object).
        """
        if poses.ndim < 3 or poses.shape[-2:] != (4, 4):
            raise ValueError(f"poses must have shape [B, ..., 4, 4], got {tuple(poses.shape)}")
        batch = poses.shape[0]
        if plane_x_m.shape != (batch,):
            raise ValueError(
                f"plane_x_m must have shape [B] = [{batch}] (the batch of poses), "
                f"got {tuple(plane_x_m.shape)}"
            )
        if plane_y_m is not None and (not isinstance(plane_y_m, Tensor) or plane_y_m.shape != (batch,)):
            raise ValueError(
                f"plane_y_m must be None or a tensor of shape [B] = [{batch}] (the batch of poses), "
                f"got {tuple(getattr(plane_y_m, 'shape', ())) or type(plane_y_m).__name__}"
            )
        if not isinstance(texture_index, Tensor) or texture_index.dtype not in (
            torch.int32,
            torch.int64,
        ):
            raise TypeError(
                f"texture_index must be an integer tensor [B], got "
                f"{getattr(texture_index, 'dtype', type(texture_index).__name__)}"
            )
        if texture_index.shape != (batch,):
            raise ValueError(
                f"texture_index must have shape [B] = [{batch}] (the batch of the poses), "
                f"got {tuple(texture_index.shape)}"
            )
        if check_range and bool(((texture_index < 0) | (texture_index >= self.num_textures)).any()):
            raise IndexError(
                f"texture_index must be in [0, {self.num_textures}), got values "
                f"{int(texture_index.min())}..{int(texture_index.max())}"
            )
        return batch


class Placement(NamedTuple):
    """Each environment's object and background where a :class:`SceneLayout` draws them (the
    renderers' ``placement``). ``None`` leaves a part as :class:`PlaneScene` has it.

    Attributes:
        slant_rad: ``[B]``: the object plane turned about the vertical axis through its pivot
            (``x = plane_x_m``, ``y`` the scene's ``object_center_yz_m[0]``) by this angle:
            its normal toward the eyes becomes ``-(cos a, sin a, 0)``, so a positive slant brings
            its left side (+y) nearer. The object's centre moves along the turned plane by the
            renderers' ``plane_y_m``.
        background_x_m: ``[B]``: world x of each environment's background plane.
        background_index: ``[B]`` (integers): each environment's background texture, an index
            into the scene's object textures (``None``: the scene's own background).
    """

    slant_rad: Tensor | None = None
    background_x_m: Tensor | None = None
    background_index: Tensor | None = None

    def check(self, batch: int, num_textures: int) -> None:
        """Shapes ``[batch]`` and the background indices within ``[0, num_textures)``."""
        for name in self._fields:
            value = getattr(self, name)
            if value is not None and (not isinstance(value, Tensor) or value.shape != (batch,)):
                raise ValueError(f"placement.{name} must be None or a tensor of shape [B] = [{batch}], got "
                                 f"{tuple(getattr(value, 'shape', ())) or type(value).__name__}")
        index = self.background_index
        if index is not None and (index.dtype not in (torch.int32, torch.int64)
                                  or bool(((index < 0) | (index >= num_textures)).any())):
            raise ValueError(f"placement.background_index must be integers in [0, {num_textures}), got {index!r}")


def axis_point(eye_m: Tensor, pan_deg: Tensor, plane_x_m: Tensor, slant_rad: Tensor | None,
               pivot_y_m: float) -> Tensor:
    """Where an eye's optical axis meets the object plane (slanted, extended past its edges).

    The axis leaves ``eye_m`` horizontally at ``pan_deg`` (positive to the left); the plane passes
    through ``(plane_x_m, pivot_y_m)`` turned by ``slant_rad`` about the vertical (:class:`Placement`).

    Shape:
        eye_m: ``[B, 3]``; pan_deg, plane_x_m, slant_rad: ``[B]``; output ``[B, 3]``.

    Example:
        >>> axis_point(torch.tensor([[0.0, 0.0, 0.5]]), torch.zeros(1), torch.ones(1), None, 0.0)
        tensor([[1.0000, 0.0000, 0.5000]])
    """
    slope = torch.tan(torch.deg2rad(pan_deg))
    if slant_rad is None:
        reach = plane_x_m - eye_m[:, 0]
    else:
        c, s = torch.cos(slant_rad), torch.sin(slant_rad)
        reach = (c * (plane_x_m - eye_m[:, 0]) + s * (pivot_y_m - eye_m[:, 1])) / (c + s * slope)
    return torch.stack((eye_m[:, 0] + reach, eye_m[:, 1] + reach * slope, eye_m[:, 2]), dim=-1)


#: Where a layout's background texture comes from: ``"fixed"``, the scene's one background
#: texture; ``"bank"``, a texture of the bank other than the object's, drawn per trial.
BACKGROUND_TEXTURES = ("fixed", "bank")


def _range(value, name: str, low: float = -math.inf, high: float = math.inf) -> list[float]:
    """``[low, high]`` of a per-trial draw, checked: two finite numbers, ordered, within ``(low, high)``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, value]
    try:
        pair = [float(v) for v in value]
    except (TypeError, ValueError):
        pair = []
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair) or pair[0] > pair[1] \
            or not (low < pair[0] and pair[1] < high):
        raise ValueError(f"scene.{name} must be [low, high] with {low:g} < low <= high < {high:g}, got {value!r}")
    return pair


@dataclass
class SceneLayout:
    """The world's depth structure, drawn per trial; the defaults are the plain world (a 3 m
    fronto-parallel object plane that fills every crop, before the fixed background at 8 m).

    The object is a square of side ``object_width_m`` cut from the 3 m textured plane (its
    texels as large as in the plain world), its pivot straight ahead of the left eye's start
    position at the trial's distance (where a fixation starting straight ahead fixates), its
    centre moved sideways along its plane by ``object_offset_m`` and the plane turned about the
    vertical through the pivot by ``slant_deg`` (positive: its left side nearer); the background
    stands ``background_depth_m`` behind the pivot with a texture of the bank
    (``background_texture="bank"``). Every range is drawn uniformly per environment and trial,
    from the environment's generator, and only when it is not the default (the plain world draws
    nothing more).

    Attributes:
        object_width_m: the visible object's side, metres (0 < width <= 3; 3: the whole plane, the
            plain world's). Narrower, its edges fall inside the coder's windows.
        object_offset_m: ``[low, high]``, the object centre's sideways offset from the pivot
            along the object's plane, metres, each smaller than half ``object_width_m`` (the
            pivot, the fixation target, stays on the object).
        slant_deg: ``[low, high]``, the object plane's turn about the vertical through the pivot,
            degrees, within +-60: the disparity varies across a window.
        background_depth_m: ``null`` (default): the fixed background at x = 8 m. ``[low, high]``
            (metres, low > 0): the background plane stands this far behind the pivot, drawn per
            trial, so windows at the object's edges span two depths.
        background_texture: ``"fixed"`` (the one pink-noise background image) or ``"bank"``
            (a texture of the training textures other than the object's, drawn per trial).
        background_width_m: the background plane's width, metres (its height the same for square
            textures); rays past it see black.
    """

    object_width_m: float = 3.0
    object_offset_m: list[float] = field(default_factory=lambda: [0.0, 0.0])
    slant_deg: list[float] = field(default_factory=lambda: [0.0, 0.0])
    background_depth_m: Optional[list[float]] = None
    background_texture: str = "fixed"
    background_width_m: float = 30.0

    def __post_init__(self) -> None:
        width = self.object_width_m
        if isinstance(width, bool) or not isinstance(width, (int, float)) or not 0 < width <= 3.0:
            raise ValueError(f"scene.object_width_m must be a number in (0, 3] (metres), got {width!r}")
        self.object_width_m = float(width)
        half = 0.5 * self.object_width_m
        self.object_offset_m = _range(self.object_offset_m, "object_offset_m", -half, half)
        self.slant_deg = _range(self.slant_deg, "slant_deg", -60.0, 60.0)
        if self.background_depth_m is not None:
            self.background_depth_m = _range(self.background_depth_m, "background_depth_m", 0.0)
        if self.background_texture not in BACKGROUND_TEXTURES:
            raise ValueError(f"scene.background_texture must be one of {BACKGROUND_TEXTURES}, "
                             f"got {self.background_texture!r}")
        bw = self.background_width_m
        if isinstance(bw, bool) or not isinstance(bw, (int, float)) or not bw > 0:
            raise ValueError(f"scene.background_width_m must be a number > 0 (metres), got {bw!r}")
        self.background_width_m = float(bw)

    @property
    def plain(self) -> bool:
        """Whether this is the plain world (nothing drawn per trial, nothing cut)."""
        return self == SceneLayout()

    @property
    def draws(self) -> bool:
        """Whether trials draw anything (a placement per trial)."""
        return (self.object_offset_m != [0.0, 0.0] or self.slant_deg != [0.0, 0.0]
                or self.background_depth_m is not None or self.background_texture != "fixed")


class LayoutDraws:
    """A :class:`SceneLayout` in ``env`` (an `ActiveDepthEnv`): the scene it cuts, each trial's
    draws ``[B, 4]`` (offset, slant, background depth, background texture; ``None``: nothing drawn)
    and the renderers' placement of them."""

    #: Its part of the environment's batch state (`ActiveDepthEnv.state_dict`): the state's key -> its
    #: attribute, a tensor ``[B, ...]`` stored while it is not ``None``.
    STATE = {"scene_layout": "draws"}

    def __init__(self, env: Any, layout: SceneLayout) -> None:
        self.env, self.layout = env, layout
        self.draws: Tensor | None = None

    def check(self, protocol) -> None:
        """``ValueError`` where the layout cannot be drawn: for a moving object (the protocol's
        speeds), or a background texture of the bank with fewer than 2 textures."""
        if self.layout.draws and (protocol.object_speed_deg != (0.0, 0.0) or protocol.object_depth_speed_m != (0.0, 0.0)):
            raise ValueError("layout (scene.object_offset_m, slant_deg, background_depth_m, background_texture) cannot "
                             "be drawn for a moving object (object_speed_deg, object_depth_speed_m): use one of them")
        if self.layout.background_texture == "bank" and len(self.env.textures) < 2:
            raise ValueError("scene.background_texture='bank' draws a texture other than the object's: it needs at "
                             f"least 2 textures, got {len(self.env.textures)}")

    def scene_arguments(self) -> dict:
        """The `PlaneScene` arguments of the layout: none for the plain world; else the object cut
        to its side, its pivot straight ahead of the left eye's start, the background's width."""
        layout, env = self.layout, self.env
        if layout.plain:
            return {}
        eye = env.head.eye_centres(torch.zeros(1, dtype=env.dtype, device=env.device))[0, 0]
        return dict(object_extent_m=None if layout.object_width_m >= 3.0 else layout.object_width_m,
                    object_center_yz_m=(float(eye[1]), float(eye[2])),
                    background_width_m=layout.background_width_m)

    def draw(self, index: Tensor) -> None:
        """Each environment's placement for a trial of object textures ``index``."""
        layout, env = self.layout, self.env
        offset, slant = env.uniform(tuple(layout.object_offset_m)), env.uniform(tuple(layout.slant_deg))
        depth = env.uniform(tuple(layout.background_depth_m)) if layout.background_depth_m is not None \
            else torch.full_like(offset, math.nan)
        behind = torch.full_like(offset, -1.0)
        if layout.background_texture == "bank":  # any texture but the object's
            other = env.randint(len(env.textures) - 1)
            behind = (other + (other >= index).long()).to(offset)
        self.draws = torch.stack((offset, slant, depth, behind), dim=-1)

    def placement(self) -> dict:
        """The renderers' ``plane_y_m`` and ``placement`` of this trial's layout (none: plain)."""
        if self.draws is None:
            return {}
        offset, slant, depth, behind = self.draws.unbind(-1)
        layout = self.layout
        return dict(plane_y_m=offset, placement=Placement(
            slant_rad=torch.deg2rad(slant) if layout.slant_deg != [0.0, 0.0] else None,
            background_x_m=self.env.plane_x_m + depth if layout.background_depth_m is not None else None,
            background_index=behind.long() if layout.background_texture == "bank" else None))

    def slant_rad(self) -> Tensor | None:
        """The object plane's slant ``[B]`` (radians), or ``None`` where the layout does not slant it."""
        if self.draws is None or self.layout.slant_deg == [0.0, 0.0]:
            return None
        return torch.deg2rad(self.draws[:, 1])
