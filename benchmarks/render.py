"""Frames per second of the two plane renderers: aectorch's torch renderer versus pyrender (OSMesa).

One frame is one eye camera's grey image. Each environment of a batch of B looks at its own
texture (100 procedural 512 x 512 textures, as ``TextureBank.default()``), at its own distance,
with its own body shift and eye pans, as ``ActiveDepthEnv`` renders them. Measured:

  * ``TorchPlaneRenderer`` (eager), one call renders ``[B, 2]`` frames;
  * ``PyrenderRenderer`` on OSMesa (llvmpipe), one OpenGL draw per frame, what a user of the
    MATLAB/V-REP lineage would otherwise reach for;

for B = 1, 64 and 256, for the whole 320 x 240 frame and for the 128 x 128 central window that
the coder uses (``window="crops"``), on 1 and 2 threads. Each thread count runs in its own
subprocess with ``OMP_NUM_THREADS`` (torch) and ``LP_NUM_THREADS`` (llvmpipe) set before either
library starts. Medians of ``--repeats`` timed calls after one warm-up call (which also
uploads pyrender's textures).

Usage:
    python benchmarks/render.py                 # full sweep (a few minutes)
    python benchmarks/render.py --quick         # B = 1 and 64, 1 thread
    python benchmarks/render.py --agreement     # only: mean |torch - pyrender| at 1, 2, 3 m

Writes a table to stdout and JSON to benchmarks/results/render.json (--json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worker(batches: list[int], repeats: int, pyrender_max_frames: int) -> list[dict]:
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    sys.path.insert(0, str(ROOT))
    import torch

    from aectorch.sim import HOAP3Head, PlaneScene, TextureBank, TorchPlaneRenderer
    from aectorch.sim.camera import PinholeCamera
    from aectorch.sim.render_pyrender import PyrenderRenderer

    threads = int(os.environ["OMP_NUM_THREADS"])
    torch.set_num_threads(threads)
    bank = TextureBank.default("train")
    background = TextureBank.procedural(1, size=(256, 256), seed=1).textures[0]
    scene = PlaneScene(bank.textures, background)
    camera = PinholeCamera()
    head = HOAP3Head()
    torch_renderer = TorchPlaneRenderer(scene, camera)
    gl_renderer = PyrenderRenderer(scene, camera)
    generator = torch.Generator().manual_seed(0)
    rows = []
    for batch in batches:
        shift = (torch.rand(batch, generator=generator) - 0.5) * 0.2
        pan = (torch.rand(batch, 2, generator=generator) - 0.5) * 10
        poses = head.camera_poses(shift, pan)
        plane_x = 1.03 + 2 * torch.rand(batch, generator=generator)
        index = torch.arange(batch) % len(bank)
        for window_name, window in (("full", camera.full_window), ("crops", camera.central_window(128))):
            for name, render in (("torch", torch_renderer), ("pyrender", gl_renderer)):
                frames = batch * 2
                sub = batch
                if name == "pyrender" and frames > pyrender_max_frames:
                    # pyrender's cost is per frame; time a slice and report frames per second.
                    sub = max(1, pyrender_max_frames // 2)
                args = (poses[:sub], plane_x[:sub], index[:sub], window)
                with torch.inference_mode():
                    render(*args)  # warm-up (pyrender uploads the textures here)
                    times = []
                    for _ in range(repeats):
                        t0 = time.perf_counter()
                        render(*args)
                        times.append(time.perf_counter() - t0)
                seconds = statistics.median(times)
                rows.append(
                    {
                        "renderer": name,
                        "window": window_name,
                        "pixels": window.height * window.width,
                        "B": batch,
                        "threads": threads,
                        "frames_timed": sub * 2,
                        "seconds_per_call": seconds,
                        "frames_per_s": sub * 2 / seconds,
                    }
                )
                print(
                    f"  threads={threads} B={batch:<4d} {window_name:5s} {name:8s} "
                    f"{sub * 2 / seconds:10.1f} frames/s",
                    file=sys.stderr,
                    flush=True,
                )
    gl_renderer.close()
    return rows


def agreement() -> None:
    """Mean |torch - pyrender| inside the object plane, the quantity tests/test_sim.py bounds."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    sys.path.insert(0, str(ROOT))
    import torch

    from aectorch.sim import HOAP3Head, PlaneScene, TextureBank, TorchPlaneRenderer, render_planes
    from aectorch.sim.camera import PinholeCamera
    from aectorch.sim.render_pyrender import PyrenderRenderer

    def q(x):
        return (x * 255).round() / 255

    scene = PlaneScene(q(TextureBank.procedural(3, size=(512, 512), seed=7).textures),
                       q(TextureBank.procedural(1, size=(256, 256), seed=8).textures[0]))
    head, camera = HOAP3Head(), PinholeCamera()
    shift = torch.tensor([0.1, -0.1, 0.05])
    pan = torch.tensor([[-5.7, -2.3], [2.9, 4.6], [-1.0, 0.3]])
    roll = torch.tensor([[0.0, 0.0], [0.0, 0.0], [3.0, -2.0]])
    poses = head.camera_poses(shift, pan, roll)
    plane_x = torch.tensor([1.0, 2.0, 3.0]) + head.eye_x_m
    index = torch.tensor([0, 1, 2])
    gl = PyrenderRenderer(scene, camera)
    for name, window in (("320x240", camera.full_window), ("128x128 crops", camera.central_window(128))):
        ours = TorchPlaneRenderer(scene, camera)(poses, plane_x, index, window)
        theirs = gl(poses, plane_x, index, window)
        inside = render_planes(poses, plane_x, index, PlaneScene(torch.ones(3, 4, 4), torch.zeros(4, 4)),
                               camera, window) > 0.5
        for b, d in enumerate((1, 2, 3)):
            diff = (ours[b] - theirs[b]).abs()[inside[b]]
            print(f"{name:14s} {d} m: mean |torch - pyrender| = {100 * diff.mean():.3f} % of range, "
                  f"max {100 * diff.max():.2f} %")
    gl.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 256])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--pyrender-max-frames", type=int, default=128,
                        help="time pyrender on at most this many frames per call (its cost is per frame)")
    parser.add_argument("--quick", action="store_true", help="B = 1 and 64 on 1 thread, 3 repeats")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "render.json")
    parser.add_argument("--agreement", action="store_true",
                        help="only print the renderers' mean absolute difference at 1, 2 and 3 m")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.agreement:
        agreement()
        return
    if args.quick:
        args.batches, args.threads, args.repeats = [1, 64], [1], 3
    if args.worker:
        rows = worker(args.batches, args.repeats, args.pyrender_max_frames)
        print(json.dumps(rows))
        return

    rows = []
    for threads in args.threads:
        env = dict(os.environ, OMP_NUM_THREADS=str(threads), LP_NUM_THREADS=str(threads),
                   MKL_NUM_THREADS=str(threads), PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"))
        command = [sys.executable, __file__, "--worker", "--repeats", str(args.repeats),
                   "--pyrender-max-frames", str(args.pyrender_max_frames), "--batches", *map(str, args.batches)]
        result = subprocess.run(command, env=env, capture_output=True, text=True)
        sys.stderr.write(result.stderr)
        if result.returncode != 0:
            raise SystemExit(f"worker with {threads} thread(s) failed (exit {result.returncode})")
        rows += json.loads(result.stdout.strip().splitlines()[-1])

    print(f"\nFrames per second (median of {args.repeats}); one frame = one eye's grey image\n")
    print("| window | B | threads | torch | pyrender (OSMesa) | torch / pyrender |")
    print("|---|---:|---:|---:|---:|---:|")
    keyed = {(r["renderer"], r["window"], r["B"], r["threads"]): r for r in rows}
    for window in ("full", "crops"):
        for batch in args.batches:
            for threads in args.threads:
                t = keyed[("torch", window, batch, threads)]["frames_per_s"]
                g = keyed[("pyrender", window, batch, threads)]["frames_per_s"]
                label = "320x240" if window == "full" else "128x128 crops"
                print(f"| {label} | {batch} | {threads} | {t:,.0f} | {g:,.0f} | {t / g:.1f}x |")
    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    report = {
        "benchmark": "render",
        "machine": machine_info(),
        "repeats": args.repeats,
        "rows": rows,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
