"""Two runs into one run folder: exactly one trains.

A second ``train.py`` into the folder of a running one (a new run with the same
``hydra.run.dir``, or ``train.resume``) exits at once, with status 2 and one ``error:`` line naming
the folder and the process that holds it; a holder killed with -9 keeps nothing locked, and the
resume that follows finishes the run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from aectorch.runtime import load_checkpoint
from aectorch.runtime.outputs import LOCK_NAME, RunFolder, RunFolderBusy
from tests.runtime.test_train import QUIET, ROOT, TINY, textures  # noqa: F401  (shared fixture)


def _env() -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYOPENGL_PLATFORM="osmesa")
    env.pop("AECTORCH_DEBUG", None)
    return env


def _train(cwd: Path, *args: str, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def test_a_folder_is_held_by_one_run_folder_at_a_time(tmp_path):
    first = RunFolder(tmp_path / "run")
    with pytest.raises(RunFolderBusy, match=rf"run folder .*run' is in use by process {os.getpid()}"):
        RunFolder(tmp_path / "run")
    first.release()
    RunFolder(tmp_path / "run").release()  # free again


@pytest.mark.integration
def test_a_second_run_into_a_running_folder_exits_at_once_and_a_killed_holder_locks_nothing(tmp_path, textures):
    run = tmp_path / "run"
    args = [*TINY, *QUIET, f"env.textures={textures}", "train.iterations=100000", "train.checkpoint_every=2"]
    holder = _train(tmp_path, *args, f"hydra.run.dir={run}")
    try:
        deadline = time.monotonic() + 300
        while not (run / "checkpoint.pt").exists():  # training, with a checkpoint to resume from
            assert holder.poll() is None, holder.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the first run did not start training"
            time.sleep(0.5)
        assert (run / LOCK_NAME).read_text().strip() == str(holder.pid)
        for second in ([*args, f"hydra.run.dir={run}"], [f"train.resume={run}"]):
            started = time.monotonic()
            out = _train(tmp_path, *second)
            _, stderr = out.communicate(timeout=120)
            lines = [line for line in stderr.splitlines() if line.strip()]
            assert out.returncode == 2, stderr[-3000:]
            assert len(lines) == 1 and lines[0].startswith("error: run folder") and str(run) in lines[0], stderr
            assert f"in use by process {holder.pid}" in lines[0]
            assert time.monotonic() - started < 60  # at once: nothing trained
        assert holder.poll() is None  # the first run trains on, untouched
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=60)
    finally:
        holder.kill()
        holder.wait(timeout=60)
    done = load_checkpoint(run / "checkpoint.pt")["iteration"]
    resumed = _train(tmp_path, f"train.resume={run}", f"train.iterations={done + 2}")
    _, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr[-3000:]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == done + 2
