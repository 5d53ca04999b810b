"""Write the public rectified stereo pairs with ground truth into a folder, in the plain layout.

One pair ships inside a package on PyPI: scikit-image's ``motorcycle`` (``skimage.data.stereo_motorcycle``,
a reduced copy of Middlebury 2014's Motorcycle: 741 x 500 px, disparities 7-60 px, unknown = inf).
It is read from an installed scikit-image or, without it, from scikit-image's wheel downloaded
with ``pip download`` and read without installing it (as ``scripts/heldout_photos.py`` does), so
aectorch needs no new dependency. Each pair is written as ``FOLDER/<name>/left.png``,
``right.png`` and ``disparity.npy`` (float32, unknown = NaN), which
``python -m aectorch.evaluate pairs=FOLDER`` reads.

    .venv/bin/python scripts/stereo_pairs.py data/stereo-pairs
    .venv/bin/python scripts/stereo_pairs.py data/stereo-pairs-same --same

``--same`` writes the control instead: the left photograph to both eyes (``motorcycle_same``,
ground truth 0 everywhere it is known).
"""

from __future__ import annotations

import argparse
import io
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

FILES = ("motorcycle_left.png", "motorcycle_right.png", "motorcycle_disp.npz")


def _skimage_files(version: str) -> dict[str, bytes]:
    """The motorcycle's three files: from the installed scikit-image, else from its wheel."""
    try:
        import skimage

        folder = Path(skimage.__file__).parent / "data"
        if all((folder / name).is_file() for name in FILES):
            return {name: (folder / name).read_bytes() for name in FILES}
    except ImportError:
        pass
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "-q",
                        "-d", tmp, f"scikit-image=={version}"], check=True)
        wheel = next(Path(tmp).glob("scikit_image-*.whl"))
        with zipfile.ZipFile(wheel) as archive:
            return {name: archive.read(f"skimage/data/{name}") for name in FILES}


def write_motorcycle(out: Path, *, same: bool = False, version: str = "0.26.0") -> Path:
    """Write scikit-image's motorcycle pair (or, with ``same``, its left photograph to both eyes)
    into ``out / name`` in the plain layout; returns that folder."""
    files = _skimage_files(version)
    with np.load(io.BytesIO(files["motorcycle_disp.npz"])) as data:
        disparity = data["arr_0"].astype(np.float32)
    disparity[~np.isfinite(disparity)] = np.nan
    folder = out / ("motorcycle_same" if same else "motorcycle")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "left.png").write_bytes(files["motorcycle_left.png"])
    (folder / "right.png").write_bytes(files["motorcycle_left.png" if same else "motorcycle_right.png"])
    np.save(folder / "disparity.npy", np.where(np.isfinite(disparity), 0.0, np.nan).astype(np.float32)
            if same else disparity)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder of pair folders to fill (created)")
    parser.add_argument("--same", action="store_true", help="write the control: the left photograph to both eyes")
    parser.add_argument("--skimage-version", default="0.26.0", help="scikit-image wheel to read without it installed")
    args = parser.parse_args(argv)
    folder = write_motorcycle(args.out, same=args.same, version=args.skimage_version)
    print(f"wrote {folder}: left.png, right.png, disparity.npy")
    return 0


if __name__ == "__main__":
    sys.exit(main())
