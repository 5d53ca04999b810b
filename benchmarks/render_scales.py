"""Rendering each foveal scale at its own resolution: accuracy against the exact area average, and speed.

Accuracy: for each default scale (wide, coarse, fine; centred) the env's scale rendering
(the renderer of ``ActiveDepthEnv.stereo_observation(scales=...)``: mipmaps, 2 x 2 lookups per
pixel, level of detail biased by -0.5; 4 x 4 for the widest scale) against the exact area average (the crop
rendered 4 x 4 times finer with ``GL_LINEAR`` and block-averaged), mean |difference| in % of the
grey range, on the 40 test textures and on photographs (scikit-learn's two, which chose the
settings, and scikit-image's ``astronaut``, ``coffee``, ``chelsea`` and ``rocket``, held out), at 1-3 m with the eyes
panned; beside it the same for one lookup per pixel without the bias (OpenGL's default); and the
observation (that render plus ``pyramid_blur``) against what the coder read before (the 128 px
crop rendered, then reduced by the centred pyramid), beside the unblurred render's distance to it. Also pyrender
(``filter="trilinear"``, OSMesa) against the torch renderer at the scales.

Speed: milliseconds to render one eye's view for B = 32 (one thread): the 128 px crop
(``GL_LINEAR``, what the coder reduced before), the scales with the fused CPU kernel, and the
scales with the pure-torch code (the CUDA path).

Usage:
    python benchmarks/render_scales.py [--json benchmarks/results/render_scales.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from aectorch.coding.patches import COARSE, FINE, WIDE, pyramid_down  # noqa: E402
from aectorch.sim import ActiveDepthEnv, PinholeCamera, PixelWindow, TextureBank  # noqa: E402
from aectorch.sim import render_torch  # noqa: E402
from aectorch.sim.env import _block_mean, _finer  # noqa: E402

SCALES = [dataclasses.replace(s, centred=True) for s in (WIDE, COARSE, FINE)]
DISTANCES = (1.0, 1.5, 2.0, 2.5, 3.0)


def photographs(held_out: bool) -> torch.Tensor:
    """scikit-learn's two photographs (they chose the level-of-detail bias and the 4 x 4 rule), or
    scikit-image's four (held out: only reported)."""
    if not held_out:
        from sklearn.datasets import load_sample_images

        images = [torch.tensor(i).float().mean(-1) / 255 for i in load_sample_images().images]
    else:
        from skimage import data

        images = []
        for name in ("astronaut", "coffee", "chelsea", "rocket"):
            image = torch.tensor(getattr(data, name)()).float() / 255
            images.append(image.mean(-1) if image.dim() == 3 else image)
    side = 512
    out = []
    for image in images:  # centre square, area-resampled to 512 x 512
        h, w = image.shape
        s = min(h, w)
        square = image[(h - s) // 2:(h - s) // 2 + s, (w - s) // 2:(w - s) // 2 + s]
        out.append(torch.nn.functional.interpolate(square[None, None], size=(side, side), mode="area")[0, 0])
    return torch.stack(out)


def exact(env, poses, window, downsample, factor=4):
    camera = env.camera
    big = PinholeCamera(width=camera.width * factor, height=camera.height * factor, vfov_deg=camera.vfov_deg)
    top, left, h, w = window
    fine = render_torch.render_planes(poses, env.plane_x_m, env.texture_index, env.scene, big,
                                      PixelWindow(top * factor, left * factor, h * factor, w * factor))
    pooled = torch.nn.functional.avg_pool2d(fine.flatten(0, -3).unsqueeze(1), factor * downsample)
    return pooled.reshape(fine.shape[:-2] + pooled.shape[-2:])


def accuracy(textures: torch.Tensor, label: str) -> list[dict]:
    n = len(textures)
    env = ActiveDepthEnv(n, textures=textures, seed=0)
    plain = render_torch.TorchPlaneRenderer(env.scene, filter="trilinear")
    rows = []
    g = torch.Generator().manual_seed(0)
    for distance in DISTANCES:
        env.set_trial(torch.arange(n), torch.full((n,), distance))
        shift = (torch.rand(n, generator=g) - 0.5) * 0.2
        pan = (torch.rand(n, 2, generator=g) - 0.5) * 8
        poses = env.head.camera_poses(shift, pan, torch.zeros(n, 2), convention="opengl")
        observed = env._render(shift, pan, slice(0, 2), scales=SCALES)  # area render + pyramid_blur
        crops = env._render(shift, pan, slice(0, 2))  # the 128 px crops, GL_LINEAR
        for scale in SCALES:
            window = env.camera.central_window(scale.crop)
            k = _finer(scale.downsample)
            area = _block_mean(env._scale_renderer.render_windows(
                poses, env.plane_x_m, env.texture_index, [(window, scale.downsample // k)])[0], k)
            truth = exact(env, poses, window, scale.downsample)
            one = plain(poses, env.plane_x_m, env.texture_index, window, downsample=scale.downsample)
            top = (128 - scale.crop) // 2
            pyramid = pyramid_down(crops[..., top:top + scale.crop, top:top + scale.crop].flatten(0, 1),
                                   scale.levels, centred=True).view_as(truth)
            mad = lambda x, y=truth: 100 * float((x - y).abs().mean())  # noqa: E731
            rows.append({"source": label, "distance_m": distance, "scale": scale.name,
                         "scale_rendering_pct": mad(area), "one_lookup_pct": mad(one),
                         "observation_vs_old_pipeline_pct": mad(observed[scale.name], pyramid),
                         "area_vs_old_pipeline_pct": mad(area, pyramid)})
    return rows


def pyrender_agreement(textures: torch.Tensor) -> list[dict]:
    rows = []
    quantised = (textures * 255).round() / 255
    envs = [ActiveDepthEnv(4, textures=quantised[:4], renderer=name, seed=3) for name in ("torch", "pyrender")]
    for distance in (1.0, 2.0, 3.0):
        for env in envs:
            env.set_trial(torch.arange(4), torch.full((4,), distance))
            env.apply_pursuit(torch.tensor([0.5, -1.0, 2.0, 0.1]))
        a, b = (env.stereo_observation(scales=SCALES) for env in envs)
        for name in a:
            rows.append({"distance_m": distance, "scale": name,
                         "mean_abs_diff_pct": 100 * float((a[name] - b[name]).abs().mean()),
                         "max_abs_diff_pct": 100 * float((a[name] - b[name]).abs().max())})
    envs[1]._scale_renderer.close()
    envs[1].renderer.close()
    return rows


def speed(batch: int = 32, repeats: int = 30) -> dict:
    torch.set_num_threads(1)
    env = ActiveDepthEnv(batch, seed=1)

    def timed(fn):
        for _ in range(3):
            fn()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            fn()
            times.append(time.perf_counter() - start)
        return 1e3 * statistics.median(times)

    args = (env.body_shift_m, env.pan_deg, slice(0, 1))
    result = {"B": batch, "crop_128_linear_ms": timed(lambda: env._render(*args)),
              "scales_native_ms": timed(lambda: env._render(*args, scales=SCALES))}
    fused = render_torch._native_trilinear
    render_torch._native_trilinear = lambda *a: False
    try:
        result["scales_torch_code_ms"] = timed(lambda: env._render(*args, scales=SCALES))
    finally:
        render_torch._native_trilinear = fused
    result["pixels_crop"] = 128 * 128
    # rendered per eye image: each scale's crop plus one pixel of border, the widest 2x finer
    result["pixels_scales"] = sum(((s.crop + 2 * s.downsample) * _finer(s.downsample) // s.downsample) ** 2
                                  for s in SCALES)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "render_scales.json")
    args = parser.parse_args()
    sources = {"test textures": TextureBank.default("test").textures,
               "photographs (chose the settings)": photographs(held_out=False)}
    try:
        sources["photographs (held out)"] = photographs(held_out=True)
    except ImportError:
        print("scikit-image is not installed: no held-out photographs", file=sys.stderr)
    rows = [row for label, textures in sources.items() for row in accuracy(textures, label)]
    print("| source | scale | scale rendering vs exact, % | one lookup, no bias, vs exact | "
          "observation vs old pipeline, % | unblurred vs old pipeline |")
    print("|---|---|---:|---:|---:|---:|")
    for source in sources:
        for scale in SCALES:
            sel = [r for r in rows if r["source"] == source and r["scale"] == scale.name]
            worst = max(sel, key=lambda r: r["scale_rendering_pct"])
            print(f"| {source} | {scale.name} | {statistics.mean(r['scale_rendering_pct'] for r in sel):.3f} "
                  f"(worst {worst['scale_rendering_pct']:.3f} at {worst['distance_m']} m) | "
                  f"{statistics.mean(r['one_lookup_pct'] for r in sel):.3f} | "
                  f"{statistics.mean(r['observation_vs_old_pipeline_pct'] for r in sel):.3f} | "
                  f"{statistics.mean(r['area_vs_old_pipeline_pct'] for r in sel):.3f} |")
    agreement = pyrender_agreement(TextureBank.default("test").textures)
    print("\n| distance | scale | pyrender vs torch: mean abs diff, % | max, % |\n|---:|---|---:|---:|")
    for r in agreement:
        print(f"| {r['distance_m']} | {r['scale']} | {r['mean_abs_diff_pct']:.3f} | {r['max_abs_diff_pct']:.3f} |")
    timing = speed()
    print(f"\none eye, B = {timing['B']}, 1 thread: 128 px crop {timing['crop_128_linear_ms']:.2f} ms "
          f"({timing['pixels_crop']} px); scales {timing['scales_native_ms']:.2f} ms fused kernel, "
          f"{timing['scales_torch_code_ms']:.2f} ms torch code ({timing['pixels_scales']} px)")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"benchmark": "render_scales", "machine": machine_info(), "accuracy": rows,
                                     "pyrender": agreement, "speed": timing}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
