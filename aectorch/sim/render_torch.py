"""Exact, batched, differentiable rendering of the plane scene in torch (ray-plane homography).

Every pixel's ray (through its centre, see :mod:`aectorch.sim.camera`) is intersected with the
object plane ``x = plane_x_m`` and with the background plane; the hit point's texture coordinate
is sampled bilinearly with clamp-to-edge, exactly as OpenGL samples a ``GL_LINEAR`` texture with
``GL_CLAMP_TO_EDGE`` wrap (texel ``i`` centred at ``i + 0.5``, no mipmaps). For a plane the map
from pixel to texture coordinate is a homography; computing it through the ray keeps the code
batched over any camera pose and lets a window of the image (the coder's central crops) be
rendered without the rest.

Textures are sampled by index arithmetic from one flat tensor of all textures, so each
environment can look at its own texture without copying textures per environment, and the
result is differentiable in the poses, the plane distances and the texture values.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.scene import PlaneScene

__all__ = ["TorchPlaneRenderer", "render_planes", "sample_bilinear", "texture_atlas"]


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


def texture_atlas(textures: Tensor, background: Tensor) -> Tensor:
    """Stack the object textures and the background (same size) into one ``[N + 1, H, W]`` atlas."""
    if background.shape != textures.shape[-2:]:
        raise ValueError(
            f"background must have the textures' size {tuple(textures.shape[-2:])}, got "
            f"{tuple(background.shape)} (PlaneScene resamples it)"
        )
    return torch.cat((textures, background.to(textures).unsqueeze(0)))


def _plane_coords(o, ry, rz, plane_x, center_yz, size_m):
    """Normalised plane coordinates (0..1 from the left / top edge) of rays ``(1, ry, rz)``."""
    reach = plane_x - o[..., 0]  # along x from the eye to the plane, [B, C, 1, 1]
    width, height = size_m
    u = (center_yz[0] + 0.5 * width - o[..., 1]) / width - (reach / width) * ry
    v = (center_yz[1] + 0.5 * height - o[..., 2]) / height - (reach / height) * rz
    hit = (reach > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    return u, v, hit


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
    atlas: Tensor | None = None,
    check: bool = True,
) -> Tensor:
    """Render grey images of the plane scene for a batch of cameras.

    For each camera the pixel -> plane map is a homography: with the ray direction
    ``(dx, dy, dz)`` of a pixel (linear in the pixel's position), the plane ``x = X`` is hit at
    ``y = oy + (X - ox) dy / dx``, ``z = oz + (X - ox) dz / dx``. Both planes share the ratios
    ``dy / dx`` and ``dz / dx``; each pixel then reads the object plane where it hits it, else
    the background, with one bilinear ``grid_sample`` over an atlas of all textures (clamped to
    each texture's edge texel centres, which is ``GL_CLAMP_TO_EDGE``).

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
        atlas: a prebuilt :func:`texture_atlas` (what :class:`TorchPlaneRenderer` passes).
        check: check that every texture index is in range (one host sync). An index out of
            range would otherwise read a neighbouring texture of the atlas without an error.

    Returns:
        Intensities in [0, 1]; the object plane occludes the background; pixels whose ray hits
        neither plane are 0. Dtype and device of ``poses``.

    Shape:
        output: ``[B, ..., window.height, window.width]``.
    """
    batch = scene.check_render_inputs(poses, plane_x_m, texture_index, check_range=check)
    window = camera.check_window(window)
    dtype, device = poses.dtype, poses.device
    if atlas is None:
        atlas = texture_atlas(
            scene.textures if textures is None else textures,
            scene.background if background is None else background,
        )
    atlas = atlas.to(dtype=dtype, device=device)
    layers, tex_h, tex_w = atlas.shape

    middle = poses.shape[1:-2]
    flat = poses.reshape(batch, -1, 4, 4)
    o = flat[:, :, :3, 3][:, :, None, None, :]  # [B, C, 1, 1, 3]
    rot = flat[:, :, :3, :3, None, None]  # [B, C, 3, 3, 1, 1]
    cx, cy = camera.principal_point
    f = camera.focal_px
    top, left, h, w = window
    xs = (torch.arange(left, left + w, dtype=dtype, device=device) + 0.5 - cx) / f  # [w]
    ys = (torch.arange(top, top + h, dtype=dtype, device=device) + 0.5 - cy) / f  # [h]
    ys = ys[:, None]
    # The ray (xs, ys, 1) in the ROS optical frame is (xs, -ys, -1) in the OpenGL camera frame.
    d = [rot[:, :, i, 0] * xs - (rot[:, :, i, 1] * ys + rot[:, :, i, 2]) for i in range(3)]
    ahead = d[0] > 1e-12
    inv = 1.0 / torch.where(ahead, d[0], torch.ones_like(d[0]))
    ry, rz = d[1] * inv, d[2] * inv  # [B, C, h, w]

    plane_x = plane_x_m.to(dtype)[:, None, None, None]
    u, v, on_object = _plane_coords(o, ry, rz, plane_x, scene.object_center_yz_m, scene.object_size_m)
    ub, vb, on_background = _plane_coords(
        o, ry, rz, torch.full_like(plane_x, scene.background_x_m),
        scene.background_center_yz_m, scene.background_size_m,
    )
    on_object = on_object & ahead
    seen = on_object | (on_background & ahead)
    u = torch.where(on_object, u, ub)
    v = torch.where(on_object, v, vb)
    # Continuous texel coordinates clamped to the edge texels' centres (GL_CLAMP_TO_EDGE).
    u = (u * tex_w).clamp_(0.5, tex_w - 0.5)
    v = (v * tex_h).clamp_(0.5, tex_h - 0.5)
    index = texture_index.reshape(-1, 1, 1, 1)
    if dtype == torch.float64 or layers * tex_h <= _ATLAS_ROWS_FLOAT32:
        # The atlas row of each sample: object texture or background (the last layer).
        layer = torch.where(on_object, index.to(dtype), float(layers - 1))
        if torch.compiler.is_compiling() or (torch.is_grad_enabled() and (u.requires_grad or v.requires_grad)):
            # (compiled: inductor fuses the stack; the in-place writes below do not trace)
            gx = u * (2.0 / tex_w) - 1.0
            gy = (layer * tex_h + v) * (2.0 / (layers * tex_h)) - 1.0
            grid = torch.stack((gx, gy), dim=-1)
        else:  # the same, written in place into the grid (saves a copy of every coordinate)
            grid = torch.empty(u.shape + (2,), dtype=dtype, device=device)
            torch.mul(u, 2.0 / tex_w, out=grid[..., 0]).sub_(1.0)
            torch.add(v, layer, alpha=tex_h, out=grid[..., 1])
            grid[..., 1].mul_(2.0 / (layers * tex_h)).sub_(1.0)
        image = torch.nn.functional.grid_sample(
            atlas.reshape(1, 1, layers * tex_h, tex_w), grid.reshape(1, -1, w, 2), mode="bilinear",
            padding_mode="border", align_corners=False,
        ).reshape(u.shape)
    else:
        layer = torch.where(on_object, index, layers - 1)
        image = sample_bilinear(atlas, layer, u, v)
    image = torch.where(seen, image, torch.zeros_like(image))
    return image.reshape((batch, *middle, h, w))


class TorchPlaneRenderer(nn.Module):
    """The plane scene rendered in torch: batched, on any device, differentiable.

    The textures are buffers, so ``renderer.to(device)`` moves them; images come out in the
    dtype and on the device of the poses.

    Args:
        scene: geometry and textures.
        camera: intrinsics (default: the 320 x 240, 50 degree eye camera).

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

    def __init__(self, scene: PlaneScene, camera: PinholeCamera = PinholeCamera()) -> None:
        super().__init__()
        self.scene = scene
        self.camera = camera
        # One copy of all textures plus the background, built once (see render_planes).
        self.register_buffer("atlas", texture_atlas(scene.textures, scene.background), persistent=False)

    def forward(
        self,
        poses: Tensor,
        plane_x_m: Tensor,
        texture_index: Tensor,
        window: PixelWindow | None = None,
        *,
        check: bool = True,
    ) -> Tensor:
        """Render ``[B, ..., h, w]`` images; see :func:`render_planes` for the arguments."""
        return render_planes(
            poses, plane_x_m, texture_index, self.scene, self.camera, window, atlas=self.atlas,
            check=check,
        )

    render = forward
