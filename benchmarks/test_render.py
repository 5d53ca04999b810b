"""Frames per second of aectorch's torch renderer against pyrender on OSMesa, interleaved: one frame
is one eye's grey image, each of B environments with its own texture, distance and pans; pyrender
draws one frame at a time (timed on at most 64 environments a call). Threads: the process's
(``OMP_NUM_THREADS``, llvmpipe's ``LP_NUM_THREADS``).
"""

import functools
import os
import statistics

import pytest
import torch

import aectorch.sim
from benchmarks import harness


@functools.cache
def renderers():
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    from aectorch.sim import PinholeCamera, PlaneScene, TextureBank, TorchPlaneRenderer
    from aectorch.sim.render_pyrender import PyrenderRenderer

    bank = TextureBank.default("train") if harness.FULL else TextureBank.procedural(4, size=(64, 64), seed=0)
    scene, camera = PlaneScene(bank.textures, TextureBank.procedural(1, size=(256, 256), seed=1).textures[0]), PinholeCamera()
    return camera, len(bank), TorchPlaneRenderer(scene, camera), PyrenderRenderer(scene, camera)


@pytest.mark.parametrize("batch", harness.size([1], [1, 64, 256]))
@pytest.mark.parametrize("window", ["full", "crops"])
def test_render(benchmark, window, batch):
    camera, textures, ours, theirs = renderers()
    generator = torch.Generator().manual_seed(0)
    poses = aectorch.sim.HOAP3Head().camera_poses((torch.rand(batch, generator=generator) - 0.5) * 0.2,
                                     (torch.rand(batch, 2, generator=generator) - 0.5) * 10)
    plane_x = 1.03 + 2 * torch.rand(batch, generator=generator)
    index = torch.arange(batch) % textures
    pixels = camera.full_window if window == "full" else camera.central_window(128)
    sub = min(batch, 64)  # pyrender's cost is per frame
    with torch.inference_mode():
        times = harness.interleaved({
            "torch": lambda: ours(poses, plane_x, index, pixels),
            "pyrender": lambda: theirs(poses[:sub], plane_x[:sub], index[:sub], pixels)}, rounds=harness.size(1, 5))
        frames = benchmark.pedantic(ours, args=(poses, plane_x, index, pixels), rounds=harness.size(1, 5))
    assert frames.shape == (batch, 2, pixels.height, pixels.width)
    rates = {"torch": 2 * batch / statistics.median(times["torch"]),
             "pyrender": 2 * sub / statistics.median(times["pyrender"])}
    harness.record("render", [{
        "variant": f"{window}, B={batch}, {torch.get_num_threads()} thread(s)", "window": window, "B": batch,
        "threads": torch.get_num_threads(), "pixels": pixels.height * pixels.width,
        "torch_frames_per_s": rates["torch"], "pyrender_frames_per_s": rates["pyrender"],
        "torch_over_pyrender": rates["torch"] / rates["pyrender"]}], benchmark)
