"""Storage of large texture tensors: in RAM, or in a temporary file mapped into memory.

A bank of 10,000 photographs or the torch renderer's mipmap atlas can exceed the machine's
memory; `empty_textures` puts a tensor larger than `texture_ram_bytes` in a file the operating
system pages in and out.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import torch
from torch import Tensor

__all__ = ["TEXTURE_RAM_BYTES", "empty_textures", "texture_ram_bytes"]

#: Texture tensors (a bank, the torch renderer's atlas) larger than this many bytes live in a temporary
#: file mapped into memory instead of in RAM (`empty_textures`); the environment variable
#: ``AECTORCH_TEXTURE_RAM`` (bytes) overrides it, ``AECTORCH_TEXTURE_DIR`` chooses the file's folder.
TEXTURE_RAM_BYTES = 2 * 2**30


def texture_ram_bytes() -> int:
    """The size above which `empty_textures` maps a file: ``AECTORCH_TEXTURE_RAM`` (bytes, an
    integer >= 0) when set, else `TEXTURE_RAM_BYTES`.

    Raises:
        ValueError: ``AECTORCH_TEXTURE_RAM`` is not a non-negative integer.
    """
    text = os.environ.get("AECTORCH_TEXTURE_RAM")
    if text is None or not text.strip():
        return TEXTURE_RAM_BYTES
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise ValueError(f"AECTORCH_TEXTURE_RAM must be a number of bytes (an integer >= 0), got {text!r}")
    return value


def empty_textures(shape: Sequence[int], dtype: torch.dtype = torch.float32,
                   device: torch.device | str | None = None) -> Tensor:
    """An uninitialised CPU (or `device`) tensor for textures, in RAM or, when it is larger than
    `texture_ram_bytes`, in a temporary file mapped into memory.

    The file (in ``AECTORCH_TEXTURE_DIR``, else the system's temporary folder) is reserved in
    full at once, so a full disk fails here with ``OSError`` rather than later inside a write to
    the mapping, and it is unlinked at once: it takes disk space only while the tensor lives and
    disappears with the process. The operating system keeps the pages it has room for in its
    page cache, so a bank of 10,000 photographs costs disk, not the process's memory.
    Tensors on other devices than the CPU are plain ``torch.empty``.

    Example:
        >>> empty_textures((3, 8, 8)).shape
        torch.Size([3, 8, 8])
    """
    shape = tuple(int(n) for n in shape)
    device = torch.device(device) if device is not None else torch.device("cpu")
    numel = math.prod(shape)
    nbytes = numel * torch.empty((), dtype=dtype).element_size()
    if device.type != "cpu" or nbytes <= texture_ram_bytes() or numel == 0:
        return torch.empty(shape, dtype=dtype, device=device)
    import tempfile

    folder = os.environ.get("AECTORCH_TEXTURE_DIR") or None
    fd, path = tempfile.mkstemp(prefix="aectorch-textures-", suffix=".bin", dir=folder)
    try:
        try:
            os.posix_fallocate(fd, 0, nbytes)
        except OSError as err:
            raise OSError(err.errno, f"cannot reserve {nbytes / 2**30:.2f} GiB for textures in "
                                     f"{os.path.dirname(path)!r} ({err.strerror}); free disk space or set "
                                     f"AECTORCH_TEXTURE_DIR to a folder with room") from err
        return torch.from_file(path, shared=True, size=numel, dtype=dtype).view(shape)
    finally:
        os.close(fd)
        os.unlink(path)
