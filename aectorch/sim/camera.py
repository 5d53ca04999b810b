"""Pinhole eye cameras: intrinsics, pixel windows (the crops the coder uses) and per-pixel rays.

Pixel convention (the same as OpenGL's and pyrender's ``IntrinsicsCamera``): the image has
``height`` rows counted from the top and ``width`` columns counted from the left; pixel
``(row, col)`` covers ``[col, col + 1) x [row, row + 1)`` and its centre is at
``(col + 0.5, row + 0.5)``. A point ``(X, Y, Z)`` in the ROS optical frame (x right, y down,
z forward) projects to the continuous image position ``(f X / Z + cx, f Y / Z + cy)``. The
principal point defaults to the image centre ``(width / 2, height / 2)``, so the optical axis
passes through the corner shared by the four central pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from aectorch._checks import check_int

__all__ = ["PinholeCamera", "PixelWindow"]


class PixelWindow(NamedTuple):
    """A rectangle of whole pixels of an image: ``top`` row, ``left`` column, ``height``, ``width``."""

    top: int
    left: int
    height: int
    width: int


@dataclass(frozen=True)
class PinholeCamera:
    """An ideal pinhole camera with square pixels (the HOAP-3 eye camera of earlier AEC models).

    HOAP-3's real lens is undocumented; the defaults (320 x 240 grey, 50 degrees vertical field
    of view, focal length 257.34 px, about 0.2226 degrees per pixel at the centre) are the
    convention of earlier AEC models. See ``robots/hoap3/README.md``.

    Args:
        width: image width in pixels.
        height: image height in pixels.
        vfov_deg: vertical field of view in degrees, in (0, 180).
        cx: principal point column (continuous, from the left edge); ``None`` = ``width / 2``.
        cy: principal point row (continuous, from the top edge); ``None`` = ``height / 2``.

    Example:
        >>> cam = PinholeCamera()
        >>> round(cam.focal_px, 2), round(cam.degrees_per_pixel, 4)
        (257.34, 0.2226)
        >>> cam.central_window(128)
        PixelWindow(top=56, left=96, height=128, width=128)
    """

    width: int = 320
    height: int = 240
    vfov_deg: float = 50.0
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            check_int(getattr(self, name), f"PinholeCamera: {name}")
        if not (isinstance(self.vfov_deg, (int, float)) and 0.0 < self.vfov_deg < 180.0):
            raise ValueError(
                f"PinholeCamera: vfov_deg must be in (0, 180) degrees, got {self.vfov_deg!r}"
            )
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"PinholeCamera: {name} must be finite or None, got {value!r}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: ``(height / 2) / tan(vfov / 2)``."""
        return (self.height / 2.0) / math.tan(math.radians(self.vfov_deg) / 2.0)

    @property
    def principal_point(self) -> tuple[float, float]:
        """``(cx, cy)``: column and row of the principal point (continuous pixel coordinates)."""
        cx = self.width / 2.0 if self.cx is None else float(self.cx)
        cy = self.height / 2.0 if self.cy is None else float(self.cy)
        return cx, cy

    @property
    def degrees_per_pixel(self) -> float:
        """Angle subtended by one pixel at the image centre, in degrees."""
        return math.degrees(math.atan(1.0 / self.focal_px))

    def magnified(self, factor: float) -> "PinholeCamera":
        """This camera with its focal length times ``factor`` (> 0): the same pixels, the image
        magnified ``factor`` times about the principal point (aniseikonia,
        `aectorch.sim.perturbations`).

        Example:
            >>> round(PinholeCamera().magnified(1.05).focal_px / PinholeCamera().focal_px, 9)
            1.05
        """
        if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
            raise ValueError(f"PinholeCamera.magnified: factor must be a number > 0, got {factor!r}")
        if factor == 1:
            return self
        vfov = 2.0 * math.degrees(math.atan((self.height / 2.0) / (self.focal_px * factor)))
        return PinholeCamera(self.width, self.height, vfov, self.cx, self.cy)

    @property
    def full_window(self) -> PixelWindow:
        """The whole image."""
        return PixelWindow(0, 0, self.height, self.width)

    def central_window(self, size: int | tuple[int, int]) -> PixelWindow:
        """The central ``size`` crop, placed like :func:`aectorch.coding.extract_patches` does.

        The offset is ``(height - h) // 2`` rows and ``(width - w) // 2`` columns, so a crop of
        this window and a crop of the full image at the same size give the same pixels.
        """
        h, w = (size, size) if isinstance(size, int) else tuple(size)
        if not (1 <= h <= self.height and 1 <= w <= self.width):
            raise ValueError(
                f"central_window: size must fit the {self.height} x {self.width} image, got {size!r}"
            )
        return PixelWindow((self.height - h) // 2, (self.width - w) // 2, h, w)

    def check_window(self, window: PixelWindow | None) -> PixelWindow:
        """Return ``window`` (``None`` = full image) after checking that it lies inside the image."""
        if window is None:
            return self.full_window
        window = PixelWindow(*window)
        top, left, h, w = window
        if h < 1 or w < 1 or top < 0 or left < 0 or top + h > self.height or left + w > self.width:
            raise ValueError(
                f"window must lie inside the {self.height} x {self.width} image, got {window}"
            )
        return window

    def rays(
        self,
        window: PixelWindow | None = None,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> Tensor:
        """Ray directions through the pixel centres of ``window``, in the ROS optical frame.

        Returns:
            ``(X/Z, Y/Z, 1)`` per pixel (not normalised: the z component is 1).

        Shape:
            output: ``[window.height, window.width, 3]``.

        Example:
            >>> r = PinholeCamera(width=4, height=2, vfov_deg=90.0).rays()
            >>> r[0, 0].tolist()
            [-1.5, -0.5, 1.0]
        """
        top, left, h, w = self.check_window(window)
        cx, cy = self.principal_point
        f = self.focal_px
        cols = (torch.arange(left, left + w, dtype=dtype, device=device) + 0.5 - cx) / f
        rows = (torch.arange(top, top + h, dtype=dtype, device=device) + 0.5 - cy) / f
        x = cols.expand(h, w)
        y = rows[:, None].expand(h, w)
        return torch.stack((x, y, torch.ones_like(x)), dim=-1)

    def window_intrinsics(self, window: PixelWindow | None = None) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` of a camera that renders exactly ``window`` of this one."""
        top, left, _, _ = self.check_window(window)
        cx, cy = self.principal_point
        return self.focal_px, self.focal_px, cx - left, cy - top
