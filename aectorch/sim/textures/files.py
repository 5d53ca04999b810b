"""Image files read as grey textures: the formats, the grey conversion and the centred crop."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

__all__ = ["IMAGE_EXTENSIONS", "check_extensions", "load_grey"]

#: File extensions `TextureBank.from_folder` loads by default (compared case-insensitively).
IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg")
# Pillow modes holding more than 8 bits per grey pixel: read as float and divided by 65535,
# because Pillow's convert("L") clips them at 255 instead of rescaling.
_WIDE_GREY_MODES = ("I", "I;16", "I;16L", "I;16B", "I;16N")


def load_grey(file: Path, height: int, width: int):
    """One image file as a float32 numpy array `[height, width]` in [0, 1] (see from_folder)."""
    import numpy as np
    from PIL import Image, ImageOps

    try:
        with Image.open(file) as image:
            image.load()
            image = ImageOps.exif_transpose(image)
            if image.mode in _WIDE_GREY_MODES:
                grey, scale = image.convert("F"), 65535.0
            else:
                if image.mode not in ("1", "L", "LA", "P", "PA", "RGB", "RGBA", "RGBX", "La"):
                    image = image.convert("RGB")  # CMYK, YCbCr, LAB, HSV: through RGB
                grey, scale = image.convert("L").convert("F"), 255.0
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise ValueError(f"cannot read image file {str(file)!r}: {exc}") from exc

    w, h = grey.size
    # The largest centred window with the output's aspect ratio, in source pixels (fractional,
    # so the crop is exactly centred and the aspect ratio exactly kept), resampled to the output
    # size in one step: the same as resizing so that the image just covers the output size and
    # cutting out the centre, without rounding the intermediate size.
    if w * height >= h * width:  # wider than the output: crop the sides
        crop_w, crop_h = h * width / height, float(h)
    else:  # taller: crop top and bottom
        crop_w, crop_h = float(w), w * height / width
    left, top = (w - crop_w) / 2, (h - crop_h) / 2
    if (w, h) != (width, height):
        grey = grey.resize(
            (width, height), Image.Resampling.LANCZOS, box=(left, top, left + crop_w, top + crop_h)
        )
    array = np.asarray(grey, dtype=np.float32) / np.float32(scale)
    return np.clip(array, 0.0, 1.0)


def check_extensions(extensions) -> tuple[str, ...]:
    """File extensions as lower-case suffixes with their dot, each once, in their order.

    Example:
        >>> check_extensions(["PNG", ".jpg", "png"])
        ('.png', '.jpg')
    """
    if isinstance(extensions, str):
        extensions = (extensions,)
    if not isinstance(extensions, Sequence) or not extensions:
        raise ValueError(f"extensions must be a non-empty sequence of str, got {extensions!r}")
    out = []
    for ext in extensions:
        if not isinstance(ext, str) or not ext.strip("."):
            raise ValueError(f"extensions must be non-empty str like '.png', got {ext!r}")
        ext = ext.lower()
        out.append(ext if ext.startswith(".") else "." + ext)
    return tuple(dict.fromkeys(out))
