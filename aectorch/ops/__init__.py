"""The fused C++ kernels under the coder and the renderer: their sources, their loader and switches.

``coder_cpu.cpp`` holds the coder's operators (``torch.ops.aectorch.sparse_code``, ``encode``,
``gram``, the dictionary's steps, ``pair_patches``) and ``render_cpu.cpp`` the renderer's
(``render_trilinear``, ``pyramid_blur``); `aectorch.ops.native` builds both into one library on
first use, registers their fake implementations for ``torch.compile`` and sets their threads;
`aectorch.ops.backend` is the switch between them and torch's own operations (`use_backend`).
This floor imports only torch, so `aectorch.coding` and `aectorch.sim` both stand on it without
knowing each other.
"""

from aectorch.ops.backend import BACKENDS, fused_kernels_apply, use_backend
from aectorch.ops.native import available, get_threads, load, set_threads, sparse_code

__all__ = ["BACKENDS", "available", "fused_kernels_apply", "get_threads", "load", "set_threads", "sparse_code",
           "use_backend"]
