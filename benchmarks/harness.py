"""The benchmark suite's harness: the size, the default run, interleaved rounds, timing and results.

The tests (``benchmarks/test_*.py``) run at a tiny size unless ``AECTORCH_BENCH=full``; with
``AECTORCH_BENCH_SAVE=<folder>`` a run writes each suite's rows there as ``<suite>.<machine>.json``
in one schema (`check`), with the provenance of `aectorch.runtime.provenance`.
"""

from __future__ import annotations

import functools
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import torch
import torch.utils.benchmark

from aectorch.runtime.provenance import cpu_model, provenance

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCHEMA = "aectorch-benchmark/1"
SUITES = ("train_rate", "loop", "coding", "render", "depth", "rl_envs")
FULL = {"tiny": False, "full": True}.get(os.environ.get("AECTORCH_BENCH", "tiny"))
if FULL is None:
    raise ValueError(f"AECTORCH_BENCH must be 'tiny' or 'full', got {os.environ['AECTORCH_BENCH']!r}")
#: What a CPU without AVX-512 executes, on this machine's cores: set before torch starts (`isa`).
AVX2 = {"AECTORCH_NATIVE_MARCH": "x86-64-v3", "ATEN_CPU_CAPABILITY": "avx2", "MKL_ENABLE_INSTRUCTIONS": "AVX2",
        "ONEDNN_MAX_CPU_ISA": "AVX2"}
_rows: dict[tuple[str, str], list[dict]] = {}


def size(tiny, full):
    """``full`` under ``AECTORCH_BENCH=full``, else ``tiny``: every size of a benchmark goes through here."""
    return full if FULL else tiny


def isa() -> str:
    """``"avx2"`` under the `AVX2` variables, else ``"native"``."""
    return "avx2" if all(os.environ.get(k) == v for k, v in AVX2.items()) else "native"


@functools.cache
def default_run(num_envs: int, device: str = "cpu"):
    """train.py's default environments and learner (``ExperimentConfig()``) at B = ``num_envs``,
    built once per process. At the tiny size the 100 default textures are four small ones."""
    from aectorch.runtime import ExperimentConfig, build_env, build_learner
    from aectorch.sim import ActiveDepthEnv, TextureBank

    cfg = ExperimentConfig()
    cfg.env.num_envs, cfg.env.device = num_envs, device
    env = build_env(cfg) if FULL else ActiveDepthEnv(
        num_envs, textures=TextureBank.procedural(4, size=(96, 96), seed=0), seed=cfg.seed, device=device)
    return env, build_learner(cfg)


def interleaved(workloads: dict[str, Callable[[], object]], rounds: int, calls: int = 1, warmup: int = 1,
                clock: Callable[[], float] = time.perf_counter) -> dict[str, list[float]]:
    """Seconds per call of each workload, in ``rounds`` rounds that each run every workload ``calls`` times
    in turn, so a shared machine's drift hits all alike: compare ratios within one run, not across runs."""
    if rounds < 1 or calls < 1:
        raise ValueError(f"rounds and calls must be >= 1, got {rounds} and {calls}")
    for fn in workloads.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {name: [] for name in workloads}
    for _ in range(rounds):
        for name, fn in workloads.items():
            for _ in range(calls):
                start = clock()
                fn()
                times[name].append(clock() - start)
    return times


def median_seconds(fn: Callable[[], object], min_run_time: float | None = None) -> float:
    """Median seconds per call of ``fn`` by ``torch.utils.benchmark`` (the tiny size: one call)."""
    timer = torch.utils.benchmark.Timer(stmt="fn()", globals={"fn": fn}, num_threads=torch.get_num_threads())
    return timer.blocked_autorange(min_run_time=min_run_time or 1.0).median if FULL or min_run_time else timer.timeit(1).median


def worktree(commit: str) -> Path:
    """A git worktree of ``commit`` in the temporary folder (``compare.sh`` uses the same), made once."""
    folder = Path(os.environ.get("TMPDIR", "/tmp")) / f"aectorch-{commit}"
    if not (folder / "train.py").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(folder), commit], check=True)
    return folder


def train_py(overrides: list[str], cwd: Path = ROOT, env: dict | None = None) -> float:
    """Wall seconds of one ``python train.py`` process in ``cwd`` with this Python (evaluation,
    figures, TensorBoard, checkpoints and the progress bar off); raises with its stderr if it fails."""
    import tempfile

    quiet = ["eval.enabled=false", "train.figures=false", "train.progress=false", "train.tensorboard=false",
             "train.checkpoint_every=100000"]
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "train.py", f"hydra.run.dir={out}", *quiet, *overrides], cwd=cwd,
                              env={"PYOPENGL_PLATFORM": "osmesa", **os.environ, **(env or {})},
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wall = time.perf_counter() - start
    if done.returncode:
        raise RuntimeError(f"train.py {' '.join(overrides)} in {cwd} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return wall


def machine(device: str = "cpu") -> dict:
    """What a result is filed under: the CPU, its widest vectors, its cores, the GPU (where one ran), torch."""
    import platform

    gpu = torch.cuda.get_device_name(torch.device(device)) if torch.device(device).type == "cuda" else None
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    return {"cpu": cpu_model(), "vectors": next((v for v in ("avx512", "avx2") if f" {v}" in flags), None),
            "cores": os.cpu_count(), "gpu": gpu, "torch": torch.__version__, "platform": platform.platform()}


def slug(record: dict) -> str:
    """A machine record's file-name part: ``nvidia-h200``, ``amd-epyc-avx512-2c``."""
    name = record.get("gpu") or re.sub(r"\((r|tm)\)|processor|cpu\b|@.*", "", record["cpu"].lower()) + " " + (
        record.get("vectors") or "") + f" {record['cores']}c"
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def record(suite: str, rows: list[dict], benchmark=None, device: str = "cpu") -> None:
    """Files ``rows`` (one dict per variant, ``"variant"`` naming it) under ``suite`` for this run's
    results (`save`), checked against the schema; also into pytest-benchmark's ``extra_info``."""
    check({"schema": SCHEMA, "suite": suite, "machine": machine(device), "rows": rows})
    _rows.setdefault((suite, device), []).extend(rows)
    if benchmark is not None:
        benchmark.extra_info.update({row["variant"]: {k: v for k, v in row.items() if k != "variant"} for row in rows})


def save(folder: Path, command: str) -> list[Path]:
    """Writes each suite's rows of this run to ``folder/<suite>.<machine>.json``, in place of the rows of
    the same variants there (each row keeps its run's ``measured`` time); returns the paths."""
    import json

    written = []
    for (suite, device), rows in _rows.items():
        info = provenance(device)
        document = {"schema": SCHEMA, "suite": suite, "machine": machine(device), "command": command,
                    "provenance": info, "rows": [dict(row, measured=info["started"]) for row in rows]}
        path = Path(folder) / f"{suite}.{slug(document['machine'])}.json"
        kept = json.loads(path.read_text())["rows"] if path.exists() else []
        document["rows"][:0] = [r for r in kept if r["variant"] not in {row["variant"] for row in rows}]
        check(document, path.name)
        path.write_text(json.dumps(document, indent=1) + "\n")
        written.append(path)
    return written


def check(document: dict, name: str | None = None) -> None:
    """Raises ``ValueError`` naming what is wrong where ``document`` is not a result of the schema
    (and, given its file ``name``, where that is not ``<suite>.<machine>.json``)."""
    def need(ok: bool, what: str) -> None:
        if not ok:
            raise ValueError(f"{name or 'result'}: {what}")

    need(document.get("schema") == SCHEMA, f"schema must be {SCHEMA!r}, got {document.get('schema')!r}")
    need(document.get("suite") in SUITES, f"suite must be one of {SUITES}, got {document.get('suite')!r}")
    record_ = document.get("machine")
    need(isinstance(record_, dict) and {"cpu", "cores", "torch"} <= set(record_),
         f"machine must hold cpu, cores and torch, got {record_!r}")
    rows = document.get("rows")
    need(isinstance(rows, list) and len(rows) > 0, "rows must be a non-empty list")
    for row in rows:
        need(isinstance(row.get("variant"), str), f"each row needs a 'variant' string, got {row!r:.200}")
        need(any(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row.values()),
             f"row {row['variant']!r} holds no number")
    if name is not None:
        need(name == f"{document['suite']}.{slug(record_)}.json",
             f"the file of this suite and machine is {document['suite']}.{slug(record_)}.json")
