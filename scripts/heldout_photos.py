"""Collect a held-out folder of natural photographs that aectorch never trains on.

The photographs come from packages on PyPI (nothing from dataset hubs): scikit-image's sample
images (downloaded as its wheel with ``pip download``, read without installing it), and the
sample photographs that scikit-learn and matplotlib ship. Synthetic or text-like images
(chessboards, logos, phantoms, scanned pages) are left out.

    .venv/bin/python scripts/heldout_photos.py data/heldout-photos

The default training textures are procedural 1/f noise (``TextureBank.default("train")``), so
every one of these photographs is unseen.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

SKIMAGE = (
    "astronaut.png", "brick.png", "camera.png", "cell.png", "chelsea.png", "clock_motion.png",
    "coffee.png", "coins.png", "grass.png", "gravel.png", "hubble_deep_field.jpg", "ihc.png",
    "moon.png", "motorcycle_left.png", "retina.jpg", "rocket.jpg",
)


def _bundled() -> list[Path]:
    found = []
    try:
        import sklearn

        images = Path(sklearn.__file__).parent / "datasets" / "images"
        found += [images / "china.jpg", images / "flower.jpg"]
    except ImportError:
        pass
    try:
        import matplotlib

        found.append(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg")
    except ImportError:
        pass
    return [p for p in found if p.is_file()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder to fill (created)")
    parser.add_argument("--skimage-version", default="0.26.0", help="scikit-image wheel to read")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "-q",
             "-d", tmp, f"scikit-image=={args.skimage_version}"],
            check=True,
        )
        wheel = next(Path(tmp).glob("scikit_image-*.whl"))
        with zipfile.ZipFile(wheel) as archive:
            for name in SKIMAGE:
                (args.out / f"skimage_{name}").write_bytes(archive.read(f"skimage/data/{name}"))
    for path in _bundled():
        shutil.copyfile(path, args.out / f"{path.parent.parent.name}_{path.name}")
    count = len(list(args.out.iterdir()))
    print(f"{count} photographs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
