"""Exact, batched, differentiable rendering of the plane scene in torch (ray-plane homography).

Every pixel's ray (through its centre, see :mod:`aectorch.sim.camera`) is intersected with the
object plane ``x = plane_x_m`` and with the background plane; the hit point's texture coordinate
is sampled bilinearly with clamp-to-edge, exactly as OpenGL samples a ``GL_LINEAR`` texture with
``GL_CLAMP_TO_EDGE`` wrap (texel ``i`` centred at ``i + 0.5``, no mipmaps), or, with
``filter="trilinear"``, from an area-filtered texture pyramid (mipmaps, OpenGL's
``GL_LINEAR_MIPMAP_LINEAR``: the level of detail from the pixel's footprint in texels, two
bilinear lookups in the two nearest levels, blended). For a plane the map from pixel to texture
coordinate is a homography; computing it through the ray keeps the code batched over any camera
pose and lets a window of the image (the coder's central crops) be rendered without the rest,
also on a coarser pixel grid (``downsample``: each pixel covers ``downsample x downsample``
pixels of the camera, which is how each foveal scale is rendered at the resolution it reads).

Textures are sampled by index arithmetic from one flat tensor of all textures, so each
environment can look at its own texture without copying textures per environment, and the
result is differentiable in the poses, the plane distances and the texture values.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor, nn

from aectorch._checks import check_int
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.scene import Placement, PlaneScene
from aectorch.sim.textures.storage import empty_textures

__all__ = ["FILTERS", "MipmapAtlas", "TorchPlaneRenderer", "mipmap_atlas", "mipmap_levels", "pixel_rays",
           "render_planes", "render_rays", "sample_bilinear", "texture_atlas"]

#: Texture filters: ``"linear"`` (``GL_LINEAR``, no mipmaps) or ``"trilinear"``
#: (``GL_LINEAR_MIPMAP_LINEAR`` minification, ``GL_LINEAR`` magnification).
FILTERS = ("linear", "trilinear")


def sample_bilinear(
    textures: Tensor, texture_index: Tensor, u: Tensor, v: Tensor
) -> Tensor:
    """Sample textures bilinearly with clamp-to-edge at continuous texel coordinates.

    Args:
        textures: ``[N, H, W]``.
        texture_index: which texture each leading row of ``u`` reads, ``[B]``, or each
            sample reads, the shape of ``u`` (integers).
        u: column coordinate in texels, ``[B, ...]``; texel ``j`` is centred at ``j + 0.5``.
        v: row coordinate in texels (row 0 at the top), same shape as ``u``.

    Returns:
        Sampled values, shape of ``u``, dtype of ``textures``.

    Example:
        >>> tex = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]])
        >>> sample_bilinear(tex, torch.tensor([0]), torch.tensor([[1.0, 0.2]]), torch.tensor([[1.0, 1.0]]))
        tensor([[0.5000, 0.0000]])
    """
    n, h, w = textures.shape
    flat = textures.reshape(-1)
    x = (u - 0.5).clamp(0.0, w - 1.0)
    y = (v - 0.5).clamp(0.0, h - 1.0)
    x0 = x.detach().floor()
    y0 = y.detach().floor()
    wx = x - x0
    wy = y - y0
    x0i = x0.long()
    y0i = y0.long()
    x1i = (x0i + 1).clamp(max=w - 1)
    y1i = (y0i + 1).clamp(max=h - 1)
    base = texture_index.long() * (h * w)
    if base.ndim == 1:
        base = base.reshape((-1,) + (1,) * (u.ndim - 1))
    row0 = base + y0i * w
    row1 = base + y1i * w
    a = flat[row0 + x0i]
    b = flat[row0 + x1i]
    c = flat[row1 + x0i]
    d = flat[row1 + x1i]
    top = a + wx * (b - a)
    bottom = c + wx * (d - c)
    return top + wy * (bottom - top)


#: Above this many atlas rows in float32, the atlas coordinate's rounding (about
#: rows * 6e-8 texels) would approach 1 % of a texel: sample by index arithmetic instead.
_ATLAS_ROWS_FLOAT32 = 2**18
# Texels of level 0 filtered at once while an atlas's mipmaps are built (bounds the temporaries).
_MIP_CHUNK_TEXELS = 2**22


def texture_atlas(textures: Tensor, background: Tensor) -> Tensor:
    """Stack the object textures and the background (same size) into one ``[N + 1, H, W]`` atlas.

    A large atlas lives in a file mapped into memory (`aectorch.sim.textures.storage.empty_textures`).
    """
    if background.shape != textures.shape[-2:]:
        raise ValueError(
            f"background must have the textures' size {tuple(textures.shape[-2:])}, got "
            f"{tuple(background.shape)} (PlaneScene resamples it)"
        )
    n, h, w = textures.shape
    atlas = empty_textures((n + 1, h, w), textures.dtype, textures.device)
    atlas[:n] = textures
    atlas[n] = background
    return atlas


class MipmapAtlas(NamedTuple):
    """All textures' mipmap chains packed side by side, one packed image per texture (see :func:`mipmap_atlas`).

    Attributes:
        packed: ``[N, Hp, Wp]``: level 0 in columns ``0 .. W - 1``, the smaller levels stacked
            top to bottom in the columns to its right.
        origins: ``[L, 2]`` (int64): the row and column of each level's first texel.
        sizes: ``[L, 2]`` (int64): each level's height and width.
    """

    packed: Tensor
    origins: Tensor
    sizes: Tensor

    @property
    def levels(self) -> int:
        """Number of levels L (level 0 is the texture itself)."""
        return self.sizes.shape[0]


def mipmap_levels(images: Tensor) -> list[Tensor]:
    """The mipmap chain of ``[N, H, W]`` images, as OpenGL's ``glGenerateMipmap`` builds it.

    Each level halves both sides (rounding down, never below 1) and is the area average of the
    level above: the mean of each 2 x 2 block when the sides are even (every level of a power-of-two
    texture), an area resampling otherwise (OpenGL leaves odd sizes' filter to the implementation).

    Example:
        >>> levels = mipmap_levels(torch.rand(1, 4, 8))
        >>> len(levels), tuple(levels[1].shape), tuple(levels[-1].shape)
        (4, (1, 2, 4), (1, 1, 1))
    """
    levels = [images]
    x = images
    while x.shape[-2] > 1 or x.shape[-1] > 1:
        h, w = x.shape[-2:]
        size = (max(h // 2, 1), max(w // 2, 1))
        x = torch.nn.functional.adaptive_avg_pool2d(x.unsqueeze(1), size).squeeze(1)
        levels.append(x)
    return levels


def mipmap_atlas(textures: Tensor, background: Tensor) -> MipmapAtlas:
    """The :func:`texture_atlas` of ``textures`` and ``background`` with every layer's mipmaps, packed.

    Memory: about 1.5x the plain atlas (level 0 plus the levels beside it). The layers are
    filtered a chunk at a time into the packed atlas, which lives in a file mapped into memory
    when it is large (`aectorch.sim.textures.storage.empty_textures`), so no temporary copy of all the
    textures is made.
    """
    if background.shape != textures.shape[-2:]:
        raise ValueError(
            f"background must have the textures' size {tuple(textures.shape[-2:])}, got "
            f"{tuple(background.shape)} (PlaneScene resamples it)"
        )
    n, h, w = textures.shape
    sizes = [(h, w)]
    while sizes[-1] != (1, 1):
        sizes.append((max(sizes[-1][0] // 2, 1), max(sizes[-1][1] // 2, 1)))
    right = sizes[1][1] if len(sizes) > 1 else 0
    height = max(h, sum(lh for lh, _ in sizes[1:]))
    origins, row = [(0, 0)], 0
    for lh, _ in sizes[1:]:
        origins.append((row, w))
        row += lh
    packed = empty_textures((n + 1, height, w + right), textures.dtype, textures.device)
    packed[:, h:, :w] = 0  # what no level covers reads 0, as before
    packed[:, :, w:] = 0
    step = max(1, _MIP_CHUNK_TEXELS // (h * w))
    for start in range(0, n + 1, step):
        stop = min(start + step, n + 1)
        chunk = textures[start:min(stop, n)]
        if stop > n:
            chunk = torch.cat((chunk, background.to(textures).unsqueeze(0)))
        for (top, left), (lh, lw), level in zip(origins, sizes, mipmap_levels(chunk)):
            packed[start:stop, top:top + lh, left:left + lw] = level
    as_long = lambda rows: torch.tensor(rows, dtype=torch.int64, device=textures.device)  # noqa: E731
    return MipmapAtlas(packed, as_long(origins), as_long(sizes))


def _plane_coords(o, ry, rz, plane_x, center_yz, size_m):
    """Normalised plane coordinates (0..1 from the left / top edge) of rays ``(1, ry, rz)``."""
    reach = plane_x - o[..., 0]  # along x from the eye to the plane, [B, C, 1]
    width, height = size_m
    u = (center_yz[0] + 0.5 * width - o[..., 1]) / width - (reach / width) * ry
    v = (center_yz[1] + 0.5 * height - o[..., 2]) / height - (reach / height) * rz
    hit = (reach > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    return u, v, hit, reach


def _checked_placement(placement, batch: int, scene: PlaneScene, check: bool) -> Placement | None:
    """``placement`` checked (indices only with ``check``), ``None`` where it places nothing."""
    if placement is None:
        return None
    if not isinstance(placement, Placement):
        raise TypeError(f"placement must be None or an aectorch.sim.scene.Placement, got {type(placement).__name__}")
    if check:
        placement.check(batch, scene.num_textures)
    return None if all(part is None for part in placement) else placement


def _object_coords(o, ry, rz, plane_x, plane_y_m, placement, scene):
    """The object plane's ``(u, v, hit, reach_u, reach_v, cross)`` (see :func:`_slanted_coords`;
    ``cross`` None on a fronto-parallel plane), its visible square cut out."""
    slant = None if placement is None else placement.slant_rad
    if slant is None:
        centre = scene.object_center_yz_m
        if plane_y_m is not None:  # a moving object: its centre moved sideways
            centre = (plane_y_m.to(plane_x.dtype)[:, None, None] + centre[0], centre[1])
        u, v, hit, reach = _plane_coords(o, ry, rz, plane_x, centre, scene.object_size_m)
        reach_v, cross = reach, None
    else:
        u, v, hit, reach, reach_v, cross = _slanted_coords(
            o, ry, rz, plane_x, slant.to(plane_x.dtype)[:, None, None], scene.object_center_yz_m, plane_y_m,
            scene.object_size_m)
    if scene.object_cut is not None:  # the visible square around the object's centre
        cut_u, cut_v = scene.object_cut
        hit = hit & ((u - 0.5).abs() <= cut_u) & ((v - 0.5).abs() <= cut_v)
    return u, v, hit, reach, reach_v, cross


def _background_of(placement, plane_x, layers: int, texture_index, scene):
    """The background planes' x ``[B, 1, 1]`` and atlas layer (the last one, or ``[B, 1, 1]`` drawn ones)."""
    background_x, behind = torch.full_like(plane_x, scene.background_x_m), layers - 1
    if placement is not None and placement.background_x_m is not None:
        background_x = placement.background_x_m.to(plane_x.dtype)[:, None, None]
    if placement is not None and placement.background_index is not None:
        behind = placement.background_index.to(texture_index.device).reshape(-1, 1, 1)
    return background_x, behind


def _slanted_coords(o, ry, rz, plane_x, slant, pivot_yz, offset, size_m):
    """:func:`_plane_coords` of the object plane turned by ``slant`` about the vertical through
    ``(plane_x, pivot_yz[0])``, its centre moved along it by ``offset`` (``[B]`` or ``None``).

    Returns ``(u, v, hit, reach_u, reach_v, cross)``, the derivatives the level of detail reads,
    in the plain plane's form (where both reaches are ``plane_x - ox`` and ``cross`` is 0):
    ``-du/dry = reach_u / width``, ``-dv/drz = reach_v / height`` and ``-dv/dry = cross``.
    """
    width, height = size_m
    c, s = torch.cos(slant), torch.sin(slant)
    normal = c * (plane_x - o[..., 0]) + s * (pivot_yz[0] - o[..., 1])  # n . (pivot - eye)
    den = c + s * ry
    t = normal / torch.where(den.abs() > 1e-12, den, torch.full_like(den, 1e-12))  # hit = o + t (1, ry, rz)
    # The hit's coordinate along the plane's horizontal axis e = (-sin, cos, 0) from the pivot.
    along = -s * (o[..., 0] + t - plane_x) + c * (o[..., 1] + t * ry - pivot_yz[0])
    if offset is not None:
        along = along - offset.to(along.dtype)[:, None, None]
    u = 0.5 - along / width
    v = 0.5 - (o[..., 2] + t * rz - pivot_yz[1]) / height
    hit = (t > 0) & (den > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    reach_u = normal / den.square()
    cross = -reach_u * s * rz / height
    return u, v, hit, reach_u, t, cross


def _sample_atlas(atlas: Tensor, layer: Tensor, u: Tensor, v: Tensor, dtype) -> Tensor:
    """Bilinear lookups at texel coordinates ``(u, v)`` of atlas ``layer`` ``[N, H, W]``, one ``grid_sample``.

    The coordinates must already be clamped to edge texel centres. Above ``_ATLAS_ROWS_FLOAT32``
    rows in float32 the lookups use index arithmetic (:func:`sample_bilinear`) instead.
    """
    layers, tex_h, tex_w = atlas.shape
    if not (dtype == torch.float64 or layers * tex_h <= _ATLAS_ROWS_FLOAT32):
        return sample_bilinear(atlas, layer.long(), u, v)
    layer = layer.to(dtype)
    w = u.shape[-1]
    if torch.compiler.is_compiling() or (torch.is_grad_enabled() and (u.requires_grad or v.requires_grad)):
        # (compiled: inductor fuses the stack; the in-place writes below do not trace)
        gx = u * (2.0 / tex_w) - 1.0
        gy = (layer * tex_h + v) * (2.0 / (layers * tex_h)) - 1.0
        grid = torch.stack((gx, gy), dim=-1)
    else:  # the same, written in place into the grid (saves a copy of every coordinate)
        grid = torch.empty(u.shape + (2,), dtype=dtype, device=u.device)
        torch.mul(u, 2.0 / tex_w, out=grid[..., 0]).sub_(1.0)
        torch.add(v, layer, alpha=tex_h, out=grid[..., 1])
        grid[..., 1].mul_(2.0 / (layers * tex_h)).sub_(1.0)
    return torch.nn.functional.grid_sample(
        atlas.reshape(1, 1, layers * tex_h, tex_w), grid.reshape(1, -1, w, 2), mode="bilinear",
        padding_mode="border", align_corners=False,
    ).reshape(u.shape)


def pixel_rays(camera: PinholeCamera, windows, *, dtype=torch.float32, device=None) -> tuple[Tensor, Tensor, Tensor]:
    """The ray slopes through the pixel centres of several windows, flattened, and each pixel's size.

    Args:
        camera: intrinsics.
        windows: ``(PixelWindow, downsample)`` pairs: each window on a grid of ``downsample x
            downsample`` blocks of the camera's pixels (its sides multiples of ``downsample``).

    Returns:
        ``(xs, ys, step)``, each ``[P]`` with ``P`` the windows' pixels, row-major, window after
        window: the ray ``(xs, ys, 1)`` in the ROS optical frame through each pixel's centre, and
        the pixel's side in the same units (``downsample / focal_px``).
    """
    cx, cy = camera.principal_point
    f = camera.focal_px
    xs, ys, steps = [], [], []
    for window, downsample in windows:
        top, left, h, w = camera.check_window(window)
        check_int(downsample, "downsample")
        if h % downsample or w % downsample:
            raise ValueError(f"the window's sides {h} x {w} must be multiples of downsample={downsample}")
        h, w = h // downsample, w // downsample
        x = (left + (torch.arange(w, dtype=dtype, device=device) + 0.5) * downsample - cx) / f
        y = (top + (torch.arange(h, dtype=dtype, device=device) + 0.5) * downsample - cy) / f
        xs.append(x.repeat(h))
        ys.append(y.repeat_interleave(w))
        steps.append(torch.full((h * w,), downsample / f, dtype=dtype, device=device))
    return torch.cat(xs), torch.cat(ys), torch.cat(steps)


def render_planes(
    poses: Tensor,
    plane_x_m: Tensor,
    texture_index: Tensor,
    scene: PlaneScene,
    camera: PinholeCamera = PinholeCamera(),
    window: PixelWindow | None = None,
    *,
    textures: Tensor | None = None,
    background: Tensor | None = None,
    atlas: Tensor | MipmapAtlas | None = None,
    check: bool = True,
    downsample: int = 1,
    filter: str = "linear",
    lod_bias: float = 0.0,
    samples: int = 1,
    plane_y_m: Tensor | None = None,
    placement: Placement | None = None,
) -> Tensor:
    """Render grey images of the plane scene for a batch of cameras.

    For each camera the pixel -> plane map is a homography: with the ray direction
    ``(dx, dy, dz)`` of a pixel (linear in the pixel's position), the plane ``x = X`` is hit at
    ``y = oy + (X - ox) dy / dx``, ``z = oz + (X - ox) dz / dx``. Both planes share the ratios
    ``dy / dx`` and ``dz / dx``; each pixel then reads the object plane where it hits it, else
    the background, with one bilinear ``grid_sample`` over an atlas of all textures (clamped to
    each texture's edge texel centres, which is ``GL_CLAMP_TO_EDGE``).

    With ``filter="trilinear"`` each pixel reads the textures' mipmaps as OpenGL's
    ``GL_LINEAR_MIPMAP_LINEAR`` does: the level of detail ``lambda = log2(rho) + lod_bias``, with
    ``rho`` the longer of the pixel's two sides measured in texels (from the homography's exact
    derivatives), selects the two nearest levels, each sampled bilinearly, blended by
    ``lambda``'s fraction; ``lambda <= 0`` (magnification) reads level 0 alone. A texel of level
    ``l`` is the mean of ``2**l x 2**l`` texels, so a pixel covering many texels reads about their
    mean (an area filter) at a cost that does not depend on how many texels it covers.

    Args:
        poses: camera-to-world transforms in the OpenGL camera convention (x right, y up, looking
            along -z), ``[B, ..., 4, 4]`` (for example ``[B, 2, 4, 4]`` for both eyes).
        plane_x_m: world x of each environment's object plane, ``[B]``.
        texture_index: each environment's object texture (index into ``scene.textures``), ``[B]``.
        scene: the planes' geometry and textures.
        camera: intrinsics.
        window: the pixels to render (``None`` = the whole image).
        textures: override ``scene.textures`` (same shape), e.g. to differentiate with respect to
            them.
        background: override ``scene.background``.
        atlas: a prebuilt :func:`texture_atlas` (``filter="linear"``) or :func:`mipmap_atlas`
            (``"trilinear"``), what :class:`TorchPlaneRenderer` passes.
        check: check that every texture index is in range (one host sync). An index out of
            range would otherwise read a neighbouring texture of the atlas without an error.
        downsample: render the window on a grid of ``downsample x downsample`` blocks of the
            camera's pixels, one sample at each block's centre (the window's sides must be
            multiples of it); with ``"trilinear"`` each sample filters over its block.
        filter: ``"linear"`` or ``"trilinear"`` (:data:`FILTERS`).
        lod_bias: added to the level of detail (``GL_TEXTURE_LOD_BIAS``; ``"trilinear"`` only).
        samples: ``"trilinear"`` only: average ``samples x samples`` lookups spread over each pixel
            (at the centres of its sub-pixels, placed along the pixel's footprint on the plane),
            each at the level of detail of a sub-pixel. Two (with ``lod_bias=-0.5``) is within
            0.5 % of the exact area average of the texture (docs/simulation.md); one sample is
            OpenGL's.
        plane_y_m: each environment's object plane moved sideways by this much from
            ``scene.object_center_yz_m`` (world y, metres, ``[B]``; a moving object); ``None``: not moved.
            With a slanted object (``placement``) the centre moves along the turned plane.
        placement: each environment's slant and background (:class:`~aectorch.sim.scene.Placement`,
            a `SceneLayout`'s draws); ``None``: the scene's fronto-parallel object and background.

    Returns:
        Intensities in [0, 1]; the object plane occludes the background; pixels whose ray hits
        neither plane are 0. Dtype and device of ``poses``.

    Shape:
        output: ``[B, ..., window.height // downsample, window.width // downsample]``.
    """
    window = camera.check_window(window)
    rays = pixel_rays(camera, [(window, downsample)], dtype=poses.dtype, device=poses.device)
    image = render_rays(poses, plane_x_m, texture_index, scene, rays, textures=textures, background=background,
                        atlas=atlas, check=check, filter=filter, lod_bias=lod_bias, samples=samples,
                        plane_y_m=plane_y_m, placement=placement)
    return image.reshape(image.shape[:-1] + (window.height // downsample, window.width // downsample))


# long: one pass per pixel, ray -> plane hit -> texel -> filtered lookup, kept in one function so that
# torch.compile fuses it into one kernel and the fused C++ kernel (render_cpu.cpp) can mirror it line by line.
def render_rays(
    poses: Tensor,
    plane_x_m: Tensor,
    texture_index: Tensor,
    scene: PlaneScene,
    rays: tuple[Tensor, Tensor, Tensor],
    *,
    textures: Tensor | None = None,
    background: Tensor | None = None,
    atlas: Tensor | MipmapAtlas | None = None,
    check: bool = True,
    filter: str = "linear",
    lod_bias: float = 0.0,
    samples: int = 1,
    plane_y_m: Tensor | None = None,
    placement: Placement | None = None,
) -> Tensor:
    """:func:`render_planes` for the flattened pixels of :func:`pixel_rays`: ``[B, ..., P]``.

    Several windows (for example every foveal scale, each on its own pixel grid) then render in
    one pass: the same elementwise operations and one texture lookup for all of them.
    """
    batch = scene.check_render_inputs(poses, plane_x_m, texture_index, check_range=check, plane_y_m=plane_y_m)
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {FILTERS}, got {filter!r}")
    check_int(samples, "samples")
    placement = _checked_placement(placement, batch, scene, check)
    dtype, device = poses.dtype, poses.device
    trilinear = filter == "trilinear"
    if atlas is None:
        build = mipmap_atlas if trilinear else texture_atlas
        atlas = build(
            scene.textures if textures is None else textures,
            scene.background if background is None else background,
        )
    if trilinear != isinstance(atlas, MipmapAtlas):
        raise TypeError(f"filter={filter!r} needs atlas to be a "
                        f"{'MipmapAtlas (mipmap_atlas)' if trilinear else 'tensor (texture_atlas)'}, "
                        f"got {type(atlas).__name__}")
    mip = atlas if trilinear else None
    if trilinear and placement is None and scene.object_extent_m is None \
            and _native_trilinear(poses, mip, textures, background, scene):
        from aectorch.ops import native  # noqa: F401 - registers the operator

        (object_w, object_h), (background_w, background_h) = scene.object_size_m, scene.background_size_m
        numbers = [*scene.object_center_yz_m, object_w, object_h, scene.background_x_m,
                   *scene.background_center_yz_m, background_w, background_h]
        flat = torch.ops.aectorch.render_trilinear(
            poses.reshape(batch, -1, 4, 4), plane_x_m, texture_index, mip.packed, *rays, numbers,
            int(scene.textures.shape[-2]), int(scene.textures.shape[-1]), mip.levels, float(lod_bias), samples,
            plane_y_m)
        return flat.reshape(poses.shape[:-2] + (flat.shape[-1],))
    atlas = (mip.packed if trilinear else atlas).to(dtype=dtype, device=device)
    layers = atlas.shape[0]
    tex_h, tex_w = (int(n) for n in scene.textures.shape[-2:])
    xs, ys, step = (r.to(dtype=dtype, device=device) for r in rays)

    middle = poses.shape[1:-2]
    flat = poses.reshape(batch, -1, 4, 4)
    o = flat[:, :, None, :3, 3]  # [B, C, 1, 3]
    rot = flat[:, :, :3, :3, None]  # [B, C, 3, 3, 1]
    # The ray (xs, ys, 1) in the ROS optical frame is (xs, -ys, -1) in the OpenGL camera frame.
    d = [rot[:, :, i, 0] * xs - (rot[:, :, i, 1] * ys + rot[:, :, i, 2]) for i in range(3)]
    ahead = d[0] > 1e-12
    inv = 1.0 / torch.where(ahead, d[0], torch.ones_like(d[0]))
    ry, rz = d[1] * inv, d[2] * inv  # [B, C, P]

    plane_x = plane_x_m.to(dtype)[:, None, None]
    # cross: a slanted object's dv/dry, for the level of detail (None: fronto-parallel)
    u, v, on_object, reach, reach_v, cross = _object_coords(o, ry, rz, plane_x, plane_y_m, placement, scene)
    background_x, behind = _background_of(placement, plane_x, layers, texture_index, scene)
    ub, vb, on_background, reach_b = _plane_coords(
        o, ry, rz, background_x, scene.background_center_yz_m, scene.background_size_m,
    )
    on_object = on_object & ahead
    seen = on_object | (on_background & ahead)
    u = torch.where(on_object, u, ub)
    v = torch.where(on_object, v, vb)
    # The atlas layer of each sample: object texture or background (the last layer, or a texture
    # of the bank drawn per trial).
    layer = torch.where(on_object, texture_index.reshape(-1, 1, 1), behind)
    if not trilinear:
        # Continuous texel coordinates clamped to the edge texels' centres (GL_CLAMP_TO_EDGE).
        u = (u * tex_w).clamp_(0.5, tex_w - 0.5)
        v = (v * tex_h).clamp_(0.5, tex_h - 0.5)
        image = _sample_atlas(atlas, layer, u, v, dtype)
    else:
        # Texels per unit of ry (u) and of rz (v) on the plane each pixel reads, times its size.
        (object_w, object_h), (background_w, background_h) = scene.object_size_m, scene.background_size_m
        ku = torch.where(on_object, reach * (tex_w / object_w), reach_b * (tex_w / background_w)) * step
        kv = torch.where(on_object, reach_v * (tex_h / object_h), reach_b * (tex_h / background_h)) * step
        # The pixel's sides in texels: the derivatives of (ry, rz) along a column and a row step
        # (up to a common sign, which the symmetric sub-sample pattern does not see).
        r0, r1, r2 = rot[:, :, 0], rot[:, :, 1], rot[:, :, 2]  # rows, each [B, C, 3, 1]
        du_c = ku * (r1[:, :, 0] - ry * r0[:, :, 0]) * inv
        dv_c = kv * (r2[:, :, 0] - rz * r0[:, :, 0]) * inv
        du_r = ku * (ry * r0[:, :, 1] - r1[:, :, 1]) * inv
        dv_r = kv * (rz * r0[:, :, 1] - r2[:, :, 1]) * inv
        if cross is not None:  # on a slanted object v changes with ry too
            kc = torch.where(on_object, cross * tex_h, torch.zeros_like(cross)) * step
            dv_c = dv_c + kc * (r1[:, :, 0] - ry * r0[:, :, 0]) * inv
            dv_r = dv_r + kc * (ry * r0[:, :, 1] - r1[:, :, 1]) * inv
        rho2 = torch.maximum(du_c.square() + dv_c.square(), du_r.square() + dv_r.square())
        lod = 0.5 * torch.log2(rho2.clamp_min(1e-30)) + (lod_bias - math.log2(samples))
        u, v = u * tex_w, v * tex_h
        if samples > 1:  # a samples x samples grid inside each pixel, along its two sides
            offsets = (torch.arange(samples, dtype=dtype, device=device) + 0.5) / samples - 0.5
            oc, orow = offsets.repeat(samples), offsets.repeat_interleave(samples)
            u = (u[..., None] + du_c[..., None] * oc + du_r[..., None] * orow).flatten(-2)
            v = (v[..., None] + dv_c[..., None] * oc + dv_r[..., None] * orow).flatten(-2)
            lod = lod.repeat_interleave(samples * samples, dim=-1)
            layer = layer.repeat_interleave(samples * samples, dim=-1)
        image = _trilinear(mip, atlas, layer, u, v, lod, (tex_h, tex_w), dtype)
        if samples > 1:
            image = image.unflatten(-1, (-1, samples * samples)).mean(-1)
    image = torch.where(seen, image, torch.zeros_like(image))
    return image.reshape((batch, *middle, image.shape[-1]))


def _native_trilinear(poses, mip, textures, background, scene) -> bool:
    """Whether the fused CPU kernel (``render_cpu.cpp``) can render this call."""
    h, w = scene.textures.shape[-2:]
    if poses.device.type != "cpu" or poses.dtype not in (torch.float32, torch.float64) \
            or mip.packed.device.type != "cpu" or h & (h - 1) or w & (w - 1):
        return False
    if torch.is_grad_enabled() and any(t is not None and t.requires_grad for t in (poses, textures, background)):
        return False  # the kernel has no backward: the torch code is differentiable
    from aectorch.ops import native

    # (while tracing: only a kernel loaded already; a build does not belong in a graph)
    return native._state.get("ok") is True if torch.compiler.is_compiling() else native.available()


def _trilinear(mip: MipmapAtlas, atlas: Tensor, layer: Tensor, u: Tensor, v: Tensor, lod: Tensor,
               tex: tuple[int, int], dtype) -> Tensor:
    """``GL_LINEAR_MIPMAP_LINEAR`` lookups at level-0 texel coordinates ``(u, v)`` and levels of detail ``lod``."""
    tex_h, tex_w = tex
    top_level = mip.levels - 1
    lod = lod.clamp(0.0, float(top_level))
    low = lod.detach().floor()
    fraction = lod - low
    high = (low + 1).clamp_(max=top_level)
    power_of_two = tex_h & (tex_h - 1) == 0 and tex_w & (tex_w - 1) == 0
    xs, ys = [], []
    for level in (low, high):
        if power_of_two:  # sizes and origins in closed form (no gathers): level l is (H, W) / 2**l
            scale = torch.exp2(-level)
            lh, lw = (tex_h * scale).clamp_(min=1.0), (tex_w * scale).clamp_(min=1.0)
            row = (tex_h - 2 * tex_h * scale).clamp_(min=0.0)  # levels >= 1 stacked from row 0
            col = level.clamp(max=1.0) * tex_w
            x, y = u * scale, v * scale
        else:
            index = level.long()
            sizes, origins = mip.sizes.to(index.device, dtype), mip.origins.to(index.device, dtype)
            lh, lw, row, col = sizes[index, 0], sizes[index, 1], origins[index, 0], origins[index, 1]
            x, y = u * (lw / tex_w), v * (lh / tex_h)
        xs.append(torch.minimum(torch.maximum(x, torch.full_like(x, 0.5)), lw - 0.5) + col)
        ys.append(torch.minimum(torch.maximum(y, torch.full_like(y, 0.5)), lh - 0.5) + row)
    both = _sample_atlas(atlas, torch.cat((layer, layer), dim=-1), torch.cat(xs, dim=-1), torch.cat(ys, dim=-1), dtype)
    first, second = both.chunk(2, dim=-1)
    return first + fraction * (second - first)


class TorchPlaneRenderer(nn.Module):
    """The plane scene rendered in torch: batched, on any device, differentiable.

    The textures are buffers, so ``renderer.to(device)`` moves them; images come out in the
    dtype and on the device of the poses.

    Args:
        scene: geometry and textures.
        camera: intrinsics (default: the 320 x 240, 50 degree eye camera).
        filter: ``"linear"`` (default; ``GL_LINEAR``, no mipmaps) or ``"trilinear"`` (mipmaps,
            ``GL_LINEAR_MIPMAP_LINEAR``; what rendering at a coarser ``downsample`` needs).
        lod_bias: added to the level of detail of ``"trilinear"`` (``GL_TEXTURE_LOD_BIAS``).
        samples: lookups per pixel side with ``"trilinear"`` (see :func:`render_planes`).

    Example:
        >>> from aectorch.sim.scene import PlaneScene
        >>> scene = PlaneScene(torch.rand(2, 64, 64), torch.rand(32, 32))
        >>> renderer = TorchPlaneRenderer(scene)
        >>> pose = torch.eye(4)
        >>> pose[:3, :3] = torch.tensor([[0.0, 0, -1], [-1, 0, 0], [0, 1, 0]])  # look along +x
        >>> pose[:3, 3] = torch.tensor([0.03, 0.03, 0.529])
        >>> images = renderer(pose.expand(1, 2, 4, 4), torch.tensor([1.03]), torch.tensor([1]))
        >>> images.shape
        torch.Size([1, 2, 240, 320])
    """

    name = "torch"

    def __init__(self, scene: PlaneScene, camera: PinholeCamera = PinholeCamera(), *,
                 filter: str = "linear", lod_bias: float = 0.0, samples: int = 1) -> None:
        super().__init__()
        if filter not in FILTERS:
            raise ValueError(f"filter must be one of {FILTERS}, got {filter!r}")
        self.scene = scene
        self.camera = camera
        self.filter = filter
        self.lod_bias = float(lod_bias)
        self.samples = check_int(samples, "samples")
        self._rays: dict = {}
        # One copy of all textures plus the background, built once (see render_planes).
        if filter == "linear":
            self.register_buffer("atlas", texture_atlas(scene.textures, scene.background), persistent=False)
        else:
            mip = mipmap_atlas(scene.textures, scene.background)
            self.register_buffer("atlas", mip.packed, persistent=False)
            self.register_buffer("mip_origins", mip.origins, persistent=False)
            self.register_buffer("mip_sizes", mip.sizes, persistent=False)

    def _atlas(self):
        return self.atlas if self.filter == "linear" else MipmapAtlas(self.atlas, self.mip_origins, self.mip_sizes)

    def forward(
        self,
        poses: Tensor,
        plane_x_m: Tensor,
        texture_index: Tensor,
        window: PixelWindow | None = None,
        *,
        check: bool = True,
        downsample: int = 1,
        plane_y_m: Tensor | None = None,
        placement: Placement | None = None,
    ) -> Tensor:
        """Render ``[B, ..., h, w]`` images; see :func:`render_planes` for the arguments."""
        return render_planes(
            poses, plane_x_m, texture_index, self.scene, self.camera, window, atlas=self._atlas(),
            check=check, downsample=downsample, filter=self.filter, lod_bias=self.lod_bias, samples=self.samples,
            plane_y_m=plane_y_m, placement=placement,
        )

    render = forward

    def close(self) -> None:
        """Nothing to free (the `Renderer` interface: pyrender's frees its OpenGL contexts)."""

    def render_windows(self, poses: Tensor, plane_x_m: Tensor, texture_index: Tensor, windows, *,
                       check: bool = True, camera: PinholeCamera | None = None,
                       plane_y_m: Tensor | None = None, placement: Placement | None = None) -> list[Tensor]:
        """Render several windows, each at its own ``downsample``, in one pass.

        Args:
            windows: ``(PixelWindow, downsample)`` pairs (see :func:`pixel_rays`).
            camera: intrinsics of this call (default the renderer's): a magnified eye
                (`aectorch.sim.perturbations`, aniseikonia) is a camera of longer focal length.
            plane_y_m: the object planes' sideways offsets ``[B]`` (see :func:`render_planes`).
            placement: each environment's slant and background (see :func:`render_planes`).

        Returns:
            One ``[B, ..., h // downsample, w // downsample]`` image per window.
        """
        camera = self.camera if camera is None else camera
        windows = tuple((PixelWindow(*w), int(d)) for w, d in windows)
        key = (windows, poses.dtype, poses.device) if camera is self.camera else (windows, camera, poses.dtype,
                                                                                  poses.device)
        rays = None if torch.compiler.is_compiling() else self._rays.get(key)
        if rays is None:
            rays = pixel_rays(camera, windows, dtype=poses.dtype, device=poses.device)
            if not torch.compiler.is_compiling():
                self._rays[key] = rays
        flat = render_rays(poses, plane_x_m, texture_index, self.scene, rays, atlas=self._atlas(), check=check,
                           filter=self.filter, lod_bias=self.lod_bias, samples=self.samples, plane_y_m=plane_y_m,
                           placement=placement)
        shapes = [(w.height // d, w.width // d) for w, d in windows]
        parts = flat.split([h * w for h, w in shapes], dim=-1)
        return [part.reshape(part.shape[:-1] + shape) for part, shape in zip(parts, shapes)]
