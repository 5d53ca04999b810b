"""Rectified stereo photographs, with ground-truth disparity or without: the pairs, their readers
and the fixation points an evaluation picks on them.

Two folder layouts are read (:func:`read_pair`):

- **Middlebury's** (the 2014 and 2021 sets): ``im0.png`` (left), ``im1.png`` (right) and
  ``disp0.pfm``, the left image's disparity; unknown where it is ``inf`` or 0.
- **the plain one**: ``left.<ext>`` and ``right.<ext>`` (any image format Pillow reads) and
  ``disparity.npy``, float ``[H, W]``; unknown where it is NaN (or not finite). A folder with the
  two images and no ``disparity.npy`` is a pair without ground truth (``disparity`` ``None``), such
  as a robot's two cameras (``scripts/lerobot_pairs.py``).

Disparities are in pixels of the photographs: the point at column ``x`` of the left image is at
``x - d`` in the right one. Images are read as grey in [0, 1] (`aectorch.sim.textures.files`).
The window world over a pair is `aectorch.sim.pair_world`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
import numpy as np
import torch
from torch import Tensor

from aectorch._checks import check_int, check_real
from aectorch.sim.textures.files import load_grey

__all__ = ["MIDDLEBURY_FILES", "MIN_CONTRAST", "OCCLUSION_TOLERANCE_PX", "PLAIN_FILES", "StereoPair", "corner_disparity",
           "disparity_roughness", "layout", "occlusion", "pick_fixations", "read_pair", "read_pairs", "read_pfm"]

#: Middlebury's layout: left image, right image, the left image's disparity.
MIDDLEBURY_FILES = ("im0.png", "im1.png", "disp0.pfm")
#: The plain layout: ``left.*``, ``right.*`` (any extension Pillow reads) and the disparity.
PLAIN_FILES = ("left.*", "right.*", "disparity.npy")
#: A fixation point's least contrast: the standard deviation of grey (in [0, 1]) around it.
MIN_CONTRAST = 0.05


@dataclass(frozen=True)
class StereoPair:
    """A rectified stereo pair with the left image's disparity, or without ground truth.

    Args:
        name: the pair's name (its folder's).
        left, right: grey images ``[H, W]`` in [0, 1].
        disparity: ``[H, W]`` photo pixels (left column minus right column), NaN where unknown;
            ``None``: the pair has no ground truth.
    """

    name: str
    left: Tensor
    right: Tensor
    disparity: Tensor | None = None

    def __post_init__(self) -> None:
        images = (self.left, self.right) if self.disparity is None else (self.left, self.right, self.disparity)
        shapes = [tuple(t.shape) for t in images]
        if len(shapes[0]) != 2 or len(set(shapes)) != 1:
            names = "left and right" if self.disparity is None else "left, right and disparity"
            got = ", ".join(map(str, shapes[:-1])) + f" and {shapes[-1]}"
            raise ValueError(f"pair {self.name!r}: {names} must be [H, W] images of one size, got {got}")

    @property
    def has_ground_truth(self) -> bool:
        """Whether the pair holds a disparity map."""
        return self.disparity is not None

    @property
    def known(self) -> Tensor:
        """Where the disparity is known ``[H, W]`` (bool; nowhere without ground truth)."""
        if self.disparity is None:
            return torch.zeros(self.left.shape, dtype=torch.bool)
        return torch.isfinite(self.disparity)


def read_pfm(path: str | Path) -> np.ndarray:
    """A PFM file (Portable Float Map) as a float32 array ``[H, W]`` (``Pf``) or ``[H, W, 3]`` (``PF``),
    the first row the image's top.

    The header is ``Pf`` or ``PF``, the width and height, and a scale whose sign gives the byte
    order (negative: little-endian); the rows are stored bottom to top.

    Example:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "d.pfm")
        >>> with open(path, "wb") as f:
        ...     _ = f.write(b"Pf\\n2 2\\n-1.0\\n" + np.array([3, 4, 1, 2], "<f4").tobytes())
        >>> read_pfm(path).tolist()
        [[1.0, 2.0], [3.0, 4.0]]
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            kind = f.readline().strip()
            if kind not in (b"Pf", b"PF"):
                raise ValueError(f"not a PFM file (its header is {kind[:8]!r}, not Pf or PF)")
            size = f.readline().split()
            while size and size[0].startswith(b"#"):  # comments are not in the format, but cheap to skip
                size = f.readline().split()
            width, height = (int(v) for v in size)
            scale = float(f.readline().strip())
            channels = 3 if kind == b"PF" else 1
            data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    except (OSError, ValueError) as err:
        raise ValueError(f"cannot read PFM file {str(path)!r}: {err}") from err
    if data.size != width * height * channels:
        raise ValueError(f"cannot read PFM file {str(path)!r}: {width} x {height} x {channels} values expected, "
                         f"found {data.size}")
    shape = (height, width, channels) if channels == 3 else (height, width)
    return np.ascontiguousarray(data.reshape(shape)[::-1]).astype(np.float32)


def _image(path: Path) -> Tensor:
    from PIL import Image

    try:
        with Image.open(path) as image:
            width, height = image.size
    except OSError as err:
        raise ValueError(f"cannot read image file {str(path)!r}: {err}") from err
    return torch.from_numpy(load_grey(path, height, width))


def _one(folder: Path, stem: str) -> Path | None:
    found = sorted(p for p in folder.glob(f"{stem}.*") if p.is_file() and p.suffix.lower() != ".npy")
    if len(found) > 1:
        raise ValueError(f"pair folder {str(folder)!r} holds {len(found)} files named {stem}.*: "
                         f"{[p.name for p in found]}; keep one")
    return found[0] if found else None


def layout(folder: str | Path) -> str | None:
    """``"middlebury"`` or ``"plain"``: the layout whose files ``folder`` holds (any of them), or ``None``."""
    folder = Path(folder)
    if any((folder / name).is_file() for name in MIDDLEBURY_FILES):
        return "middlebury"
    if (folder / "disparity.npy").is_file() or _one(folder, "left") or _one(folder, "right"):
        return "plain"
    return None


def read_pair(folder: str | Path) -> StereoPair:
    """The pair in ``folder``, in Middlebury's layout or the plain one (the module's docstring).

    Raises:
        ValueError: naming the folder and the file when a layout's file is missing or unreadable
            (the plain layout's ``disparity.npy`` may be missing when both images are there: a
            pair without ground truth), the images and the disparity differ in size, or no
            disparity is known.
    """
    folder = Path(folder)
    kind = layout(folder)
    if kind is None:
        raise ValueError(f"pair folder {str(folder)!r} holds neither Middlebury's layout ({', '.join(MIDDLEBURY_FILES)}) "
                         f"nor the plain one ({', '.join(PLAIN_FILES)})")
    if kind == "middlebury":
        missing = [name for name in MIDDLEBURY_FILES if not (folder / name).is_file()]
        if missing:
            raise ValueError(f"pair folder {str(folder)!r} (Middlebury's layout) lacks {', '.join(missing)}")
        left, right = _image(folder / "im0.png"), _image(folder / "im1.png")
        disparity = torch.from_numpy(read_pfm(folder / "disp0.pfm"))
        if disparity.dim() == 3:
            disparity = disparity[..., 0]
        disparity = torch.where(torch.isfinite(disparity) & (disparity != 0), disparity, math.nan)
    else:
        files = {"left": _one(folder, "left"), "right": _one(folder, "right"),
                 "disparity": folder / "disparity.npy" if (folder / "disparity.npy").is_file() else None}
        missing = [PLAIN_FILES[i] for i, path in enumerate(files.values()) if path is None]
        left_file, right_file = files["left"], files["right"]
        if left_file is None or right_file is None:
            raise ValueError(f"pair folder {str(folder)!r} (the plain layout) lacks {', '.join(missing)}")
        left, right = _image(left_file), _image(right_file)
        if files["disparity"] is None:  # a pair without ground truth
            return StereoPair(folder.name, left, right)
        try:
            array = np.load(files["disparity"], allow_pickle=False)
        except (OSError, ValueError) as err:
            raise ValueError(f"cannot read {str(files['disparity'])!r}: {err}") from err
        if array.ndim != 2 or not np.issubdtype(array.dtype, np.number):
            raise ValueError(f"{str(files['disparity'])!r} must hold a [H, W] array of numbers, "
                             f"got {array.dtype} {array.shape}")
        disparity = torch.from_numpy(array.astype(np.float32))
        disparity = torch.where(torch.isfinite(disparity), disparity, math.nan)
    pair = StereoPair(folder.name, left, right, disparity)
    if not bool(pair.known.any()):
        raise ValueError(f"pair folder {str(folder)!r}: no pixel of its disparity is known")
    return pair


def read_pairs(folder: str | Path) -> list[StereoPair]:
    """The pairs of ``folder``: the folder itself when it holds one, else each of its sub-folders
    (sorted by name; hidden ones skipped), every one of which must hold a pair."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"no such folder {str(folder)!r}")
    if layout(folder) is not None:
        return [read_pair(folder)]
    subfolders = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not subfolders:
        raise ValueError(f"folder {str(folder)!r} holds no pair: neither a pair's files (Middlebury's "
                         f"{', '.join(MIDDLEBURY_FILES)} or the plain {', '.join(PLAIN_FILES)}) nor folders of pairs")
    return [read_pair(p) for p in subfolders]


def _window_std(image: Tensor, half: int) -> Tensor:
    """The standard deviation of ``image`` in the ``2 half`` square centred at each pixel corner
    ``(y, x)``, ``[H + 1, W + 1]`` (NaN where the square leaves the image)."""
    h, w = image.shape
    x = image.double()
    sums = [torch.nn.functional.pad(v.cumsum(0).cumsum(1), (1, 0, 1, 0)) for v in (x, x * x)]
    out = torch.full((h + 1, w + 1), math.nan, dtype=torch.float64)
    if 2 * half > min(h, w):
        return out
    n = (2 * half) ** 2

    def box(s: Tensor) -> Tensor:
        return s[2 * half:, 2 * half:] - s[:-2 * half, 2 * half:] - s[2 * half:, :-2 * half] + s[:-2 * half, :-2 * half]

    mean, square = box(sums[0]) / n, box(sums[1]) / n
    out[half:h + 1 - half, half:w + 1 - half] = (square - mean * mean).clamp_min(0).sqrt()
    return out


def pick_fixations(pair: StereoPair, count: int, *, half_extent_px: int, texture_half_px: int,
                   min_contrast: float = MIN_CONTRAST, grid_px: int = 4, seed: int = 0,
                   shift_range_px: tuple[float, float] | None = None) -> Tensor:
    """Fixation points on ``pair``: pixel corners ``(x, y)`` ``[N, 2]`` (long) with known ground
    truth (where the pair has it) and texture, ``count`` of them drawn from the candidates (all
    when fewer), reproducibly.

    A candidate is a corner on a grid of ``grid_px`` photo pixels whose four pixels have a known
    disparity, whose window of ``half_extent_px`` photo pixels either side lies in the left image
    and, moved by the disparity, in the right one, and whose left image has a standard deviation
    of at least ``min_contrast`` in the ``texture_half_px`` square around it. On a pair without
    ground truth the disparity is unknown: the window must lie in the right image moved by every
    shift of ``shift_range_px``, the right window's shifts a search may reach.

    Args:
        pair: the stereo pair.
        count: how many points (>= 1).
        half_extent_px: the eyes' largest window's half side, photo pixels.
        texture_half_px: the half side of the square whose contrast is checked, photo pixels.
        min_contrast: the least standard deviation of grey (in [0, 1]) there.
        grid_px: the candidates' spacing, photo pixels.
        seed: seeds the draw.
        shift_range_px: ``(low, high)``, photo pixels: how far left of the point the right
            window may move (``f tan(vergence) pair_scale`` over the vergence range); needed
            for, and used only on, a pair without ground truth.

    Raises:
        ValueError: when no candidate is left, saying which condition removed them, or a pair
            without ground truth is given no ``shift_range_px``.
    """
    check_int(count, "count", 1)
    check_int(half_extent_px, "half_extent_px", 1)
    check_int(texture_half_px, "texture_half_px", 1)
    check_int(grid_px, "grid_px", 1)
    check_real(min_contrast, "min_contrast", minimum=0.0)
    h, w = pair.left.shape
    ys = torch.arange(h + 1, dtype=torch.float64)[:, None].expand(h + 1, w + 1)
    xs = torch.arange(w + 1, dtype=torch.float64)[None, :].expand(h + 1, w + 1)
    inside = (ys >= half_extent_px) & (ys <= h - half_extent_px) & (xs >= half_extent_px) & (xs <= w - half_extent_px)
    conditions: dict[str, Tensor] = {}
    if pair.disparity is not None:
        d = pair.disparity.double()
        # the ground truth at a corner: the mean of its four pixels (NaN when one is unknown)
        corner = torch.full((h + 1, w + 1), math.nan, dtype=torch.float64)
        corner[1:h, 1:w] = (d[:-1, :-1] + d[:-1, 1:] + d[1:, :-1] + d[1:, 1:]) / 4
        conditions["a known disparity"] = torch.isfinite(corner)
        conditions[f"the window ({2 * half_extent_px} photo px) inside both images"] = (
            inside & (xs - corner >= half_extent_px) & (xs - corner <= w - half_extent_px))
    else:
        if shift_range_px is None:
            raise ValueError(f"pair {pair.name!r} has no ground truth: give shift_range_px, the right window's "
                             "shifts a search may reach")
        low, high = (float(v) for v in shift_range_px)
        if not low <= high:
            raise ValueError(f"shift_range_px must be (low, high) with low <= high, got {shift_range_px!r}")
        conditions[f"the window ({2 * half_extent_px} photo px) inside both images over the shifts "
                   f"{low:.1f} to {high:.1f} photo px"] = (
            inside & (xs - high >= half_extent_px) & (xs - low <= w - half_extent_px))
    conditions[f"contrast >= {min_contrast:g}"] = _window_std(pair.left, texture_half_px) >= min_contrast
    grid = torch.zeros(h + 1, w + 1, dtype=torch.bool)
    grid[::grid_px, ::grid_px] = True
    ok = grid
    for name, condition in conditions.items():
        ok = ok & condition
        if not bool(ok.any()):
            raise ValueError(f"pair {pair.name!r} ({w} x {h} px) has no fixation point with {name} "
                             f"(and the conditions before it: {', '.join(conditions)})")
    y, x = torch.nonzero(ok, as_tuple=True)
    order = torch.randperm(y.numel(), generator=torch.Generator().manual_seed(seed))[:count]
    order = order.sort().values  # the points in reading order
    return torch.stack((x[order], y[order]), -1)


def corner_disparity(pair: StereoPair, points: Tensor) -> Tensor:
    """The ground truth at pixel corners ``points`` ``[N, 2]`` (x, y): the mean disparity of the
    four pixels around each ``[N]`` (photo pixels, float64; NaN on a pair without ground truth)."""
    x, y = points[:, 0].long(), points[:, 1].long()
    if pair.disparity is None:
        return torch.full((points.shape[0],), math.nan, dtype=torch.float64)
    d = pair.disparity.double()
    return (d[y - 1, x - 1] + d[y - 1, x] + d[y, x - 1] + d[y, x]) / 4


def disparity_roughness(pair: StereoPair, points: Tensor, half_px: int, *, quantile: float = 0.9
                        ) -> tuple[Tensor, Tensor]:
    """How far the ground truth around each point departs from a surface: in the square of
    ``half_px`` photo pixels either side of the point, the ``quantile`` of the known disparities'
    absolute distance from their least-squares plane (photo pixels; a slanted surface has none, a
    depth edge much), and the fraction of the square whose disparity is unknown, two ``[N]``."""
    if pair.disparity is None:
        raise ValueError(f"pair {pair.name!r} has no ground truth: its roughness is unknown")
    rough, unknown = [], []
    for x, y in points.long().tolist():
        window = pair.disparity[max(y - half_px, 0):y + half_px, max(x - half_px, 0):x + half_px].double()
        rows, cols = torch.meshgrid(torch.arange(window.shape[0], dtype=torch.float64),
                                    torch.arange(window.shape[1], dtype=torch.float64), indexing="ij")
        known = torch.isfinite(window)
        unknown.append(1.0 - float(known.double().mean()) if window.numel() else 1.0)
        if int(known.sum()) < 3:
            rough.append(math.nan)
            continue
        design = torch.stack((torch.ones_like(rows[known]), cols[known], rows[known]), -1)
        plane = torch.linalg.lstsq(design, window[known][:, None]).solution
        residual = (window[known] - (design @ plane)[:, 0]).abs()
        rough.append(float(torch.quantile(residual, quantile)))
    return torch.tensor(rough, dtype=torch.float64), torch.tensor(unknown, dtype=torch.float64)


#: A pixel is occluded in the right photograph when a nearer pixel's disparity there exceeds its own
#: by more than this many photo pixels (:func:`occlusion`).
OCCLUSION_TOLERANCE_PX = 1.0


def occlusion(pair: StereoPair, tolerance_px: float = OCCLUSION_TOLERANCE_PX) -> Tensor:
    """Which pixels of the left photograph the right one does not see, ``[H, W]`` bool, from the
    ground truth alone (a left-right visibility test, as Middlebury's ``mask0nocc`` marks them).

    The pixel at column ``x`` with known disparity ``d`` covers the right photograph's columns
    ``floor(x - d)`` and ``ceil(x - d)`` (one column where ``x - d`` is whole). Every known pixel
    of the row marks the columns it covers with its disparity; a pixel is occluded where the
    largest disparity marked on a column it covers exceeds its own by more than ``tolerance_px``
    (a nearer surface covers it there). Unknown pixels neither occlude nor are occluded; pixels
    that land outside the right photograph are occluded (it does not see them either).

    Example:
        >>> d = torch.full((1, 30), 2.0)
        >>> d[0, 15:25] = 10.0  # a near object; the 8 px of background left of it are hidden
        >>> pair = StereoPair("toy", torch.zeros(1, 30), torch.zeros(1, 30), d)
        >>> torch.nonzero(occlusion(pair)[0]).flatten().tolist()
        [0, 1, 7, 8, 9, 10, 11, 12, 13, 14]
    """
    check_real(tolerance_px, "tolerance_px", minimum=0.0)
    if pair.disparity is None:
        raise ValueError(f"pair {pair.name!r} has no ground truth: its occlusion cannot be told")
    d = pair.disparity.double()
    h, w = d.shape
    known = torch.isfinite(d)
    columns = torch.arange(w, dtype=torch.float64).expand(h, w)
    lands = columns - torch.where(known, d, 0.0)
    first, last = torch.floor(lands).long(), torch.ceil(lands).long()
    inside = known & (first >= 0) & (last < w)
    rows = torch.arange(h)[:, None].expand(h, w)
    marks = torch.full((h * w,), -math.inf, dtype=torch.float64)
    for column in (first, last):  # the columns each pixel covers
        marks.scatter_reduce_(0, (rows * w + column.clamp(0, w - 1))[inside], d[inside], reduce="amax")
    marks = marks.view(h, w)
    nearest = torch.maximum(marks.gather(1, first.clamp(0, w - 1)), marks.gather(1, last.clamp(0, w - 1)))
    return known & (~inside | (nearest > d + tolerance_px))
