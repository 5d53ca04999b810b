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

__all__ = ["TorchPlaneRenderer", "render_planes", "sample_bilinear"]


def sample_bilinear(
    textures: Tensor, texture_index: Tensor, u: Tensor, v: Tensor
) -> Tensor:
    """Sample textures bilinearly with clamp-to-edge at continuous texel coordinates.

    Args:
        textures: ``[N, H, W]``.
        texture_index: which texture each leading row of ``u`` reads, ``[B]`` (int64).
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
    base = (texture_index.long() * (h * w)).reshape((-1,) + (1,) * (u.ndim - 1))
    row0 = base + y0i * w
    row1 = base + y1i * w
    a = flat[row0 + x0i]
    b = flat[row0 + x1i]
    c = flat[row1 + x0i]
    d = flat[row1 + x1i]
    top = a + wx * (b - a)
    bottom = c + wx * (d - c)
    return top + wy * (bottom - top)


def _plane_texel_coords(
    origin: Tensor,
    direction: Tensor,
    plane_x: Tensor,
    center_yz: tuple[float, float],
    size_m: tuple[float, float],
    texture_hw: tuple[int, int],
) -> tuple[Tensor, Tensor, Tensor]:
    """Texel coordinates ``(u, v)`` where rays hit the plane ``x = plane_x`` and whether they do."""
    dx = direction[..., 0]
    ahead = dx > 1e-12
    t = (plane_x - origin[..., 0]) / torch.where(ahead, dx, torch.ones_like(dx))
    y = origin[..., 1] + t * direction[..., 1]
    z = origin[..., 2] + t * direction[..., 2]
    width, height = size_m
    th, tw = texture_hw
    u = (center_yz[0] + 0.5 * width - y) * (tw / width)
    v = (center_yz[1] + 0.5 * height - z) * (th / height)
    hit = ahead & (t > 0) & (u >= 0) & (u <= tw) & (v >= 0) & (v <= th)
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
) -> Tensor:
    """Render grey images of the plane scene for a batch of cameras.

    Args:
        poses: camera-to-world transforms in the OpenGL camera convention (x right, y up, looking
            along -z), ``[B, ..., 4, 4]`` (for example ``[B, 2, 4, 4]`` for both eyes).
        plane_x_m: world x of each environment's object plane, ``[B]``.
        texture_index: each environment's object texture (index into ``scene.textures``), ``[B]``.
        scene: the planes' geometry and textures.
        camera: intrinsics.
        window: the pixels to render (``None`` = the whole image).
        textures: override ``scene.textures`` (same shape), e.g. to differentiate with respect to
            them or to use a copy on another device.
        background: override ``scene.background``.

    Returns:
        Intensities in [0, 1]; the object plane occludes the background; pixels whose ray hits
        neither plane are 0. Dtype and device of ``poses``.

    Shape:
        output: ``[B, ..., window.height, window.width]``.
    """
    if poses.ndim < 3 or poses.shape[-2:] != (4, 4):
        raise ValueError(f"poses must have shape [B, ..., 4, 4], got {tuple(poses.shape)}")
    batch = poses.shape[0]
    if plane_x_m.shape != (batch,):
        raise ValueError(
            f"plane_x_m must have shape [B] = [{batch}] (the batch of poses), "
            f"got {tuple(plane_x_m.shape)}"
        )
    scene.check_texture_index(texture_index, batch)
    window = camera.check_window(window)
    dtype, device = poses.dtype, poses.device
    textures = scene.textures if textures is None else textures
    background = scene.background if background is None else background
    textures = textures.to(dtype=dtype, device=device)
    background = background.to(dtype=dtype, device=device)

    middle = poses.shape[1:-2]
    flat_poses = poses.reshape(batch, -1, 4, 4)  # [B, C, 4, 4]
    rays = camera.rays(window, dtype=dtype, device=device)  # ROS: x right, y down, z forward
    # ROS -> OpenGL camera axes: (x, y, z) -> (x, -y, -z); then rotate into the world.
    rays_gl = rays * torch.tensor([1.0, -1.0, -1.0], dtype=dtype, device=device)
    rotation = flat_poses[..., :3, :3]
    direction = torch.einsum("bcij,hwj->bchwi", rotation, rays_gl)  # [B, C, h, w, 3]
    origin = flat_poses[..., :3, 3][:, :, None, None, :]  # [B, C, 1, 1, 3]

    plane_x = plane_x_m.to(dtype)[:, None, None, None]
    u, v, on_object = _plane_texel_coords(
        origin, direction, plane_x, scene.object_center_yz_m, scene.object_size_m,
        tuple(textures.shape[-2:]),
    )
    colour = sample_bilinear(textures, texture_index, u, v)
    ub, vb, on_background = _plane_texel_coords(
        origin, direction, torch.full_like(plane_x, scene.background_x_m),
        scene.background_center_yz_m, scene.background_size_m, tuple(background.shape[-2:]),
    )
    zero_index = torch.zeros_like(texture_index)
    behind = sample_bilinear(background.unsqueeze(0), zero_index, ub, vb)
    image = torch.where(on_object, colour, torch.where(on_background, behind, torch.zeros_like(behind)))
    return image.reshape((batch, *middle, window.height, window.width))


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
        self.register_buffer("textures", scene.textures, persistent=False)
        self.register_buffer("background", scene.background, persistent=False)

    def forward(
        self,
        poses: Tensor,
        plane_x_m: Tensor,
        texture_index: Tensor,
        window: PixelWindow | None = None,
    ) -> Tensor:
        """Render ``[B, ..., h, w]`` images; see :func:`render_planes` for the arguments."""
        return render_planes(
            poses, plane_x_m, texture_index, self.scene, self.camera, window,
            textures=self.textures, background=self.background,
        )

    render = forward
