"""Env-iterations per second of the whole training loop, with a stage breakdown and a FLOP floor.

One env-iteration is one environment doing both cues of one iteration: rendering, foveal
patches, sparse coding, rewards, actions, dictionary and policy learning (and, amortised, the
depth MLP's Levenberg-Marquardt refits). ``JointLearner.iteration`` with B environments does B
env-iterations. Measured with the learner of the recorded tables (``--learner recorded``, the
defaults of the morning of 2026-12-01: MP, 288 atoms, the paper's two scales, 13 actions, no cue
symmetries), the two-scale defaults until 2026-12-02 (``--learner two-scale``: the same with the
symmetries) or today's defaults (``--learner default``, ``LearnerConfig()``: PPO on four scales,
11 actions, the symmetries) for every combination of:

  * B (``--batches``, default 1, 16, 64, 256);
  * ``eager`` or ``compile`` (``train.compile=true``: ``torch.compile`` of both encoders and of
    the torch renderer);
  * the ``torch`` or the ``pyrender`` (OSMesa) renderer;
  * 1 or 2 threads (``OMP_NUM_THREADS`` and llvmpipe's ``LP_NUM_THREADS`` set before torch or
    OpenGL start).

Every configuration runs in a fresh subprocess.

Per configuration: ``--warmup`` untimed iterations (compilation happens there), then
``--iterations`` iterations timed one by one; env-iterations/s = B / median iteration time.
Also recorded:

  * **peak memory**: the rise of the process's peak resident set (VmHWM) over its resident set
    after the imports, before the environments and learner are built (so it includes the 100
    training textures, 100 MB, and compiled code); on CUDA, ``torch.cuda.max_memory_allocated``;
  * **stage breakdown** (``aectorch.profiling.StageTimer`` over the timed iterations): render,
    encode (split, in eager mode, into patches and sparse coding by timing
    ``extract_patches`` alone on the same images), RL, dictionary update, env kinematics,
    metrics; the depth LM refit is timed once on 2000 stored trials and amortised over the
    256 trials x 60 iterations between refits;
  * **FLOPs per env-iteration** (``torch.utils.flop_counter.FlopCounterMode`` over one
    iteration at B = 64: matrix products, which dominate) and the **floor** they imply at the
    machine's sustained float32 matmul rate, measured in the same run on the loop's own
    largest product ([B x 113 patches, 200] x [200, 288]).

Usage:
    python benchmarks/train_step.py                    # the full sweep (about 20 minutes on 2 cores)
    python benchmarks/train_step.py --quick            # B = 1, 16, 64; 1 thread; eager and compile
    python benchmarks/train_step.py --device cuda --renderers torch --batches 256 4096 16384
    python benchmarks/train_step.py --leak 10000 --batches 16 --json benchmarks/results/train_step_leak.json
    python benchmarks/train_step.py --interleave pyrender:1:eager torch:64:eager torch:64:compile \
        --json benchmarks/results/train_step_interleaved.json     # ratios robust to the VM's drift

Writes a table to stdout, JSON to benchmarks/results/train_step.json (--json) and the plots to
docs/figures/train_step.png (--plot; ``--plot-only <json>`` redraws them).
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
FIT_TRIALS = 2000          # stored trials the amortised depth refit is timed on
REFIT_EVERY_TRIALS = 256   # LearnerConfig.depth_every_trials
#: ``--learner``: the learner settings measured. ``recorded`` is what benchmarks/results/*.json and
#: docs/performance.md were measured with (the defaults until 2026-12-01).
_TWO_SCALE = {"scales": ("coarse", "fine"),
              "actions_deg": (-2.0, -1.0, -0.5, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)}
LEARNERS = {
    "recorded": {**_TWO_SCALE, "symmetry": None},  # the tables of 2026-12-01, before the symmetries
    "two-scale": _TWO_SCALE,                        # the defaults until 2026-12-02 (with the symmetries)
    "default": {},
}
_LEARNER_VARIABLE = "AECTORCH_BENCH_LEARNER"  # passes --learner on to the worker processes


def _learner_name() -> str:
    return os.environ.get(_LEARNER_VARIABLE, "recorded")


def learner_config():
    """The ``LearnerConfig`` of ``--learner`` (the workers read it from the environment)."""
    from aectorch.framework import LearnerConfig, default_cues

    # each cue's settings (CueConfig fields), the same for both cues
    return LearnerConfig(cues=default_cues(**LEARNERS[_learner_name()]))


TRIAL_ITERATIONS = 60      # 2 fixations x h = 30


def env_protocol() -> dict:
    """The body movement of the measured runs: train.py's defaults for ``--learner default``
    (the shift over 20 iterations, yoked pursuit), the instant shift for the recorded tables."""
    if _learner_name() != "default":
        return {"shift_iterations": 1, "yoked_pursuit": False}
    from aectorch.sim import DEFAULT_PROTOCOL

    return {"shift_iterations": DEFAULT_PROTOCOL.shift_iterations, "yoked_pursuit": DEFAULT_PROTOCOL.yoked_pursuit}


def _rss_mb(field: str = "VmRSS") -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _reset_peak() -> None:
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:  # pragma: no cover - not Linux
        pass


def matmul_rate(batch: int, device: str, repeats: int = 20) -> float:
    """Sustained float32 FLOP/s of the loop's largest product at this B."""
    import torch

    a = torch.randn(batch * 113, 200, device=device)
    b = torch.randn(200, 288, device=device)
    out = torch.empty(batch * 113, 288, device=device)
    times = []
    for _ in range(repeats + 2):
        if device == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        for _ in range(10):
            torch.mm(a, b, out=out)
        if device == "cuda":
            torch.cuda.synchronize()
        times.append((time.perf_counter() - t) / 10)
    return 2 * a.shape[0] * 200 * 288 / statistics.median(times[2:])


def flops_per_env_iteration(device: str) -> float:
    """Matrix-product FLOPs of one learning iteration at B = 64, per environment."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from aectorch.framework import JointLearner
    from aectorch.sim import ActiveDepthEnv

    batch = 64
    env = ActiveDepthEnv(batch, seed=0, device=device, **env_protocol())
    learner = JointLearner(learner_config(), generator=torch.Generator().manual_seed(0), device=device)
    learner.iteration(env)  # so that the next one also updates the actor-critics
    # With the torch backend: FlopCounterMode cannot see the matrix product inside the fused
    # pursuit operator, and the work is the same whichever backend does it.
    from aectorch.coding import use_backend

    with use_backend("torch"), FlopCounterMode(display=False) as counter:
        learner.iteration(env)
    return counter.get_total_flops() / batch


def depth_refit_seconds(device: str) -> float:
    """One Levenberg-Marquardt refit of the depth MLP on FIT_TRIALS stored trials."""
    import torch

    from aectorch.framework import JointLearner

    learner = JointLearner(learner_config(), generator=torch.Generator().manual_seed(0), device=device)
    g = torch.Generator().manual_seed(1)
    d = 1 + 2 * torch.rand(FIT_TRIALS, generator=g, dtype=torch.float64)
    pursuit = torch.rad2deg(torch.atan(0.1 / d))
    vergence = torch.rad2deg(2 * torch.atan(0.03 / d))
    q = torch.stack((-pursuit, vergence, pursuit, vergence), -1) + 0.05 * torch.randn(FIT_TRIALS, 4, generator=g, dtype=torch.float64)
    learner.depth_learner.inputs = q.to(learner.depth_inputs)
    learner.depth_learner.targets = d.to(learner.depth_targets)
    start = time.perf_counter()
    learner.fit_depth(seed=0)
    return time.perf_counter() - start


def build(renderer: str, batch: int, mode: str, device: str):
    """The measured environments and learner; ``mode`` ``compile`` (``train.compile=true``) or
    ``cudagraphs`` (the encoders compiled with CUDA graphs, ``mode="reduce-overhead"``; GPU only)."""
    import torch

    from aectorch.runtime import compile_hot_path
    from aectorch.framework import JointLearner
    from aectorch.sim import ActiveDepthEnv

    env = ActiveDepthEnv(batch, renderer=renderer, seed=0, device=device, **env_protocol())
    learner = JointLearner(learner_config(), generator=torch.Generator().manual_seed(0), device=device)
    if mode == "compile":
        compile_hot_path(learner, env)
    elif mode == "cudagraphs":
        for cue in ("parallax", "stereo"):
            getattr(learner, cue).compile(mode="reduce-overhead")
    return env, learner


def _timed_iteration(learner, env, device: str) -> float:
    """Seconds of one learner iteration (the GPU synchronised before and after)."""
    import torch

    if device == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    learner.iteration(env)
    if device == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - start


def measure(renderer: str, batch: int, mode: str, iterations: int, warmup: int, device: str) -> dict:
    import torch

    from aectorch.coding import extract_patches
    from aectorch.coding.patches import reduced_patches
    from aectorch.profiling import StageTimer

    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
        base_cuda = torch.cuda.memory_allocated()
    base = _rss_mb()
    _reset_peak()
    env, learner = build(renderer, batch, mode, device)
    compile_start = time.perf_counter()
    for _ in range(warmup):
        learner.iteration(env)
    warmup_s = time.perf_counter() - compile_start
    times = []
    with StageTimer(device if device == "cuda" else None) as timer:
        for _ in range(iterations):
            times.append(_timed_iteration(learner, env, device))
    median = statistics.median(times)
    per_iteration = {name: seconds / iterations for name, seconds in timer.seconds.items()}
    stages = {name: per_iteration.get(name, 0.0) for name in ("render", "encode", "rl", "dictionary", "env", "metrics")}
    if mode == "eager":
        # Split "encode" into patches and sparse coding (+ pooling, errors) on the same images.
        scaled = learner.stereo.encoder.scales if learner.config.render_scales else None
        pair = env.stereo_observation()["window"] if scaled is None else env.stereo_observation(scales=scaled)
        patch_times = []
        for _ in range(max(3, min(iterations, 10))):
            start = time.perf_counter()
            for scale in learner.stereo.encoder.scales:
                if scaled is None:
                    extract_patches(pair[:, 0], pair[:, 1], scale, check_finite=False)
                else:
                    reduced_patches(pair[scale.name][:, 0], pair[scale.name][:, 1], scale)
            if device == "cuda":
                torch.cuda.synchronize()
            patch_times.append(time.perf_counter() - start)
        patches = min(2 * statistics.median(patch_times), stages["encode"])
        stages["patches"], stages["coding"] = patches, stages.pop("encode") - patches
    else:
        stages["encode (compiled)"] = stages.pop("encode")
    row = {
        "renderer": renderer, "B": batch, "mode": mode, "device": device,
        "threads": torch.get_num_threads(),
        "median_iteration_s": median,
        "env_iterations_per_s": batch / median,
        "warmup_s": warmup_s,
        "stage_s_per_iteration": stages,
        "stage_s_per_iteration_sum": sum(stages.values()),
        "peak_rss_mb": _rss_mb("VmHWM") - base,
    }
    if device == "cuda":
        row["peak_cuda_mb"] = (torch.cuda.max_memory_allocated() - base_cuda) / 2**20
    env.close()
    return row


def leak(iterations: int, batch: int, device: str, samples: int = 50) -> dict:
    """Resident memory over a long run: is there growth beyond the bounded depth store?"""
    import torch

    from aectorch.framework import JointLearner
    from aectorch.sim import ActiveDepthEnv

    env = ActiveDepthEnv(batch, seed=0, device=device, **env_protocol())
    learner = JointLearner(learner_config(), generator=torch.Generator().manual_seed(0), device=device)
    every = max(1, iterations // samples)
    trace = []
    start = time.perf_counter()
    for i in range(1, iterations + 1):
        learner.iteration(env)
        if i % every == 0 or i == iterations:
            trace.append((i, _rss_mb(), torch.cuda.memory_allocated() / 2**20 if device == "cuda" else None))
    half = [(i, m) for i, m, _ in trace if i > iterations // 2]
    n = len(half)
    mean_i = sum(i for i, _ in half) / n
    mean_m = sum(m for _, m in half) / n
    slope = (sum((i - mean_i) * (m - mean_m) for i, m in half)
             / max(sum((i - mean_i) ** 2 for i, _ in half), 1e-12))
    return {"iterations": iterations, "B": batch, "seconds": time.perf_counter() - start,
            "rss_mb": [[i, m] for i, m, _ in trace],
            "cuda_mb": [[i, c] for i, _, c in trace] if device == "cuda" else None,
            "slope_mb_per_1000_iterations_second_half": 1000 * slope,
            "depth_samples_stored": int(learner.depth_inputs.shape[0])}


def interleave(configs: list[str], rounds: int, block: int, warmup: int, device: str) -> list[dict]:
    """Several configurations in one process, timed in alternating blocks.

    The VM's speed drifts by 25 % or more within minutes; alternating blocks of ``block``
    iterations for ``rounds`` rounds exposes every configuration to the same drift, so their
    ratios are trustworthy where separate runs are not.
    """
    import torch

    setups = []
    for text in configs:
        renderer, batch, mode = text.split(":")
        env, learner = build(renderer, int(batch), mode, device)
        for _ in range(warmup):
            learner.iteration(env)
        setups.append((text, int(batch), env, learner, []))
    for _ in range(rounds):
        for _, _, env, learner, times in setups:
            for _ in range(block):
                times.append(_timed_iteration(learner, env, device))
    return [{"config": text, "B": batch, "threads": torch.get_num_threads(),
             "median_iteration_s": statistics.median(times),
             "env_iterations_per_s": batch / statistics.median(times), "iterations": len(times)}
            for text, batch, _, _, times in setups]


def worker(args) -> dict:
    """One configuration (or, with --extras, the FLOP count, matmul rates and the depth refit)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    sys.path.insert(0, str(ROOT))
    import torch

    threads = int(os.environ["OMP_NUM_THREADS"])
    torch.set_num_threads(threads)
    if args.leak:
        return leak(args.leak, args.batches[0], args.device)
    if args.interleave:
        return {"rows": interleave(args.interleave, args.rounds, args.block, args.warmup, args.device)}
    if args.extras:
        return {
            "threads": threads,
            "matmul_flops_per_s": {str(b): matmul_rate(b, args.device) for b in args.batches},
            "depth_refit_s": depth_refit_seconds(args.device),
            "flops_per_env_iteration": flops_per_env_iteration(args.device),
        }
    (renderer,), (batch,), (mode,) = args.renderers, args.batches, args.modes
    return measure(renderer, batch, mode, args.iterations, args.warmup, args.device)


def plot(report: dict, path: Path) -> None:
    """Throughput against B (left) and the stage breakdown per env-iteration (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["rows"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6))
    styles = {("torch", "eager"): ("C0", "-"), ("torch", "compile"): ("C0", "--"),
              ("pyrender", "eager"): ("C3", "-"), ("pyrender", "compile"): ("C3", "--")}
    for (renderer, mode), (colour, line) in styles.items():
        for threads, marker in ((1, "o"), (2, "s")):
            points = sorted((r["B"], r["env_iterations_per_s"]) for r in rows
                            if r["renderer"] == renderer and r["mode"] == mode and r["threads"] == threads)
            if points:
                left.plot(*zip(*points), color=colour, linestyle=line, marker=marker,
                          label=f"{renderer}, {mode}, {threads} thread{'s' if threads > 1 else ''}")
    left.set(xscale="log", yscale="log", xlabel="environments B", ylabel="env-iterations / s",
             title="(a) training-loop throughput")
    left.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=7)
    names = ["render", "patches", "coding", "encode (compiled)", "rl", "dictionary", "env", "metrics"]
    chosen = [r for r in rows if r["threads"] == 1 and r["renderer"] == "torch"]
    labels = [f"B={r['B']}\n{r['mode']}" for r in chosen]
    bottom = [0.0] * len(chosen)
    for i, name in enumerate(names):
        heights = [1e3 * r["stage_s_per_iteration"].get(name, 0.0) / r["B"] for r in chosen]
        if any(heights):
            right.bar(range(len(chosen)), heights, bottom=bottom, label=name, color=f"C{i}")
            bottom = [b + h for b, h in zip(bottom, heights)]
    right.set_xticks(range(len(chosen)), labels, fontsize=7)
    right.set(ylabel="ms per env-iteration", title="(b) where the time goes (torch renderer, 1 thread)")
    right.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--learner", choices=sorted(LEARNERS), default=None,
                        help="recorded: the learner of the recorded tables (2 scales, 13 actions, no "
                             "symmetries; the default); two-scale: the same with the symmetries (the "
                             "defaults until 2026-12-02); default: today's LearnerConfig() (3 scales, 11 actions)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--modes", nargs="+", default=["eager", "compile"], choices=["eager", "compile", "cudagraphs"])
    parser.add_argument("--renderers", nargs="+", default=["torch", "pyrender"], choices=["torch", "pyrender"])
    parser.add_argument("--iterations", type=int, default=20, help="timed iterations per configuration")
    parser.add_argument("--warmup", type=int, default=3, help="untimed iterations first (compilation)")
    parser.add_argument("--pyrender-max-batch", type=int, default=256,
                        help="skip pyrender above this B (its cost is per frame)")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--quick", action="store_true", help="B = 1, 16, 64 on 1 thread, 10 timed iterations")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "train_step.json")
    parser.add_argument("--plot", type=Path, default=ROOT / "docs" / "figures" / "train_step.png",
                        help="where to draw throughput vs B and the stage breakdown")
    parser.add_argument("--plot-only", type=Path, default=None, metavar="JSON",
                        help="only redraw --plot from an earlier run's JSON")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--extras", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--leak", type=int, default=0, metavar="ITERATIONS",
                        help="instead of the sweep: resident memory over this many iterations at the "
                             "first --batches B, one thread (JSON to --json)")
    parser.add_argument("--interleave", nargs="+", default=None, metavar="RENDERER:B:MODE",
                        help="instead of the sweep: these configurations in one process, timed in "
                             "alternating blocks (robust ratios), on each of --threads")
    parser.add_argument("--rounds", type=int, default=10, help="--interleave: rounds of blocks")
    parser.add_argument("--block", type=int, default=3, help="--interleave: iterations per block")
    args = parser.parse_args()
    if args.learner is not None:  # the workers inherit it; a worker without --learner keeps its parent's
        os.environ[_LEARNER_VARIABLE] = args.learner
    if args.interleave and not args.worker:
        report = {"benchmark": "train_step --interleave", "learner": _learner_name(), "rounds": args.rounds, "block": args.block, "rows": []}
        for threads in args.threads:
            env = dict(os.environ, OMP_NUM_THREADS=str(threads), LP_NUM_THREADS=str(threads),
                       MKL_NUM_THREADS=str(threads), PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"))
            command = [sys.executable, __file__, "--worker", "--interleave", *args.interleave,
                       "--rounds", str(args.rounds), "--block", str(args.block), "--warmup", str(args.warmup),
                       "--device", args.device]
            result = subprocess.run(command, env=env, stdout=subprocess.PIPE, text=True, check=True)
            rows = json.loads(result.stdout.strip().splitlines()[-1])["rows"]
            first = rows[0]["env_iterations_per_s"]
            print(f"\n{threads} thread(s), {args.rounds} rounds of {args.block} iterations each, medians:")
            print(f"| configuration | env-it/s | x {rows[0]['config']} |\n|---|---:|---:|")
            for row in rows:
                row["ratio_to_first"] = row["env_iterations_per_s"] / first
                print(f"| {row['config']} | {row['env_iterations_per_s']:,.1f} | {row['ratio_to_first']:.2f}x |")
            report["rows"] += rows
        sys.path.insert(0, str(ROOT))
        from benchmarks.machine import machine_info

        report["machine"] = machine_info()
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {args.json}")
        return
    if args.plot_only is not None:
        plot(json.loads(args.plot_only.read_text()), args.plot)
        print(f"wrote {args.plot}")
        return
    if args.quick:
        args.batches, args.threads, args.iterations = [1, 16, 64], [1], 10
    if args.leak and not args.worker:
        env = dict(os.environ, OMP_NUM_THREADS="1", PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"))
        command = [sys.executable, __file__, "--worker", "--leak", str(args.leak), "--device", args.device,
                   "--batches", str(args.batches[0])]
        result = subprocess.run(command, env=env, stdout=subprocess.PIPE, text=True, check=True)
        report = json.loads(result.stdout.strip().splitlines()[-1])
        rss = report["rss_mb"]
        print(f"B = {report['B']}: {report['iterations']} iterations in {report['seconds']:.0f} s; resident "
              f"{rss[0][1]:.0f} MB at iteration {rss[0][0]}, {max(m for _, m in rss):.0f} MB at most, "
              f"{rss[-1][1]:.0f} MB at the end; second-half slope "
              f"{report['slope_mb_per_1000_iterations_second_half']:+.2f} MB per 1000 iterations")
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"benchmark": "train_step --leak", "learner": _learner_name(), **report}, indent=2) + "\n")
        print(f"wrote {args.json}")
        return
    if args.worker:
        print(json.dumps(worker(args)))
        return

    def run(threads: int, *options: str) -> dict:
        # Every configuration in a fresh process: its peak memory is its own, and neither
        # compiled code nor allocator caches carry over from the one before.
        env = dict(os.environ, OMP_NUM_THREADS=str(threads), LP_NUM_THREADS=str(threads),
                   MKL_NUM_THREADS=str(threads), PYOPENGL_PLATFORM=os.environ.get("PYOPENGL_PLATFORM", "osmesa"))
        command = [sys.executable, __file__, "--worker", "--iterations", str(args.iterations),
                   "--warmup", str(args.warmup), "--device", args.device, *options]
        result = subprocess.run(command, env=env, stdout=subprocess.PIPE, text=True)
        if result.returncode != 0:
            raise SystemExit(f"worker {' '.join(options)} with {threads} thread(s) failed (exit {result.returncode})")
        return json.loads(result.stdout.strip().splitlines()[-1])

    rows, extras = [], []
    for threads in args.threads:
        extras.append(run(threads, "--extras", "--batches", *map(str, args.batches)))
        for renderer in args.renderers:
            for batch in args.batches:
                if renderer == "pyrender" and batch > args.pyrender_max_batch:
                    continue
                for mode in args.modes:
                    row = run(threads, "--renderers", renderer, "--batches", str(batch), "--modes", mode)
                    print(f"  {threads} thread(s) {renderer:8s} B={batch:5d} {mode:7s} "
                          f"{row['env_iterations_per_s']:9.1f} env-it/s", file=sys.stderr, flush=True)
                    rows.append(row)

    flops = extras[0]["flops_per_env_iteration"]
    rates = {(r["threads"], int(b)): v for r in extras for b, v in r["matmul_flops_per_s"].items()}
    refit = {r["threads"]: r["depth_refit_s"] for r in extras}
    baseline = {r["threads"]: r["env_iterations_per_s"] for r in rows
                if r["renderer"] == "pyrender" and r["B"] == 1 and r["mode"] == "eager"}
    for row in rows:
        rate = rates[(row["threads"], row["B"])]
        row["floor_env_iterations_per_s"] = rate / flops
        row["fraction_of_floor"] = row["env_iterations_per_s"] / row["floor_env_iterations_per_s"]
        row["depth_lm_s_per_env_iteration"] = refit[row["threads"]] / (REFIT_EVERY_TRIALS * TRIAL_ITERATIONS)
        if row["threads"] in baseline:
            row["speedup_vs_pyrender_B1"] = row["env_iterations_per_s"] / baseline[row["threads"]]

    print(f"\nEnv-iterations per second (median of {args.iterations} iterations after {args.warmup} warm-up), "
          f"device {args.device}; {flops / 1e6:.1f} MFLOP (matrix products) per env-iteration\n")
    print("| renderer | B | mode | threads | env-it/s | x pyrender B=1 | floor env-it/s | of floor | peak MB |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        speed = row.get("speedup_vs_pyrender_B1")
        memory = row.get("peak_cuda_mb", row["peak_rss_mb"])
        print(f"| {row['renderer']} | {row['B']} | {row['mode']} | {row['threads']} | "
              f"{row['env_iterations_per_s']:,.1f} | {'' if speed is None else f'{speed:.1f}x'} | "
              f"{row['floor_env_iterations_per_s']:,.0f} | {100 * row['fraction_of_floor']:.1f} % | {memory:,.0f} |")
    print("\nStage breakdown, ms per env-iteration (stage time of one learner iteration / B)\n")
    names = ["render", "patches", "coding", "encode (compiled)", "rl", "dictionary", "env", "metrics"]
    print("| renderer | B | mode | threads | " + " | ".join(names) + " | depth LM (amortised) |")
    print("|---|---:|---|---:|" + "---:|" * (len(names) + 1))
    for row in rows:
        stages = row["stage_s_per_iteration"]
        cells = [f"{1e3 * stages[n] / row['B']:.3f}" if n in stages else "" for n in names]
        print(f"| {row['renderer']} | {row['B']} | {row['mode']} | {row['threads']} | " + " | ".join(cells)
              + f" | {1e3 * row['depth_lm_s_per_env_iteration']:.4f} |")

    sys.path.insert(0, str(ROOT))
    from benchmarks.machine import machine_info

    report = {
        "benchmark": "train_step",
        "learner": _learner_name(),
        "machine": machine_info(),
        "iterations": args.iterations,
        "warmup": args.warmup,
        "flops_per_env_iteration": flops,
        "matmul_flops_per_s": {f"{t} threads, B={b}": v for (t, b), v in rates.items()},
        "depth_refit_s": refit,
        "rows": rows,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    plot(report, args.plot)
    print(f"\nwrote {args.json} and {args.plot}")


if __name__ == "__main__":
    main()
