"""The switch between the fused CPU kernels and torch's own operations, read by the coder and the renderer.

``backend="auto"`` (the default) runs a fused kernel wherever it applies: a CPU float32/float64
tensor and the kernels built (`aectorch.ops.native.load`); ``"native"`` asks for the kernel (the
coders raise a ValueError where it cannot run); ``"torch"`` runs torch's operations everywhere
(the CUDA path, differentiable, and the reference the kernels are tested against). `use_backend`
sets the default for a block of code, so it reaches the sparse coders, patches and dictionary steps
that library code runs for you.

Example:
    >>> import torch
    >>> from aectorch.ops import use_backend, fused_kernels_apply
    >>> with use_backend("torch"):
    ...     fused_kernels_apply(torch.zeros(3))
    False
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch

from aectorch.ops import native

__all__ = ["BACKENDS", "check_backend", "default_backend", "fused_kernels_apply", "native_supports", "use_backend"]

#: Values of the ``backend`` argument of `aectorch.coding.omp` and `aectorch.coding.matching_pursuit`.
BACKENDS = ("auto", "native", "torch")

_default_backend = "auto"


def check_backend(backend: str) -> None:
    """Raise a ValueError unless ``backend`` is one of `BACKENDS`."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


def default_backend() -> str:
    """The backend of calls without ``backend=``: ``"auto"`` unless `use_backend` changed it."""
    return _default_backend


@contextlib.contextmanager
def use_backend(backend: str) -> Iterator[None]:
    """Within the block, `omp` and `matching_pursuit` called without ``backend=`` use this one.

    Reaches the sparse coding that library code runs for you (`SparseDictionary`,
    `BinocularEncoder`, `aectorch.JointLearner`), e.g. to compare the fused kernel with torch.

    Example:
        >>> import torch
        >>> from aectorch.coding import matching_pursuit, use_backend
        >>> D = torch.nn.functional.normalize(torch.randn(20, 50, dtype=torch.float64), dim=0)
        >>> x = torch.randn(8, 20, dtype=torch.float64)
        >>> with use_backend("torch"):
        ...     slow = matching_pursuit(x, D, 3)
        >>> torch.equal(slow.indices, matching_pursuit(x, D, 3).indices)
        True
    """
    global _default_backend
    check_backend(backend)
    previous, _default_backend = _default_backend, backend
    try:
        yield
    finally:
        _default_backend = previous


@torch.compiler.assume_constant_result
def native_loaded() -> bool:
    """Whether the fused kernels are built and loaded (building them on the first call)."""
    # A constant for torch.compile: traced graphs call the operator (or not) without tracing
    # the loader.
    return native.load()


def native_supports(tensor: torch.Tensor) -> bool:
    """Whether a fused kernel can run on ``tensor``: a CPU float32/float64 tensor, the kernels loaded."""
    return tensor.device.type == "cpu" and tensor.dtype in (torch.float32, torch.float64) and native_loaded()


def fused_kernels_apply(tensor: torch.Tensor) -> bool:
    """Whether library code uses the fused CPU kernels for ``tensor`` (a CPU float32/float64
    tensor, the kernels loaded, and no ``use_backend("torch")`` around the call)."""
    return _default_backend != "torch" and native_supports(tensor)
