"""The scene every environment sees: a fronto-parallel textured object plane and a still background.

World frame (URDF/ROS): x forward, y left, z up, origin on the floor under the robot's starting
position. Both planes are perpendicular to x and face the robot. A texture is mapped onto its
plane as a viewer standing at the robot sees it: texture column 0 on the plane's left edge
(largest y), row 0 on its top edge (largest z), texels square (the plane's height is its width
times the texture's aspect ratio ``H / W``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

__all__ = ["PlaneScene", "DEFAULT_EYE_HEIGHT_M"]

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
