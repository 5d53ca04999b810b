"""The simulated world: HOAP-3 eye kinematics, textures, plane renderers, ActiveDepthEnv.

``sim`` knows nothing about learning: it renders what the eyes see and reports the ground truth.
pyrender (and with it PyOpenGL) is imported only when a :class:`PyrenderRenderer` is built.
"""

from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.env import (
    DEFAULT_DISTANCES_M, RENDERERS, WINDOW, ActiveDepthEnv, IterationInfo, make_renderer,
)
from aectorch.sim.hoap3 import HOAP3Head
from aectorch.sim.movements import Movement
from aectorch.sim.oculomotor import PAN_RANGE_DEG, VERGENCE_RANGE_DEG, check_oculomotor_range, clamp_eyes
from aectorch.sim.protocol import (
    DEFAULT_PROTOCOL, START_PURSUIT_DEG, START_VERGENCE_DEG, Renderer, TrialProtocol, resolve_protocol,
)
from aectorch.sim.render_torch import (
    MipmapAtlas, TorchPlaneRenderer, mipmap_atlas, pixel_rays, render_planes, render_rays, sample_bilinear,
)
from aectorch.sim.scene import PlaneScene
from aectorch.sim.textures import PROCEDURAL_TEXTURES, TextureBank, dead_leaves_image, pink_noise_images


def __getattr__(name: str):
    # Lazy: importing pyrender loads OpenGL, which must see PYOPENGL_PLATFORM first.
    if name == "PyrenderRenderer":
        from aectorch.sim.render_pyrender import PyrenderRenderer

        return PyrenderRenderer
    raise AttributeError(f"module 'aectorch.sim' has no attribute {name!r}")


__all__ = [
    "ActiveDepthEnv",
    "Movement",
    "WINDOW",
    "DEFAULT_PROTOCOL",
    "START_PURSUIT_DEG",
    "START_VERGENCE_DEG",
    "Renderer",
    "TrialProtocol",
    "resolve_protocol",
    "DEFAULT_DISTANCES_M",
    "HOAP3Head",
    "PAN_RANGE_DEG",
    "VERGENCE_RANGE_DEG",
    "check_oculomotor_range",
    "clamp_eyes",
    "IterationInfo",
    "PinholeCamera",
    "PixelWindow",
    "PlaneScene",
    "PyrenderRenderer",
    "RENDERERS",
    "TextureBank",
    "TorchPlaneRenderer",
    "make_renderer",
    "pink_noise_images",
    "dead_leaves_image",
    "PROCEDURAL_TEXTURES",
    "render_planes",
    "render_rays",
    "pixel_rays",
    "mipmap_atlas",
    "MipmapAtlas",
    "sample_bilinear",
]
