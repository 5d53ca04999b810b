"""What the eyes of an `ActiveDepthEnv` see: the renderers' calls, the foveal scales and the cached frames.

`EyeImages` renders the eyes' images for the movements' observations (`aectorch.sim.movements`):
at a body shift, pans and roll, through the eyes' optics (`aectorch.sim.perturbations.Optics`),
of the whole window or of each foveal scale at its own resolution (:data:`SCALE_FILTER`, then
:func:`pyramid_blur`). It keeps the fixation's first image of the left eye (with the roll and the
optics it was taken with) and the left eye's last frame, reused while the left eye's view has not
changed (:meth:`EyeImages.moved`).

Example:
    >>> pyramid_blur(torch.ones(1, 6, 6), 1).shape  # one pixel of margin on every side used
    torch.Size([1, 4, 4])
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch
from torch import Tensor

from aectorch.choices import RendererName
from aectorch.ops.backend import fused_kernels_apply
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.perturbations import (NEUTRAL, Optics, blur_margin, defocus, defocus_each, orientation_filter,
                                        scale_contrast)
from aectorch.sim.scene import PlaneScene


__all__ = ["EyeImages", "RENDERERS", "SCALE_FILTER", "WINDOW", "check_window", "make_renderer", "pyramid_blur"]

#: The key of an observation's whole rendered window, ``[B, 2, H, W]``, beside the scales' entries
#: ``{scale name: [B, 2, side, side]}``. The coder reads the same key (``aectorch.coding.WINDOW``;
#: the two packages stand side by side and do not import each other; tests/sim/test_sim.py checks
#: that they agree).
WINDOW = "window"
#: Renderer names accepted by ``renderer=``.
RENDERERS = RendererName.values()

#: How :meth:`ActiveDepthEnv.parallax_observation` and ``stereo_observation`` render the foveal
#: scales they are asked for: mipmapped textures (``GL_LINEAR_MIPMAP_LINEAR``), 2 x 2 lookups per
#: pixel at a level of detail biased by -0.5: within 0.5 % of the exact area average
#: (docs/simulation.md, tests/sim/test_sim.py).
SCALE_FILTER = dict(filter="trilinear", lod_bias=-0.5, samples=2)


def _finer(downsample: int) -> int:
    """Scales reduced 16x or more (a few pixels, each many texels wide) render 2x finer and average:
    4 x 4 lookups per pixel, which the widest scale needs on photographs to stay within 0.5 %."""
    return 2 if downsample >= 16 else 1


def pyramid_blur(images: Tensor, levels: int) -> Tensor:
    """The rest of a Gaussian pyramid's blur for an area-filtered image: ``[..., h + 2, w + 2] -> [..., h, w]``.

    An image rendered at a scale's resolution is (within 0.5 %) the area average over each pixel:
    a box of variance 1/12 pixel^2 per axis. ``levels`` reductions of the centred pyramid
    (:func:`aectorch.coding.patches.pyramid_down`, each level a binomial of variance 5/4 of its
    input pixels) blur with variance ``5/4 (4^L - 1) / 3`` full pixels^2, i.e.
    ``5/12 (1 - 4^-L)`` reduced pixels^2. This adds the difference with the 3-tap kernel
    ``[a, 1 - 2a, a]`` per axis (variance ``2a``), over the valid region only (the caller renders
    one extra pixel on every side), so the coder's input has the pyramid's smoothness: without
    it the vergence learned on box-filtered images was twice as coarse (docs/simulation.md).
    """
    if levels == 0:
        return images[..., 1:-1, 1:-1]
    a = (5.0 / 12.0 * (1.0 - 4.0 ** -levels) - 1.0 / 12.0) / 2.0
    if _native_blur(images):
        # On CPU without a gradient: one fused kernel (``aectorch::pyramid_blur``, render_cpu.cpp),
        # the same operations as below and so the same bits, instead of eight small torch
        # operations (and six slices).
        flat = images.reshape(-1, *images.shape[-2:])
        blurred = torch.ops.aectorch.pyramid_blur(flat, 1.0 - 2.0 * a, a)
        return blurred.reshape(*images.shape[:-2], *blurred.shape[-2:])
    # (sums of shifted slices: on these few-pixel images conv2d's set-up costs more than the work)
    x = images[..., 1:-1] * (1.0 - 2.0 * a) + (images[..., :-2] + images[..., 2:]) * a
    return x[..., 1:-1, :] * (1.0 - 2.0 * a) + (x[..., :-2, :] + x[..., 2:, :]) * a


def _native_blur(images: Tensor) -> bool:
    """Whether `pyramid_blur` runs as the fused CPU kernel: where the coder's kernels apply
    (`aectorch.ops.fused_kernels_apply`: a CPU float tensor, the kernels loaded, no
    ``use_backend("torch")``), on images of at least 3 x 3 pixels, and no gradient is wanted."""
    return images.ndim >= 2 and min(images.shape[-2:]) >= 3 and images.numel() > 0 \
        and not (torch.is_grad_enabled() and images.requires_grad) and fused_kernels_apply(images)


def check_window(camera: PinholeCamera, window: str | PixelWindow) -> PixelWindow:
    """``ActiveDepthEnv``'s ``window``: ``"crops"`` (the central 128 x 128), ``"full"`` or a window, checked."""
    if window == "crops":
        window = camera.central_window(128)
    elif window == "full":
        window = camera.full_window
    elif isinstance(window, str):
        raise ValueError(f"window must be 'crops', 'full' or a PixelWindow, got {window!r}")
    return camera.check_window(window)


def _defocus(images: Tensor, radius_px) -> Tensor:
    """`defocus` by one disc (a number), or each environment's image by its own (a tensor ``[B]``)."""
    return defocus_each(images, radius_px) if isinstance(radius_px, Tensor) else defocus(images, radius_px)


def _elevated(poses: Tensor, elevation_deg: tuple[float, float]) -> Tensor:
    """OpenGL camera-to-world ``poses`` ``[B, 2, 4, 4]`` with each eye turned up by its
    ``elevation_deg`` about the camera's own x axis (x right, y up, looking along -z):
    a vertical misalignment."""
    angle = torch.deg2rad(torch.tensor(elevation_deg, dtype=poses.dtype, device=poses.device))
    c, s = torch.cos(angle), torch.sin(angle)
    turn = torch.eye(4, dtype=poses.dtype, device=poses.device).repeat(2, 1, 1)
    turn[:, 1, 1], turn[:, 1, 2], turn[:, 2, 1], turn[:, 2, 2] = c, -s, s, c
    return poses @ turn


def _sideways(plane_y_m: Tensor | None) -> dict:
    """The renderers' ``plane_y_m`` argument where the object moved sideways (none otherwise: a
    renderer of the still object is called as it always was)."""
    return {} if plane_y_m is None else {"plane_y_m": plane_y_m}


def _block_mean(images: Tensor, k: int) -> Tensor:
    if k == 1:
        return images
    pooled = torch.nn.functional.avg_pool2d(images.flatten(0, -3).unsqueeze(1), k)
    return pooled.reshape(images.shape[:-2] + pooled.shape[-2:])


def make_renderer(name: str, scene: PlaneScene, camera: PinholeCamera, *, device=None, dtype=None, **kwargs):
    """Build a renderer by name: ``"torch"`` (:class:`TorchPlaneRenderer`) or ``"pyrender"``.

    ``filter``, ``lod_bias`` and ``samples`` go to either renderer; other keyword arguments to
    pyrender's. The torch renderer's textures are moved to ``device`` and ``dtype`` once (it
    renders in the poses' dtype, and would otherwise convert them at every call).
    """
    if name == "torch":
        from aectorch.sim.render_torch import TorchPlaneRenderer

        filtering = {k: kwargs.pop(k) for k in ("filter", "lod_bias", "samples") if k in kwargs}
        return TorchPlaneRenderer(scene, camera, **filtering).to(device=device, dtype=dtype)
    if name == "pyrender":
        from aectorch.sim.render_pyrender import PyrenderRenderer

        return PyrenderRenderer(scene, camera, **kwargs)
    raise ValueError(f"renderer must be one of {RENDERERS}, got {name!r}")


def _margin_window(camera: PinholeCamera, size: int, margin: int, what: str) -> PixelWindow:
    """The central ``size`` crop with ``margin`` more pixels on every side, for a blur."""
    if size + 2 * margin > min(camera.height, camera.width):
        raise ValueError(f"the blur of anisometropia ({what}) needs {margin} px beyond the {size} px crop on "
                         f"every side, more than the {camera.height} x {camera.width} image holds; use a smaller "
                         "blur disc")
    return camera.central_window(size + 2 * margin)


class EyeImages:
    """The eyes' images of ``env`` (an `ActiveDepthEnv`, whose renderer, head, optics and object
    it reads), and the frames it keeps: the fixation's first left image and the left eye's last."""

    def __init__(self, env: Any) -> None:
        self.env = env
        self.scale_renderer = None  # built on the first request for foveal scales
        self.last_left: tuple | None = None  # (view version, scales, left image) of the last stereo frame
        self.view = 0  # the left eye's view version: moved() counts its changes
        self.start_fixation()

    def start_fixation(self) -> None:
        """A new fixation: its first image is taken (and its roll and optics kept) when next asked for."""
        self.first_image: dict = {}
        self.first_roll: Tensor | None = None
        self.first_optics: Optics | None = None

    def moved(self) -> None:
        """The left eye's view changed (pan, roll or body): a stereo frame can no longer be reused."""
        self.view += 1

    def rebuild_world(self, bands) -> None:
        """The world's textures filtered to the orientation ``bands`` (none: as built;
        `ActiveDepthEnv.set_optics`): the renderers are built anew, every kept frame rendered again."""
        env = self.env
        world = env.built_scene
        if bands:
            world = replace(world, textures=orientation_filter(world.textures, bands),
                            background=orientation_filter(world.background, bands))
        env.close()
        env.scene = world
        env.renderer = make_renderer(env.renderer_name, world, env.camera, device=env.device, dtype=env.dtype,
                                     **env.renderer_options)
        self.scale_renderer = None
        self.first_image = {}  # what the eye saw of the old world is rendered again in the new one
        self.last_left = None

    @staticmethod
    def key(scales, window: bool):
        return None if scales is None else tuple(scales), bool(window)

    def render(self, shift_m: Tensor, pans: Tensor, eyes: slice, roll_deg: Tensor | None = None,
               scales=None, window: bool = False, optics: Optics | None = None,
               plane: tuple[Tensor, Tensor | None] | None = None) -> dict[str, Tensor]:
        """The eyes' images at ``shift_m`` and ``pans``, the object plane at ``plane`` (its x and
        sideways offset; default where it is now)."""
        env = self.env
        plane_x, plane_y = (env.plane_x_m, env.motion.plane_y_m) if plane is None else plane
        roll = env.roll_deg if roll_deg is None else roll_deg
        optics = env.optics if optics is None else optics
        if optics.pan_offset_deg != NEUTRAL.pan_offset_deg:
            pans = pans + torch.tensor(optics.pan_offset_deg, dtype=pans.dtype, device=pans.device)
        poses = env.head.camera_poses(shift_m, pans, roll, convention="opengl")
        if optics.elevation_offset_deg != NEUTRAL.elevation_offset_deg:
            poses = _elevated(poses, optics.elevation_offset_deg)
        if optics.shift_m != NEUTRAL.shift_m:  # the robot's frame is the world's moved by the body shift
            poses = poses.clone()
            poses[..., :3, 3] += torch.tensor(optics.shift_m, dtype=poses.dtype, device=poses.device)
        poses = poses[:, eyes]
        indices = tuple(range(*eyes.indices(2)))
        world = env.eye_optics.world_blur_arcmin(optics)
        if world is not None or not optics.images_neutral(indices):
            return self._render_optics(poses, indices, optics, scales, window, plane_x, plane_y, world)
        out = {}
        # The indices were checked by set_trial: no host sync per frame.
        if scales is None or window:
            out[WINDOW] = env.renderer(poses, plane_x, env.texture_index, env.window, check=False,
                                       **_sideways(plane_y), **env.layout_draws.placement()).to(env.dtype)
        if scales is None:
            return out
        # Each scale's crop with one more of its pixels on every side, for the blur.
        finer = [_finer(s.downsample) for s in scales]
        windows = [(env.camera.central_window(s.crop + 2 * s.downsample), s.downsample // k)
                   for s, k in zip(scales, finer)]
        images = self.scale_renderer_built().render_windows(poses, plane_x, env.texture_index, windows,
                                                            check=False, **_sideways(plane_y),
                                                            **env.layout_draws.placement())
        for s, image, k in zip(scales, images, finer):
            out[s.name] = pyramid_blur(_block_mean(image, k), s.levels).to(env.dtype)
        return out

    def scale_renderer_built(self):
        """The renderer of the foveal scales (:data:`SCALE_FILTER`), built on first use."""
        if self.scale_renderer is None:
            env = self.env
            self.scale_renderer = make_renderer(env.renderer_name, env.scene, env.camera, device=env.device,
                                                dtype=env.dtype, **{**env.renderer_options, **SCALE_FILTER})
        return self.scale_renderer

    def _render_optics(self, poses: Tensor, eyes: tuple[int, ...], optics: Optics, scales, window: bool,
                       plane_x: Tensor, plane_y: Tensor | None, world_arcmin: Tensor | None = None):
        """`render` of eyes with perturbed images, one eye at a time: each through its own camera
        (magnified: aniseikonia), rendered with the margin its blur disc needs (anisometropia, and
        the world's defocus ``world_arcmin`` ``[B, 2]``, each environment's disc diameter added to
        the eye's), blurred, then its contrast scaled about each image's mean (monocular deprivation)."""
        env, per_eye = self.env, []
        for j, eye in enumerate(eyes):
            camera = env.camera.magnified(optics.magnification[eye])
            arcmin_per_px = 60.0 * camera.degrees_per_pixel
            radius: float | Tensor = optics.blur_arcmin[eye] / 2.0 / arcmin_per_px  # full-resolution px of this eye
            if world_arcmin is not None:  # the world's defocus too: a disc per environment
                radius = (optics.blur_arcmin[eye] + world_arcmin[:, eye]) / 2.0 / arcmin_per_px
            largest = float(radius.max()) if isinstance(radius, Tensor) else radius
            pose, out = poses[:, j:j + 1], {}
            if scales is None or window:
                margin = blur_margin(largest)
                top, left, h, w = env.window
                grown = PixelWindow(top - margin, left - margin, h + 2 * margin, w + 2 * margin)
                if margin and (h + 2 * margin > camera.height or w + 2 * margin > camera.width
                               or top < margin or left < margin):
                    raise ValueError(f"the blur of anisometropia ({optics.blur_arcmin[eye]:g} arcmin) needs {margin} "
                                     "px beyond the rendered window, which the image does not hold")
                image = env.renderer.render_windows(pose, plane_x, env.texture_index, [(grown, 1)], check=False,
                                                    camera=camera, **_sideways(plane_y),
                                                    **env.layout_draws.placement())[0]
                out[WINDOW] = _defocus(image, radius).to(env.dtype)
            if scales is not None:
                finer = [_finer(s.downsample) for s in scales]
                margins = [blur_margin(largest / s.downsample) for s in scales]
                windows = [(_margin_window(camera, s.crop + 2 * s.downsample, s.downsample * m,
                                           f"{optics.blur_arcmin[eye]:g} arcmin at the {s.name} scale"),
                            s.downsample // k) for s, k, m in zip(scales, finer, margins)]
                images = self.scale_renderer_built().render_windows(pose, plane_x, env.texture_index,
                                                                    windows, check=False, camera=camera,
                                                                    **_sideways(plane_y),
                                                                    **env.layout_draws.placement())
                for s, image, k in zip(scales, images, finer):
                    image = _defocus(_block_mean(image, k), radius / s.downsample)
                    out[s.name] = pyramid_blur(image, s.levels).to(env.dtype)
            if optics.contrast[eye] != 1:
                out = {name: scale_contrast(image, optics.contrast[eye]) for name, image in out.items()}
            per_eye.append(out)
        return {name: torch.cat([out[name] for out in per_eye], dim=1) for name in per_eye[0]}

    def first_left(self, key, scales, window: bool) -> dict[str, Tensor]:
        """The left eye's image at the fixation's start (its start pan, roll, optics and object
        place), rendered once per fixation and kept."""
        first = self.first_image.get(key)
        if first is None:
            env = self.env
            zero = torch.zeros_like(env.body_shift_m)
            if self.first_roll is None:  # the roll and optics when the fixation's first image was taken
                self.first_roll = env.roll_deg.clone()
            if self.first_optics is None:
                self.first_optics = env.optics
            # (the world's textures are always today's: a change of them rendered it again)
            first = self.render(zero, env._start_pans, slice(0, 1), self.first_roll, scales, window,
                                optics=replace(self.first_optics, orientation_bands=env.optics.orientation_bands),
                                plane=env.motion.start_plane if env.moving else None)
            self.first_image[key] = first
        return first

    def current_left(self, key, scales, window: bool) -> dict[str, Tensor]:
        """The left eye's image now: the last one rendered when the eye has not moved since."""
        cached = self.last_left
        if cached is not None and cached[0] == self.view and cached[1] == key:
            return cached[2]
        env = self.env
        second = self.render(env.body_shift_m, env.pan_deg, slice(0, 1), scales=scales, window=window)
        self.last_left = (self.view, key, second)
        return second

    def stereo(self, scales, window: bool) -> dict[str, Tensor]:
        """Both eyes at the shifted position; the left image kept as the left eye's last frame."""
        env = self.env
        pair = self.render(env.body_shift_m, env.pan_deg, slice(0, 2), scales=scales, window=window)
        self.last_left = (self.view, self.key(scales, window), {name: p[:, :1] for name, p in pair.items()})
        return pair

    def close(self) -> None:
        """Free the scale renderer's resources."""
        if self.scale_renderer is not None:
            self.scale_renderer.close()
