"""Smoke tests for the installed package and the off-screen rendering stack."""

import os

# Must be set before OpenGL/pyrender are imported anywhere in this process.
os.environ["PYOPENGL_PLATFORM"] = "osmesa"

import importlib.metadata

import numpy as np
import pytest


def test_version_matches_distribution():
    import aectorch

    assert aectorch.__version__ == importlib.metadata.version("aectorch")


def test_pyrender_osmesa_renders_white_quad():
    import pyrender
    import trimesh

    # Unit quad in the z=0 plane, facing +z (towards the camera).
    vertices = np.array(
        [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]]
    )
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    quad = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    material = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=(1.0, 1.0, 1.0, 1.0), doubleSided=True
    )
    mesh = pyrender.Mesh.from_trimesh(quad, material=material, smooth=False)

    scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 1.0), ambient_light=(0.0, 0.0, 0.0))
    scene.add(mesh)
    # Camera on the +z axis looking down -z; the view spans [-1, 1] x [-1, 1],
    # so the quad covers the central half of the image and the corners are empty.
    camera = pyrender.OrthographicCamera(xmag=1.0, ymag=1.0, znear=0.1, zfar=10.0)
    pose = np.eye(4)
    pose[2, 3] = 2.0
    scene.add(camera, pose=pose)

    renderer = pyrender.OffscreenRenderer(viewport_width=64, viewport_height=64)
    try:
        color, depth = renderer.render(scene, flags=pyrender.RenderFlags.FLAT)
    finally:
        renderer.delete()

    assert color.shape == (64, 64, 3)
    assert color[32, 32].min() >= 250, color[32, 32]
    assert color[0, 0].max() <= 5, color[0, 0]
    assert depth[32, 32] > 0 and depth[0, 0] == 0


@pytest.mark.integration
def test_the_wheel_ships_the_fused_kernels_sources(tmp_path):
    """The kernels are built on the user's machine from the .cpp files next to ``aectorch.ops.native``:
    the package data must ship them from where the loader reads them."""
    import shutil
    import subprocess
    import sys
    import zipfile
    from pathlib import Path

    from aectorch.ops import native

    root = Path(__file__).resolve().parents[2]
    tree = tmp_path / "tree"
    shutil.copytree(root / "aectorch", tree / "aectorch", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(root / name, tree / name)
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", str(tree), "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path / "wheel")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = (tmp_path / "wheel").glob("*.whl")
    shipped = set(zipfile.ZipFile(wheel).namelist())
    expected = {source.relative_to(root).as_posix() for source in native.SOURCES}
    assert expected == {"aectorch/ops/coder_cpu.cpp", "aectorch/ops/render_cpu.cpp"}
    assert expected <= shipped, sorted(expected - shipped)
