"""Stereo photographs as a world: the eyes are windows over a rectified pair.

Each environment fixates one point of the pair (`aectorch.sim.stereo_pairs.pick_fixations`): the
left eye's optical axis passes through it, and the right eye looks through the same photo row,
its window moved left by ``f tan(vergence)`` eye pixels, the map by which a pan of the simulated
camera (`PinholeCamera`, ``f`` its focal length in pixels) moves the image at its centre. At zero
vergence the eyes are parallel, as the rectified cameras were; the optimum puts the right window
over the fixation point's match: ``f tan(v*) = d / pair_scale``, ``d`` the ground-truth disparity
there (photo pixels) and ``pair_scale`` the photo pixels one eye pixel spans.

On a pair without ground truth (``pair.disparity`` ``None``) the optimum is unknown: the eyes
move and see as on any pair, and the ground truth and the errors are NaN.

Each foveal scale's eye images are made as `ActiveDepthEnv.stereo_observation` makes them: the
scale's central crop with one more of its pixels on every side, each pixel the area average of
the photo over its footprint (a photo pixel is a constant square; a window moved by a fraction of
a pixel averages the parts it covers), then the rest of the pyramid's blur (`pyramid_blur`).
Beyond the photo's left and right edges its edge columns repeat.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from aectorch._checks import check_choice, check_int
from aectorch.choices import Proprioception
from aectorch.sim.camera import PinholeCamera
from aectorch.sim.observations import pyramid_blur
from aectorch.sim.oculomotor import VERGENCE_RANGE_DEG
from aectorch.sim.stereo_pairs import StereoPair, corner_disparity

__all__ = ["StereoPairWorld", "area_windows", "eye_extent_px", "row_integral"]


def area_windows(image: Tensor, top: Tensor, left: Tensor, rows: int, cols: int, block: int) -> Tensor:
    """Windows of ``image``, each pixel the area average of a ``block`` x ``block`` square of it.

    Window ``b`` has its top-left corner at row ``top[b]`` (whole pixels) and column ``left[b]``
    (any real number); its pixel ``(i, j)`` averages ``image`` over rows ``[top + i block, top +
    (i + 1) block)`` and columns ``[left + j block, left + (j + 1) block)``, each image pixel a
    constant unit square. Columns beyond the image repeat its edge columns; rows must lie inside.

    Args:
        image: ``[H, W]``.
        top: ``[B]`` integer rows.
        left: ``[B]`` columns (continuous, from the image's left edge).
        rows, cols: the windows' size in blocks.
        block: the block's side in image pixels.

    Returns:
        ``[B, rows, cols]`` (float64).

    Example:
        >>> image = torch.arange(8.0).repeat(2, 1)
        >>> area_windows(image, torch.tensor([0]), torch.tensor([0.5]), 1, 3, 2)[0, 0].tolist()
        [1.0, 3.0, 5.0]
    """
    return _windows(row_integral(image), top, left, rows, cols, block)


def row_integral(image: Tensor) -> Tensor:
    """``image`` ``[H, W]`` summed down its columns from the top, ``[H + 1, W]`` (float64, first row 0):
    what `area_windows` averages with, kept by a world that reads the same photo every step."""
    return torch.nn.functional.pad(image.double().cumsum(0), (0, 0, 1, 0))


def _windows(integral: Tensor, top: Tensor, left: Tensor, rows: int, cols: int, block: int) -> Tensor:
    h, w = integral.shape[0] - 1, integral.shape[1]
    top = top.long()
    if bool((top < 0).any()) or bool((top + rows * block > h).any()):
        raise ValueError(f"the windows' rows must lie inside the {h}-row image: tops {top.tolist()[:4]}..., "
                         f"{rows * block} rows")
    device = integral.device
    left = left.double().to(device)
    # the photo columns each window touches, one more on either side; beyond the image its edge repeats
    first_column = left.floor().long() - 1
    span = cols * block + 2
    columns = (first_column[:, None] + torch.arange(span, device=device)).clamp(0, w - 1)  # [B, span]
    first = top[:, None] + torch.arange(rows, device=device) * block  # [B, rows]
    band = (integral[(first + block)[:, :, None], columns[:, None, :]]
            - integral[first[:, :, None], columns[:, None, :]]) / block  # [B, rows, span]: each block row's mean
    running = torch.nn.functional.pad(band.cumsum(-1), (1, 0))  # [B, rows, span + 1]: the integral at column edges
    edges = (left - first_column.double())[:, None] + torch.arange(cols + 1, device=device, dtype=torch.float64) * block
    k = edges.floor().long().clamp(max=span - 1)
    index = k[:, None, :].expand(-1, rows, -1)
    at = running.gather(-1, index) + (edges - k)[:, None, :] * band.gather(-1, index)
    return (at[..., 1:] - at[..., :-1]) / block


def eye_extent_px(scales: Sequence) -> int:
    """The half side (eye pixels) of the largest window `StereoPairWorld.stereo_observation` reads
    for ``scales`` (each scale's crop and one of its pixels on every side)."""
    return max((s.crop + 2 * s.downsample) // 2 for s in scales)


class StereoPairWorld:
    """Eyes as windows over a rectified stereo pair, one fixation point per environment.

    Args:
        pair: the stereo pair.
        points: ``[B, 2]`` the fixation points, pixel corners ``(x, y)`` of the photos.
        pair_scale: photo pixels per eye pixel (an integer >= 1).
        camera: the eye camera whose focal length maps vergence to pixels (default `PinholeCamera()`).
        vergence_range_deg: ``(low, high)``, the vergence's range in degrees.
        dtype: of the observations.

    Example:
        >>> from aectorch.coding.patches import as_scale
        >>> photo = torch.rand(200, 300)
        >>> pair = StereoPair("same", photo, photo, torch.zeros(200, 300))
        >>> world = StereoPairWorld(pair, torch.tensor([[150, 100]]))
        >>> obs = world.stereo_observation([as_scale("fine")])
        >>> obs["fine"].shape, bool((obs["fine"][:, 0] == obs["fine"][:, 1]).all())
        (torch.Size([1, 2, 40, 40]), True)
    """

    def __init__(self, pair: StereoPair, points: Tensor, *, pair_scale: int = 1, camera: PinholeCamera | None = None,
                 vergence_range_deg: Sequence[float] = VERGENCE_RANGE_DEG, dtype: torch.dtype = torch.float32) -> None:
        self.pair_scale = check_int(pair_scale, "pair_scale", 1)
        points = torch.as_tensor(points)
        if points.dim() != 2 or points.shape[1] != 2 or points.shape[0] == 0:
            raise ValueError(f"points must be [B, 2] pixel corners (x, y), B >= 1, got {tuple(points.shape)}")
        self.pair, self.points = pair, points.long()
        self.camera = camera or PinholeCamera()
        low, high = (float(v) for v in vergence_range_deg)
        if not low < high:
            raise ValueError(f"vergence_range_deg must be (low, high) with low < high, got {vergence_range_deg!r}")
        self.vergence_range_deg = (low, high)
        self.dtype = dtype
        self.disparity_px = corner_disparity(pair, self.points)  # photo pixels; NaN without ground truth
        if pair.has_ground_truth and not bool(torch.isfinite(self.disparity_px).all()):
            raise ValueError(f"pair {pair.name!r}: the ground truth is unknown at some of the points")
        self.vergence_deg = torch.zeros(self.num_envs, dtype=torch.float64)
        self._left: dict[tuple, dict[str, Tensor]] = {}
        self._integrals = {"left": row_integral(pair.left), "right": row_integral(pair.right)}

    @property
    def num_envs(self) -> int:
        return int(self.points.shape[0])

    @property
    def ground_truth_px(self) -> Tensor:
        """The fixation points' disparity in eye pixels ``[B]``: the right window's optimal offset."""
        return self.disparity_px / self.pair_scale

    def shift_px(self, vergence_deg: Tensor | None = None) -> Tensor:
        """How far left the right window is moved, eye pixels ``[B]``: ``f tan(vergence)``."""
        v = self.vergence_deg if vergence_deg is None else vergence_deg.double()
        return self.camera.focal_px * torch.tan(torch.deg2rad(v))

    @property
    def optimal_vergence_deg(self) -> Tensor:
        """The vergence that puts the right window over the fixation point's match ``[B]``."""
        return torch.rad2deg(torch.atan(self.ground_truth_px / self.camera.focal_px))

    @property
    def vergence_error_px(self) -> Tensor:
        """The right window's offset from its optimum, eye pixels ``[B]`` (positive: past it, converged too far)."""
        return self.shift_px() - self.ground_truth_px

    @property
    def vergence_error_deg(self) -> Tensor:
        """The vergence minus its optimum, degrees ``[B]``."""
        return self.vergence_deg - self.optimal_vergence_deg

    def set_vergence_deg(self, vergence_deg) -> None:
        """Put every right eye at ``vergence_deg`` (``[B]`` or a number), clamped into the range."""
        v = torch.as_tensor(vergence_deg, dtype=torch.float64).expand(self.num_envs).clone()
        self.vergence_deg = v.clamp(*self.vergence_range_deg)

    def apply_vergence(self, delta_deg: Tensor) -> None:
        """Turn the right eyes by ``delta_deg`` ``[B]`` (clamped into the vergence range)."""
        delta = torch.as_tensor(delta_deg).detach().double().cpu()
        if delta.shape != (self.num_envs,):
            raise ValueError(f"delta_deg must be [B] = [{self.num_envs}], got {tuple(delta.shape)}")
        self.set_vergence_deg(self.vergence_deg + delta)

    def proprioception(self, names: Sequence[str]) -> Tensor:
        """What the eyes sense of themselves ``[B, len(names)]``: only ``vergence`` (degrees) exists here."""
        columns = []
        for name in names:
            if check_choice(name, "proprioception", Proprioception) != Proprioception.vergence:
                raise ValueError(f"proprioception {name!r} has no meaning over a stereo pair (only 'vergence')")
            columns.append(self.vergence_deg)
        return torch.stack(columns, -1).to(self.dtype) if columns else torch.zeros(self.num_envs, 0, dtype=self.dtype)

    def _eye(self, eye: str, shift_photo_px: Tensor, scales) -> dict[str, Tensor]:
        x, y = self.points[:, 0].double(), self.points[:, 1]
        out = {}
        for s in scales:
            side = (s.crop + 2 * s.downsample) * self.pair_scale  # photo pixels
            if side % 2:
                raise ValueError(f"scale {s.name!r}: its window of {side} photo px has no centre on a pixel corner")
            top = y - side // 2
            if bool((top < 0).any()) or bool((y + side // 2 > self.pair.left.shape[0]).any()):
                raise ValueError(f"pair {self.pair.name!r}: the {s.name} scale's window ({side} photo px) leaves the "
                                 "photo's rows at some points; pick points within the eyes' extent (eye_extent_px)")
            n = side // (s.downsample * self.pair_scale)
            window = _windows(self._integrals[eye], top, x - shift_photo_px - side / 2, n, n,
                              s.downsample * self.pair_scale)
            out[s.name] = pyramid_blur(window.to(self.dtype), s.levels)
        return out

    def stereo_observation(self, scales) -> dict[str, Tensor]:
        """The left then the right eye's images of each of ``scales``: ``{scale.name: [B, 2, side, side]}``."""
        scales = list(scales)
        key = tuple(s.name for s in scales)
        left = self._left.get(key)
        if left is None:
            left = self._left[key] = self._eye("left", torch.zeros(self.num_envs, dtype=torch.float64),
                                               scales)
        right = self._eye("right", self.shift_px() * self.pair_scale, scales)
        return {name: torch.stack((left[name], right[name]), 1) for name in key}

    def __repr__(self) -> str:
        return (f"StereoPairWorld(pair={self.pair.name!r}, fixations={self.num_envs}, pair_scale={self.pair_scale}, "
                f"degrees_per_pixel={math.degrees(math.atan(1 / self.camera.focal_px)):.4f})")
