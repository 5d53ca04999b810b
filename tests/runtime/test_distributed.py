"""torch.distributed (torchrun, gloo): 2 processes x B environments make the run 1 process x 2B makes."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from aectorch.framework import Shard
from aectorch.runtime import load_checkpoint
from aectorch.runs import Run

from tests.runtime.test_train import TINY, _lines, _without_time  # noqa: F401
from tests.runtime.test_train import textures  # noqa: F401  (the fixture)

ROOT = Path(__file__).resolve().parents[2]
QUIET = ["train.figures=false", "train.tensorboard=false", "eval.enabled=false", "train.progress=false"]


def _env() -> dict:
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    env.pop("AECTORCH_DEBUG", None)
    for key in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(key, None)
    return env


def _torchrun(*args: str, cwd: Path, nproc: int = 2) -> subprocess.CompletedProcess:
    torchrun = shutil.which("torchrun", path=str(Path(sys.executable).parent))
    assert torchrun is not None, "torchrun comes with torch"
    return subprocess.run([torchrun, "--standalone", f"--nproc_per_node={nproc}", str(ROOT / "train.py"), *args],
                          cwd=cwd, env=_env(), capture_output=True, text=True, timeout=600)


def _single(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, env=_env(),
                          capture_output=True, text=True, timeout=600)


def _tiny(textures: Path, num_envs: int, run: Path) -> list[str]:
    overrides = [o for o in TINY if not o.startswith(("env.num_envs", "train.progress"))]
    # The natural actor-critic: its batched update reduces over processes exactly; PPO's minibatches
    # are drawn per process, so a split batch is another (equally valid) run, not the same one.
    nac = [f"learner.cues.{cue}.agent=nac" for cue in ("parallax", "stereo")]
    return [*overrides, *QUIET, *nac, f"env.num_envs={num_envs}", f"env.textures={textures}", f"hydra.run.dir={run}"]


def _close(a, b, path="checkpoint"):
    if isinstance(a, torch.Tensor):
        assert a.shape == b.shape and a.dtype == b.dtype, path
        if a.is_floating_point():
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5, equal_nan=True, msg=path)
        else:
            assert torch.equal(a, b), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            _close(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{path}[{i}]")
    else:
        assert a == b, path


@pytest.mark.integration
def test_two_processes_with_b_envs_match_one_process_with_2b(tmp_path, textures):
    split, whole = tmp_path / "split", tmp_path / "whole"
    done = _torchrun(*_tiny(textures, 3, split), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-4000:]
    done = _single(*_tiny(textures, 6, whole), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-4000:]
    # one run folder, written by rank 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["split", "whole"]
    a, b = load_checkpoint(split / "checkpoint.pt"), load_checkpoint(whole / "checkpoint.pt")
    assert a["iteration"] == b["iteration"] == 12
    _close(a["learner"], b["learner"], "learner")  # dictionaries, policies, critics, depth data and MLP
    _close(a["metrics"], b["metrics"], "metrics")
    # the environments: the checkpoint holds the whole batch (rank 0's envs 0-2, then rank 1's 3-5)
    assert a["env"]["num_envs"] == 6
    _close(a["env"], b["env"], "env")
    lines_a, lines_b = _without_time(_lines(split)), _without_time(_lines(whole))
    assert [line["env_iterations"] for line in lines_a] == [line["env_iterations"] for line in lines_b]
    for x, y in zip(lines_a, lines_b):
        for key in x:
            if x[key] is None:
                assert y[key] is None, key
            else:
                assert x[key] == pytest.approx(y[key], rel=1e-4, abs=1e-5), key
    sessions = Run(split).provenance["sessions"]
    assert sessions[0]["world_size"] == 2
    # Resuming with another number of processes, and torchrun's restarts: tests/runtime/test_restarts.py.


@pytest.mark.integration
def test_multirun_sweep_through_the_submitit_launcher(tmp_path, textures):
    # submitit_local: the launcher that submitit_slurm is, with local subprocesses for jobs.
    sweep = tmp_path / "sweep"
    args = [o for o in _tiny(textures, 2, tmp_path / "unused") if not o.startswith("hydra.run.dir")]
    done = _single("-m", "hydra/launcher=submitit_local", "seed=0,1", "train.iterations=4",
                   *[a for a in args if not a.startswith("train.iterations")], f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-4000:]
    for job in ("0", "1"):
        assert load_checkpoint(sweep / job / "checkpoint.pt")["iteration"] == 4
    assert load_checkpoint(sweep / "0" / "checkpoint.pt")["config"]["seed"] == 0
    assert load_checkpoint(sweep / "1" / "checkpoint.pt")["config"]["seed"] == 1


def test_teardown_leaves_a_process_group_the_caller_made(tmp_path):
    import torch.distributed as dist

    from aectorch.runtime import distributed

    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'rendezvous'}", rank=0, world_size=1)
    try:
        assert distributed.setup(4) == Shard.single(4)  # one process: a shard of world size 1
        distributed.teardown()
        assert dist.is_initialized()  # still the caller's
    finally:
        dist.destroy_process_group()
