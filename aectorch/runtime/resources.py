"""What the config's dataclasses cannot check before a run: the folders of images, the renderer,
the device, LeRobot and the resume folder (:func:`validate_resources`)."""

from __future__ import annotations

import os

import torch

from aectorch.runtime.config import ExperimentConfig
from aectorch.sim import PROCEDURAL_TEXTURES

__all__ = ["validate_resources"]


def _images(folder: str) -> list[str]:
    from aectorch.sim.textures import IMAGE_EXTENSIONS

    extensions = {e.lower() if e.startswith(".") else f".{e.lower()}" for e in IMAGE_EXTENSIONS}
    return sorted(
        entry.path for entry in os.scandir(folder)
        if entry.is_file() and not entry.name.startswith(".") and os.path.splitext(entry.name)[1].lower() in extensions
    )


def _check_images(name: str, folder: str) -> None:
    """Every image of the folder opens (its header and data structure, without decoding it all)."""
    from PIL import Image

    files = _images(folder)
    if not files:
        raise ValueError(f"{name}: the folder {folder!r} holds no images")
    for file in files:
        try:
            with Image.open(file) as image:
                image.verify()
        except Exception as err:  # PIL raises many types for broken files
            raise ValueError(f"{name}: cannot read the image {file!r} ({type(err).__name__}: {err}); "
                             "remove or replace it") from err


def validate_resources(cfg: ExperimentConfig) -> None:
    """Check what the dataclasses cannot: folders exist and hold readable images, the renderer
    imports, the resume folder has a checkpoint. Raises ``ValueError`` naming the field (and the
    file)."""
    for name, folder in (("env.textures", cfg.env.textures), ("eval.textures", cfg.eval.textures)):
        if folder is None or folder in PROCEDURAL_TEXTURES:
            continue
        if not os.path.isdir(folder):
            raise ValueError(f"{name}: no such folder {folder!r}")
        _check_images(name, folder)
    device = torch.device(cfg.env.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"env.device={cfg.env.device!r}, but this torch ({torch.__version__}) sees no CUDA "
                         "device; use env.device=cpu")
    if cfg.env.renderer == "pyrender":
        try:
            from aectorch.sim.render_pyrender import import_pyrender

            import_pyrender()  # PYOPENGL_PLATFORM first (the user's, else osmesa), then pyrender
        except Exception as err:  # ImportError, or OpenGL failing to find a platform
            raise ValueError(f"env.renderer='pyrender' cannot be used: {type(err).__name__}: {err}") from err
    if cfg.record.lerobot is not None:
        if os.path.exists(cfg.record.lerobot):
            raise ValueError(f"record.lerobot: {cfg.record.lerobot!r} exists already; give a new folder")
        try:
            import lerobot  # noqa: F401
        except ImportError as err:
            raise ValueError("record.lerobot needs LeRobot, which is not installed here: run train.py with "
                             ".venv-lerobot/bin/python (bash scripts/setup_lerobot.sh makes it)") from err
    if cfg.train.resume is not None:
        checkpoint = os.path.join(cfg.train.resume, "checkpoint.pt")
        if not os.path.isfile(checkpoint):
            raise ValueError(f"train.resume: no checkpoint at {checkpoint!r}")
