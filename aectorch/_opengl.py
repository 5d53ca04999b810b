"""PyOpenGL's platform, chosen before anything imports OpenGL (``import aectorch`` does it first).

PyOpenGL reads ``PYOPENGL_PLATFORM`` once, when it is first imported, and pyrender imports it.
Unless the user set the variable, aectorch sets it to ``osmesa`` (software OpenGL, which every
machine this library runs on can have) as the package is imported, and
:func:`aectorch.sim.render_pyrender.import_pyrender` may still switch it to ``egl`` when asked
before OpenGL is imported. The user's own value is always respected.
"""

from __future__ import annotations

import os
import sys

__all__ = ["DEFAULT_PLATFORM", "PLATFORMS", "choose_default", "chosen_by_aectorch", "set_platform"]

VARIABLE = "PYOPENGL_PLATFORM"
#: The platforms aectorch's pyrender renderer supports.
PLATFORMS = ("osmesa", "egl")
DEFAULT_PLATFORM = "osmesa"
_state = {"ours": False}


def choose_default() -> None:
    """Set ``PYOPENGL_PLATFORM=osmesa`` unless the user set it or OpenGL is imported already."""
    if VARIABLE not in os.environ and "OpenGL" not in sys.modules:
        os.environ[VARIABLE] = DEFAULT_PLATFORM
        _state["ours"] = True


def chosen_by_aectorch() -> bool:
    """Whether the current ``PYOPENGL_PLATFORM`` is aectorch's default rather than the user's."""
    return _state["ours"] and os.environ.get(VARIABLE) is not None


def set_platform(platform: str) -> None:
    """Switch aectorch's default to ``platform`` before OpenGL is imported (the user's value stays)."""
    os.environ[VARIABLE] = platform
    _state["ours"] = True
