"""Start-up that nothing a user does can wedge: kernel builds killed or raced, caches
shared between checkouts, no PYOPENGL_PLATFORM, and kill -9 during training.

Each test runs real processes (train.py, or a kernel load) against its own kernel cache
(``AECTORCH_CACHE``), so the kernels are really built; on this project's 2-core machine a build
takes 10-60 s.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from aectorch.runtime import load_checkpoint
from tests.runtime.test_reliability import _assert_equal_everywhere
from tests.runtime.test_train import QUIET, ROOT, TINY, textures  # noqa: F401  (shared fixture)

pytestmark = pytest.mark.integration  # every test here runs training or a subprocess

_LOAD = "from aectorch.ops import native; import sys; sys.exit(0 if native.load() else 1)"


def _env(cache: Path, **extra) -> dict:
    env = dict(os.environ, AECTORCH_CACHE=str(cache), OMP_NUM_THREADS="1", **extra)
    env.pop("AECTORCH_DEBUG", None)
    env.pop("AECTORCH_NATIVE", None)
    return env


def _train(run: Path, textures: Path, env: dict, *extra: str, timeout: float = 300) -> subprocess.CompletedProcess:
    args = [*TINY, *QUIET, f"env.textures={textures}", f"hydra.run.dir={run}", *extra]
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=run.parent, env=env,
                          capture_output=True, text=True, timeout=timeout)


def _build_folder(cache: Path) -> Path:
    (folder,) = (cache / "native").iterdir()
    return folder


def test_a_kill_during_the_kernel_build_does_not_wedge_the_next_run(tmp_path, textures):
    cache = tmp_path / "cache"
    env = _env(cache)
    builder = subprocess.Popen([sys.executable, "-c", _LOAD], env=env, stderr=subprocess.PIPE, text=True)
    try:
        line = builder.stderr.readline()  # the first thing it says: it is compiling
        assert "compiling the fused CPU kernels" in line, line
        time.sleep(1.0)  # inside the compiler now (a build takes 10-60 s here)
        builder.send_signal(signal.SIGKILL)
        builder.wait(timeout=30)
    finally:
        builder.kill()
    folder = _build_folder(cache)
    assert not (folder / "built").exists(), "the build finished before the kill: no test"
    # The next run (a real train.py) takes over at once, says so in one line, builds and trains.
    run = _train(tmp_path / "run", textures, env, "train.iterations=2")
    assert run.returncode == 0, run.stderr[-3000:]
    assert "did not finish (it is no longer running); building again" in run.stderr, run.stderr[-2000:]
    assert "waiting for" not in run.stderr
    assert (folder / "built").exists() and load_checkpoint(tmp_path / "run" / "checkpoint.pt")["iteration"] == 2
    # Built: the next process loads it without a lock or a compiler (even with none on PATH).
    again = subprocess.run([sys.executable, "-c", _LOAD], env=_env(cache, CXX="/bin/false", PATH="/nonexistent"),
                           capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr[-2000:]


def test_two_processes_on_a_cold_cache_both_finish_and_build_once(tmp_path, textures):
    cache = tmp_path / "cache"
    env = _env(cache)
    runs = [tmp_path / "one", tmp_path / "two"]
    args = [*TINY, *QUIET, f"env.textures={textures}", "train.iterations=2"]
    procs = [subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args, f"hydra.run.dir={run}"],
                              cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for run in runs]
    try:
        outputs = [p.communicate(timeout=400) for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, (_, err) in zip(procs, outputs):
        assert p.returncode == 0, err[-3000:]
    assert sum("compiling the fused CPU kernels" in err for _, err in outputs) == 1  # one built, one waited
    for run in runs:
        assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 2


def test_another_checkout_reuses_the_built_kernels(tmp_path):
    """The cache is keyed by the sources' content, not by where the checkout lies."""
    cache = tmp_path / "cache"
    first = subprocess.run([sys.executable, "-c", _LOAD], env=_env(cache), capture_output=True, text=True,
                           timeout=400)
    assert first.returncode == 0 and "compiling" in first.stderr, first.stderr[-2000:]
    copy = tmp_path / "elsewhere"
    shutil.copytree(ROOT / "aectorch", copy / "aectorch", ignore=shutil.ignore_patterns("__pycache__"))
    second = subprocess.run([sys.executable, "-c", _LOAD], cwd=copy, env=_env(cache, PYTHONPATH=str(copy)),
                            capture_output=True, text=True, timeout=400)
    assert second.returncode == 0 and "compiling" not in second.stderr, second.stderr[-2000:]
    check = subprocess.run([sys.executable, "-c", "import aectorch; print(aectorch.__file__)"], cwd=copy,
                           env=_env(cache, PYTHONPATH=str(copy)), capture_output=True, text=True)
    assert check.stdout.strip().startswith(str(copy))  # it really was the other checkout


def test_pyrender_trains_without_pyopengl_platform_in_the_environment(tmp_path, textures):
    env = _env(Path(os.environ.get("AECTORCH_CACHE", Path.home() / ".cache" / "aectorch")))
    env.pop("PYOPENGL_PLATFORM", None)
    run = _train(tmp_path / "run", textures, env, "env.renderer=pyrender", "train.iterations=2", "env.num_envs=1")
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    # and a script's own `import aectorch` chooses the platform before pyrender needs it
    code = ("import os, aectorch; from aectorch.sim import ActiveDepthEnv, TrialProtocol; "
            "env = ActiveDepthEnv(1, protocol=TrialProtocol(renderer='pyrender'), "
            "textures=__import__('torch').rand(2, 16, 16)); "
            "print(os.environ['PYOPENGL_PLATFORM'], tuple(env.stereo_observation()['window'].shape))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split()[0] == "osmesa", out.stderr[-2000:]
    # the user's own value is respected: a platform pyrender cannot use here ends in one line
    bad = _train(tmp_path / "bad", textures, dict(env, PYOPENGL_PLATFORM="wgl"), "env.renderer=pyrender",
                 "train.iterations=2", timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr[-2000:]
    assert bad.stderr.strip().startswith("error:") and "pyrender" in bad.stderr


def test_kill_9_at_any_moment_then_resume_is_bit_identical(tmp_path, textures):
    env = _env(Path(os.environ.get("AECTORCH_CACHE", Path.home() / ".cache" / "aectorch")),
               PYOPENGL_PLATFORM="osmesa")
    straight = _train(tmp_path / "straight", textures, env, "train.iterations=120", "train.checkpoint_every=2")
    assert straight.returncode == 0, straight.stderr[-2000:]
    run = tmp_path / "run"
    args = [*TINY, *QUIET, f"env.textures={textures}", f"hydra.run.dir={run}", "train.iterations=120",
            "train.checkpoint_every=2"]
    for delay in (0.0, 0.35, 0.8):  # after the first checkpoint: mid-iteration, mid-write, ...
        proc = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args,
                                 *([f"train.resume={run}"] if (run / "checkpoint.pt").exists() else [])],
                                cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 240
            before = (run / "checkpoint.pt").stat().st_mtime_ns if (run / "checkpoint.pt").exists() else None
            while proc.poll() is None and time.monotonic() < deadline:
                path = run / "checkpoint.pt"
                if path.exists() and path.stat().st_mtime_ns != before:
                    break
                time.sleep(0.02)
            time.sleep(delay)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
        finally:
            proc.kill()
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] < 120  # the kills did cut the run short
    resumed = _train(tmp_path / "run", textures, env, "train.iterations=120", "train.checkpoint_every=2",
                     f"train.resume={run}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    _assert_equal_everywhere(load_checkpoint(tmp_path / "straight" / "checkpoint.pt"),
                             load_checkpoint(run / "checkpoint.pt"))
    assert torch.equal(torch.tensor(load_checkpoint(run / "checkpoint.pt")["iteration"]), torch.tensor(120))
