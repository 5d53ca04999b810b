"""The plane scene rendered by pyrender (OpenGL through OSMesa on a CPU machine, EGL on a GPU one).

This is the renderer a user would otherwise reach for, and the independent oracle of
:class:`aectorch.sim.render_torch.TorchPlaneRenderer`. One ``OffscreenRenderer`` (one OpenGL context)
is reused for every frame and window size; each texture is uploaded once, as its own quad, the first time an
environment looks at it, and only the current texture's quad is visible during a draw.

Conventions that make the two renderers agree (see ``docs/simulation.md``):

- unlit: ``RenderFlags.FLAT`` and our own material with ``baseColorFactor`` 1.0 (trimesh's
  default material would dim the texture to 40 %), so a pixel equals the sampled texture;
- textures are uploaded as 8-bit RGB (three equal channels); pyrender flips the rows for
  OpenGL, so texture coordinate ``t = 1`` is the image's top row;
- filtering ``GL_LINEAR`` for both magnification and minification (no mipmaps), or with
  ``filter="trilinear"`` ``GL_LINEAR_MIPMAP_LINEAR`` minification over the mipmaps OpenGL builds
  (``glGenerateMipmap``) with ``GL_TEXTURE_LOD_BIAS`` ``lod_bias``; wrap ``GL_CLAMP_TO_EDGE``;
  unpack and pack alignment 1, so any texture or window width works;
- the camera is pyrender's ``IntrinsicsCamera`` with the principal point of
  :class:`~aectorch.sim.camera.PinholeCamera` shifted by the window's offset, so a window renders
  exactly those pixels of the full image.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import torch
from torch import Tensor

from aectorch._checks import check_int
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.scene import Placement, PlaneScene

__all__ = ["PyrenderRenderer", "import_pyrender"]

_PLATFORMS = ("osmesa", "egl")
_OSMESA_HINT = (
    "OSMesa (software OpenGL) is needed to render with pyrender on a machine without a display. "
    "Install it with `sudo apt-get install libosmesa6` (Debian/Ubuntu; `make setup` does this), "
    "or use the torch renderer (env.renderer=torch)."
)


def import_pyrender(platform: str | None = None):
    """Import pyrender for off-screen rendering on ``platform`` ("osmesa" or "egl").

    ``PYOPENGL_PLATFORM`` must be set before PyOpenGL is first imported. ``import aectorch`` sets
    it to ``osmesa`` unless the user did (`aectorch._opengl`); this switches aectorch's default to
    the ``platform`` asked for while OpenGL is not imported yet, and refuses a conflict with the
    user's own value with a message that says what to do. ``None``: the user's value if set, else
    ``osmesa``.
    """
    import sys

    from aectorch import _opengl

    current = os.environ.get("PYOPENGL_PLATFORM")
    ours = _opengl.chosen_by_aectorch()
    if platform is None:
        platform = current if current is not None and not ours else _opengl.DEFAULT_PLATFORM
    if platform not in _PLATFORMS:
        raise ValueError(f"platform must be one of {_PLATFORMS}, got {platform!r}")
    if current != platform:
        if current is not None and not ours:
            raise RuntimeError(
                f"PYOPENGL_PLATFORM is {current!r} but the pyrender renderer was asked for "
                f"{platform!r}; set PYOPENGL_PLATFORM={platform} before starting Python, or ask for "
                f"platform={current!r}"
            )
        if "OpenGL" in sys.modules:
            raise RuntimeError(
                f"PyOpenGL was imported before PYOPENGL_PLATFORM could be set to {platform!r}; set "
                f"PYOPENGL_PLATFORM={platform} in the environment before starting Python"
            )
        _opengl.set_platform(platform)
    try:
        if platform == "egl":
            # pyrender's viewer subclasses pyglet's window at import: without an X server's libraries
            # (a GPU server) pyglet's headless (EGL) windowing is the one that loads.
            import pyglet

            pyglet.options["headless"] = True
        import pyrender  # noqa: F401
        from OpenGL import GL  # noqa: F401
    except (ImportError, OSError, AttributeError) as error:  # pragma: no cover - depends on system
        hint = _OSMESA_HINT if platform == "osmesa" else (
            "EGL needs a GPU driver with libEGL (e.g. NVIDIA's); on a CPU machine use osmesa."
        )
        raise RuntimeError(f"cannot load pyrender on {platform}: {error}. {hint}") from error
    return pyrender


def _quad(pyrender, texture: np.ndarray, size_m: tuple[float, float], filter: str = "linear",
          lod_bias: float = 0.0, cut: tuple[float, float] | None = None):
    """A flat-shaded quad in the plane x = 0 that faces -x, texture column 0 at +y, row 0 at +z
    (``cut``: only its central part, half sides these fractions of the whole, `PlaneScene.object_cut`)."""
    width, height = size_m
    w2, h2 = width / 2.0, height / 2.0
    positions = np.array(
        [[0.0, w2, h2], [0.0, -w2, h2], [0.0, -w2, -h2], [0.0, w2, -h2]], dtype=np.float32
    )
    # pyrender flips the rows on upload: t = 1 is the top row (row 0) of the image.
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]], dtype=np.float32)
    if cut is not None:
        half = np.array([2.0 * cut[0], 2.0 * cut[1]], dtype=np.float32)
        positions[:, 1:] *= half
        uv = (0.5 + (uv - 0.5) * half).astype(np.float32)
    normals = np.tile(np.array([[-1.0, 0.0, 0.0]], dtype=np.float32), (4, 1))
    indices = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32)
    from OpenGL.GL import GL_CLAMP_TO_EDGE, GL_LINEAR, GL_LINEAR_MIPMAP_LINEAR

    sampler = pyrender.Sampler(
        magFilter=GL_LINEAR, minFilter=GL_LINEAR_MIPMAP_LINEAR if filter == "trilinear" else GL_LINEAR,
        wrapS=GL_CLAMP_TO_EDGE, wrapT=GL_CLAMP_TO_EDGE
    )
    rgb = np.ascontiguousarray(np.repeat(texture[:, :, None], 3, axis=2))
    material = pyrender.MetallicRoughnessMaterial(
        baseColorTexture=_texture_class(pyrender)(source=rgb, source_channels="RGB", sampler=sampler,
                                                  lod_bias=lod_bias),
        baseColorFactor=[1.0, 1.0, 1.0, 1.0],
        metallicFactor=0.0,
        roughnessFactor=1.0,
        doubleSided=True,
    )
    primitive = pyrender.Primitive(
        positions=positions, normals=normals, texcoord_0=uv, indices=indices, material=material
    )
    return pyrender.Mesh([primitive])


_TEXTURE_CLASS: dict = {}


def _texture_class(pyrender):
    """pyrender's ``Texture`` that also sets ``GL_TEXTURE_LOD_BIAS`` when it is uploaded."""
    if "class" not in _TEXTURE_CLASS:
        class BiasedTexture(pyrender.Texture):
            def __init__(self, *args, lod_bias: float = 0.0, **kwargs):
                super().__init__(*args, **kwargs)
                self.lod_bias = float(lod_bias)

            def _add_to_context(self):
                super()._add_to_context()
                if self.lod_bias:
                    from OpenGL.GL import GL_TEXTURE_LOD_BIAS, glBindTexture, glTexParameterf

                    glBindTexture(self.tex_type, self._texid)
                    glTexParameterf(self.tex_type, GL_TEXTURE_LOD_BIAS, self.lod_bias)
                    glBindTexture(self.tex_type, 0)

        _TEXTURE_CLASS["class"] = BiasedTexture
    return _TEXTURE_CLASS["class"]


def _stable_program_cache(pyrender, renderer) -> None:
    """Make pyrender reuse its compiled shader programs on OSMesa.

    pyrender keys its program cache by ``OpenGL.contextdata.getContext()``, which on OSMesa is
    a fresh ctypes pointer object at every call; pointers compare by identity, so every draw
    missed the cache and compiled a new program that was never freed: about 0.7 MB and a
    shader compilation per rendered image (24 GB after 400 training iterations at B = 8).
    One :class:`PyrenderRenderer` owns one context, so the context can be left out of the key.
    """
    base = pyrender.shader_program.ShaderProgramCache

    class StableProgramCache(base):  # type: ignore[valid-type,misc]  # pyrender's class, looked up at run time
        def __init__(self, shader_dir=None):
            super().__init__(shader_dir)
            self._stable: dict = {}

        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            key = (vertex_shader, fragment_shader, geometry_shader,
                   tuple(sorted((defines or {}).items())))
            program = self._stable.get(key)
            if program is None:
                program = super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
                self._stable[key] = program
            return program

        def clear(self):
            super().clear()
            self._stable = {}

    inner = renderer._renderer
    old = inner._program_cache
    if not isinstance(old, base) or type(old) is not base:
        return  # a pyrender we do not know: leave it alone
    inner._program_cache = StableProgramCache(old.shader_dir)
    old.clear()


def _to_uint8(image: Tensor) -> np.ndarray:
    return (image.detach().float().clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()


class PyrenderRenderer:
    """The plane scene rendered with pyrender's ``OffscreenRenderer`` (same API as the torch one).

    Args:
        scene: geometry and textures (textures are quantised to 8 bits on upload).
        camera: intrinsics.
        platform: "osmesa" (CPU) or "egl" (GPU machines); ``None`` (default): the user's
            ``PYOPENGL_PLATFORM`` if set, else "osmesa".
        znear, zfar: clipping planes in metres (the background must lie inside).
        filter, lod_bias, samples: as for :class:`~aectorch.sim.render_torch.TorchPlaneRenderer`
            (``"trilinear"`` is OpenGL's own mipmapping; ``samples`` renders each window
            ``samples`` times finer and averages ``samples x samples`` blocks).

    Renders one camera at a time (OpenGL has no batch); images come back as float32 in [0, 1]
    (multiples of 1/255) on the device of the poses.

    Example:
        >>> from aectorch.sim.scene import PlaneScene
        >>> scene = PlaneScene(torch.rand(2, 64, 64), torch.rand(32, 32))
        >>> renderer = PyrenderRenderer(scene)
        >>> pose = torch.eye(4)
        >>> pose[:3, :3] = torch.tensor([[0.0, 0, -1], [-1, 0, 0], [0, 1, 0]])  # look along +x
        >>> pose[:3, 3] = torch.tensor([0.03, 0.03, 0.529])
        >>> renderer(pose.expand(1, 2, 4, 4), torch.tensor([1.03]), torch.tensor([1])).shape
        torch.Size([1, 2, 240, 320])
        >>> renderer.close()
    """

    name = "pyrender"

    def __init__(
        self,
        scene: PlaneScene,
        camera: PinholeCamera = PinholeCamera(),
        *,
        platform: str | None = None,
        znear: float = 0.05,
        zfar: float = 100.0,
        filter: str = "linear",
        lod_bias: float = 0.0,
        samples: int = 1,
    ) -> None:
        if filter not in ("linear", "trilinear"):
            raise ValueError(f"filter must be one of ('linear', 'trilinear'), got {filter!r}")
        self.filter, self.lod_bias, self.samples = filter, float(lod_bias), check_int(samples, "samples")
        if not (0 < znear < zfar):
            raise ValueError(f"need 0 < znear < zfar, got znear={znear!r}, zfar={zfar!r}")
        if scene.background_x_m >= zfar:
            raise ValueError(
                f"zfar ({zfar}) must exceed the background's distance ({scene.background_x_m} m)"
            )
        self._pyrender = import_pyrender(platform)
        self.scene = scene
        self.camera = camera
        self.platform = os.environ["PYOPENGL_PLATFORM"]
        self.znear, self.zfar = float(znear), float(zfar)
        pyrender = self._pyrender
        self._gl_scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0], ambient_light=[1.0, 1.0, 1.0])
        background = _to_uint8(scene.background)
        pose = np.eye(4)
        pose[:3, 3] = [scene.background_x_m, *scene.background_center_yz_m]
        self._background_node = self._gl_scene.add(
            _quad(pyrender, background, scene.background_size_m, filter, self.lod_bias), pose=pose)
        self._texture_nodes: dict[int, Any] = {}  # pyrender Nodes
        self._visible: int | None = None
        self._backgrounds: dict[int, Any] = {}  # the bank's textures as backgrounds (Placement)
        self._visible_background: int | None = None
        self._placed = False  # whether the last call's placement moved the background
        self._camera_node = None
        self._gl_renderer = None
        self._flags = pyrender.RenderFlags.FLAT | pyrender.RenderFlags.SKIP_CULL_FACES

    # -- resources ---------------------------------------------------------------------------
    def _renderer(self, window: PixelWindow):
        # One OpenGL context for everything: pyrender keeps uploaded meshes and textures per
        # context, so a second OffscreenRenderer would not see them. Windows of another size
        # resize its framebuffer (EGL); OSMesa has no framebuffer objects, so its context is
        # made as large as the largest window so far and smaller windows are drawn into its
        # corner (`_draw`): a new context would upload every texture again (rendering the
        # scales' three window sizes through pyrender's own resizing ran at 0.8 iterations/s).
        renderer = self._gl_renderer
        if renderer is None:
            try:
                renderer = self._pyrender.OffscreenRenderer(window.width, window.height)
            except Exception as error:  # pragma: no cover - depends on the system's OpenGL
                raise RuntimeError(
                    f"pyrender could not create an off-screen context on {self.platform}: "
                    f"{error!r}. {_OSMESA_HINT if self.platform == 'osmesa' else ''}"
                ) from error
            self._gl_renderer = renderer
        platform = renderer._platform
        if platform.supports_framebuffers():
            renderer.viewport_width = window.width
            renderer.viewport_height = window.height
        else:
            size = (max(platform.viewport_width, window.width), max(platform.viewport_height, window.height))
            if size != (platform.viewport_width, platform.viewport_height):
                renderer.viewport_width, renderer.viewport_height = size
                renderer.delete()
                renderer._create()
        if not getattr(renderer._renderer, "_aectorch_ready", False):
            from OpenGL.GL import GL_PACK_ALIGNMENT, GL_UNPACK_ALIGNMENT, glPixelStorei

            renderer._platform.make_current()
            # Rows of any width: RGB rows of a width that is not a multiple of 4 bytes would
            # otherwise be read and written with padding.
            glPixelStorei(GL_UNPACK_ALIGNMENT, 1)
            glPixelStorei(GL_PACK_ALIGNMENT, 1)
            _stable_program_cache(self._pyrender, renderer)
            renderer._renderer._aectorch_ready = True
        return renderer

    def _draw(self, renderer, height: int, width: int) -> np.ndarray:
        """One frame of ``height x width`` pixels (RGB, rows from the top)."""
        platform = renderer._platform
        if platform.supports_framebuffers():
            colour, _ = renderer.render(self._gl_scene, flags=self._flags)
            return colour
        # OSMesa: what OffscreenRenderer.render does, without re-creating a context of this size.
        platform.make_current()
        inner = renderer._renderer
        inner.viewport_width, inner.viewport_height = width, height
        inner.render(self._gl_scene, self._flags)
        colour = inner.read_color_buf()
        platform.make_uncurrent()
        return colour

    def _show_texture(self, index: int) -> None:
        if self._visible == index:
            return
        node = self._texture_nodes.get(index)
        if node is None:
            texture = _to_uint8(self.scene.textures[index])
            mesh = _quad(self._pyrender, texture, self.scene.object_size_m, self.filter, self.lod_bias,
                         self.scene.object_cut)
            node = self._gl_scene.add(mesh, pose=np.eye(4))
            self._texture_nodes[index] = node
        if self._visible is not None:
            self._texture_nodes[self._visible].mesh.is_visible = False
        node.mesh.is_visible = True
        self._visible = index

    def _show_background(self, index: int | None, x_m: float) -> None:
        """The background: the scene's own (``index`` None) or texture ``index`` of the bank, at ``x_m``."""
        if index is not None and index not in self._backgrounds:
            mesh = _quad(self._pyrender, _to_uint8(self.scene.textures[index]), self.scene.background_size_m,
                         self.filter, self.lod_bias)
            self._backgrounds[index] = self._gl_scene.add(mesh, pose=np.eye(4))
            mesh.is_visible = False
        if index != self._visible_background:
            old = self._background_node if self._visible_background is None else self._backgrounds[self._visible_background]
            new = self._background_node if index is None else self._backgrounds[index]
            old.mesh.is_visible, new.mesh.is_visible = False, True
            self._visible_background = index
        pose = np.eye(4)
        pose[:3, 3] = [x_m, *self.scene.background_center_yz_m]
        self._gl_scene.set_pose(self._background_node if index is None else self._backgrounds[index], pose)

    def _set_camera(self, intrinsics: tuple[float, float, float, float]) -> None:
        fx, fy, cx, cy = intrinsics
        camera = self._pyrender.IntrinsicsCamera(fx, fy, cx, cy, znear=self.znear, zfar=self.zfar)
        if self._camera_node is not None:
            self._gl_scene.remove_node(self._camera_node)
        self._camera_node = self._gl_scene.add(camera, pose=np.eye(4))

    def close(self) -> None:
        """Free the OpenGL contexts (also done when the renderer is garbage-collected)."""
        if self._gl_renderer is not None:
            self._gl_renderer.delete()
            self._gl_renderer = None

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter exit
        try:
            self.close()
        except Exception:
            pass

    # -- rendering ---------------------------------------------------------------------------
    def __call__(
        self,
        poses: Tensor,
        plane_x_m: Tensor,
        texture_index: Tensor,
        window: PixelWindow | None = None,
        *,
        check: bool = True,
        plane_y_m: Tensor | None = None,
        placement: Placement | None = None,
    ) -> Tensor:
        """Render ``[B, ..., h, w]`` images; the arguments are those of :func:`render_planes`.

        ``check`` is accepted for symmetry with the torch renderer; the indices are always
        checked, since they go to the host anyway.
        """
        window = self.camera.check_window(window)
        return self.render_windows(poses, plane_x_m, texture_index, [(window, 1)], plane_y_m=plane_y_m,
                                   placement=placement)[0]

    render = __call__

    def render_windows(self, poses: Tensor, plane_x_m: Tensor, texture_index: Tensor, windows, *,
                       check: bool = True, camera: PinholeCamera | None = None,
                       plane_y_m: Tensor | None = None, placement: Placement | None = None) -> list[Tensor]:
        """Render several windows, each on its own pixel grid; see ``TorchPlaneRenderer.render_windows``
        (``camera``: this call's intrinsics, default the renderer's; ``plane_y_m``: the object
        planes' sideways offsets ``[B]``, a moving object; ``placement``: each environment's slant and
        background, `aectorch.sim.scene.Placement`).

        A window at ``downsample`` d is drawn by a camera whose pixels are ``d / samples`` of this
        one's (``samples x samples`` of them then averaged per pixel).
        """
        camera = self.camera if camera is None else camera
        batch = self.scene.check_render_inputs(poses, plane_x_m, texture_index, plane_y_m=plane_y_m)
        index = texture_index.cpu().tolist()
        flat_poses = poses.detach().reshape(batch, -1, 4, 4).to("cpu", torch.float64).numpy()
        planes = plane_x_m.detach().to("cpu", torch.float64).numpy()
        sideways = np.zeros(batch) if plane_y_m is None else plane_y_m.detach().to("cpu", torch.float64).numpy()
        if placement is not None:
            placement.check(batch, self.scene.num_textures)
        place = Placement() if placement is None else placement
        if placement is None and self._placed:  # the scene's own background, where it stands
            self._show_background(None, self.scene.background_x_m)
        self._placed = placement is not None
        host = lambda t, kind=torch.float64: None if t is None else t.detach().to("cpu", kind).tolist()  # noqa: E731
        slants, behind_x, behind = host(place.slant_rad), host(place.background_x_m), host(place.background_index,
                                                                                          torch.int64)
        f = camera.focal_px
        pcx, pcy = camera.principal_point
        results = []
        for window, downsample in windows:
            top, left, h, w = camera.check_window(window)
            if h % downsample or w % downsample:
                raise ValueError(f"the window's sides {h} x {w} must be multiples of downsample={downsample}")
            factor = self.samples / downsample
            height, width = round(h * factor), round(w * factor)
            renderer = self._renderer(PixelWindow(0, 0, height, width))
            self._set_camera((f * factor, f * factor, (pcx - left) * factor, (pcy - top) * factor))
            out = np.empty((batch, flat_poses.shape[1], height, width), dtype=np.uint8)
            y, z = self.scene.object_center_yz_m
            for b in range(batch):
                self._show_texture(index[b])
                node = self._texture_nodes[index[b]]
                pose = np.eye(4)
                pose[:3, 3] = [planes[b], y + sideways[b], z]
                if slants is not None:  # turned about the vertical through the pivot, the centre along it
                    c, s = np.cos(slants[b]), np.sin(slants[b])
                    pose[:2, :2] = [[c, -s], [s, c]]
                    pose[:3, 3] = [planes[b] - s * sideways[b], y + c * sideways[b], z]
                self._gl_scene.set_pose(node, pose)
                if placement is not None:
                    self._show_background(None if behind is None else behind[b],
                                          self.scene.background_x_m if behind_x is None else behind_x[b])
                for c in range(flat_poses.shape[1]):
                    self._gl_scene.set_pose(self._camera_node, flat_poses[b, c])
                    out[b, c] = self._draw(renderer, height, width)[:, :, 0]
            images = torch.from_numpy(out).to(torch.float32).div_(255.0)
            if self.samples > 1:
                images = torch.nn.functional.avg_pool2d(images, self.samples)
            images = images.reshape(poses.shape[:-2] + images.shape[-2:])
            results.append(images.to(poses.device))
        return results
