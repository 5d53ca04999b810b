"""Nothing lost when a run is started twice, a process dies, or the job moves.

- A new run into a folder that holds a run's ``checkpoint.pt`` stops before any write (status 2,
  one line); ``train.resume=auto`` continues it, ``train.overwrite=true`` starts afresh.
- ``torchrun --max-restarts`` with ``train.resume=auto``: a worker killed with SIGKILL, the group
  restarted, the run resumed from its last checkpoint and ended where an undisturbed run ends.
- A checkpoint holds the whole batch: a run of 2 processes resumes with 1, and one of 1 with 2.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from aectorch.framework.batch_state import gather_rows, take_rows
from aectorch.runtime import RunExists, build_env, build_learner, load_checkpoint, prepare_run, run_experiment
from aectorch.framework import Shard
from aectorch.runs import Run
from tests.runtime.test_distributed import _close, _env, _single, _tiny, _torchrun
from tests.runtime.test_train import QUIET, ROOT, TINY, _assert_same_state, _cfg, _lines  # noqa: F401
from tests.runtime.test_train import textures  # noqa: F401  (the fixture)


def _files(folder: Path) -> dict[str, str]:
    """Every file below ``folder`` (Hydra's included) and the hash of its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _run(tmp_path: Path, textures: Path, run: Path, *extra: str) -> subprocess.CompletedProcess:
    return _single(*TINY, *QUIET, f"env.textures={textures}", f"hydra.run.dir={run}", *extra, cwd=tmp_path)


@pytest.mark.integration
def test_a_rerun_into_a_finished_run_stops_before_any_write(tmp_path, textures):
    run, drawn = tmp_path / "R", ("train.figures=true", "train.tensorboard=true")
    done = _run(tmp_path, textures, run, *drawn)
    assert done.returncode == 0, done.stderr[-3000:]
    before = _files(run)
    assert {"checkpoint.pt", "metrics.jsonl", "summary.json", ".hydra/config.yaml"} <= before.keys()
    again = _run(tmp_path, textures, run, "train.iterations=5", "seed=2")
    lines = [line for line in again.stderr.splitlines() if line.strip()]
    assert again.returncode == 2 and len(lines) == 1, again.stderr[-3000:]
    assert lines[0].startswith("error: ") and str(run) in lines[0] and "iteration 12 of 12" in lines[0]
    assert f"train.resume={run}" in lines[0] and "another folder" in lines[0], lines[0]
    assert _files(run) == before  # byte-identical, Hydra's files and the lock included

    # train.resume=auto continues it; in a folder without a checkpoint it starts a new run.
    done = _run(tmp_path, textures, run, *drawn, "train.resume=auto", "train.iterations=14")
    assert done.returncode == 0, done.stderr[-3000:]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 14
    assert [line["iteration"] for line in _lines(run)] == list(range(2, 15, 2))
    fresh = tmp_path / "fresh"
    done = _run(tmp_path, textures, fresh, "train.resume=auto", "train.iterations=4")
    assert done.returncode == 0, done.stderr[-3000:]
    assert load_checkpoint(fresh / "checkpoint.pt")["iteration"] == 4

    # train.overwrite=true deletes the run's files and starts afresh.
    done = _run(tmp_path, textures, run, "train.overwrite=true", "train.iterations=4")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "train.overwrite: deleted checkpoint.pt" in done.stderr
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 4
    assert [line["iteration"] for line in _lines(run)] == [2, 4]
    assert not (run / "figures").exists() and not (run / "best.pt").exists()
    sessions = Run(run).provenance["sessions"]
    assert len(sessions) == 1 and sessions[0]["start_iteration"] == 0


@pytest.mark.integration
def test_the_library_refuses_too_and_resume_and_overwrite_exclude_each_other(tmp_path, textures):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    before = (run / "checkpoint.pt").read_bytes()
    with pytest.raises(RunExists, match=r"checkpoint.pt at iteration 2 of 2.*train.resume="):
        run_experiment(_cfg(textures, "train.iterations=4"), run)
    assert (run / "checkpoint.pt").read_bytes() == before
    run_experiment(_cfg(textures, "train.iterations=4", "train.resume=auto"), run)
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 4
    with pytest.raises(ValueError, match=r"train.overwrite=true starts a run afresh and train.resume=auto"):
        _cfg(textures, "train.resume=auto", "train.overwrite=true")


@pytest.mark.integration
def test_a_share_that_changes_the_whole_batch_is_refused(tmp_path, textures, monkeypatch):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=2", "env.num_envs=6"), run)
    monkeypatch.setenv("WORLD_SIZE", "2")  # as torchrun sets it for 2 processes
    cfg, _ = prepare_run(_cfg(textures, f"train.resume={run}"), {"train.resume"})
    assert cfg.env.num_envs == 3  # the checkpoint's 6 environments over 2 processes
    with pytest.raises(ValueError, match=r"env.num_envs=4 with 2 process\(es\) makes a batch of 8, but the "
                                         r"checkpoint .* holds 6 environments; give env.num_envs=3"):
        prepare_run(_cfg(textures, f"train.resume={run}", "env.num_envs=4"), {"train.resume", "env.num_envs"})
    monkeypatch.setenv("WORLD_SIZE", "4")
    with pytest.raises(ValueError, match=r"holds 6 environments, which 4 processes cannot share evenly"):
        prepare_run(_cfg(textures, f"train.resume={run}"), {"train.resume"})


@pytest.mark.integration
def test_a_relaunched_sweep_is_refused_and_resumes_with_auto(tmp_path, textures):
    sweep = tmp_path / "sweep"
    args = ["-m", *TINY, *QUIET, f"env.textures={textures}", "seed=0,1", "train.iterations=4",
            f"hydra.sweep.dir={sweep}"]
    done = _single(*args, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    before = _files(sweep)
    again = _single(*args, cwd=tmp_path)
    assert again.returncode == 2 and "holds 2 run(s) of an earlier sweep" in again.stderr, again.stderr[-3000:]
    assert "train.resume=auto" in again.stderr and _files(sweep) == before
    done = _single(*[a for a in args if a != "train.iterations=4"], "train.iterations=6", "train.resume=auto",
                   cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    for job in ("0", "1"):
        assert load_checkpoint(sweep / job / "checkpoint.pt")["iteration"] == 6


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _rank_of(pid: int) -> int | None:
    try:
        environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    except OSError:
        return None
    ranks = [int(item[5:]) for item in environ if item.startswith(b"RANK=")]
    return ranks[0] if ranks else None


@pytest.mark.integration
def test_torchrun_restarts_a_killed_worker_and_the_run_resumes_to_the_undisturbed_result(tmp_path, textures):
    """Real torchrun (2 processes, gloo, ``--max-restarts=2``), a real SIGKILL of rank 1 mid-run;
    the restarted group resumes ``checkpoint.pt`` (``train.resume=auto``) and ends equal to one
    undisturbed process with the whole batch, within the reductions' summation order (NAC)."""
    iterations = ["train.iterations=60", "train.checkpoint_every=2"]
    run = tmp_path / "elastic"
    args = [*_tiny(textures, 3, run), *iterations, "train.resume=auto"]
    torchrun = shutil.which("torchrun", path=str(Path(sys.executable).parent))
    job = subprocess.Popen([torchrun, "--standalone", "--nproc_per_node=2", "--max-restarts=2",
                            str(ROOT / "train.py"), *args], cwd=tmp_path, env=_env(),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed_at = None
    try:
        deadline = time.monotonic() + 400
        while killed_at is None:
            assert job.poll() is None, "the run ended before a worker was killed: " + job.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the run made no checkpoint to resume from"
            if (run / "checkpoint.pt").exists():
                held = load_checkpoint(run / "checkpoint.pt")["iteration"]
                if held >= 6:
                    workers = [pid for pid in _children(job.pid) if _rank_of(pid) == 1]
                    if workers:
                        os.kill(workers[0], signal.SIGKILL)
                        killed_at = held
            time.sleep(0.05)
        _, stderr = job.communicate(timeout=600)
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()
    assert job.returncode == 0, stderr[-4000:]
    assert killed_at < 60
    sessions = Run(run).provenance["sessions"]
    assert len(sessions) == 2 and sessions[1]["start_iteration"] >= killed_at, sessions  # one restart, resumed
    lines = _lines(run)
    assert [line["iteration"] for line in lines] == list(range(2, 61, 2))  # no gap, no duplicate

    whole = tmp_path / "whole"
    done = _single(*_tiny(textures, 6, whole), *iterations, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    a, b = load_checkpoint(run / "checkpoint.pt"), load_checkpoint(whole / "checkpoint.pt")
    assert a["iteration"] == b["iteration"] == 60
    _close(a["learner"], b["learner"], "learner")
    _close(a["metrics"], b["metrics"], "metrics")
    _close(a["env"], b["env"], "env")


def test_a_batch_state_split_over_processes_joins_back_to_the_whole(textures):
    """The per-environment state (the pending transitions, PPO's rollout, the environments)
    taken row by row and joined again is the whole batch's, exactly."""
    cfg = _cfg(textures, "env.num_envs=6", "env.fixation_iterations=5")
    env, learner = build_env(cfg, Shard.single(6)), build_learner(cfg, shard=Shard.single(6))
    for _ in range(3):  # mid-fixation: pending transitions and a rollout in the state
        learner.iteration(env)
    state, env_state = learner.state_dict(), env.state_dict()
    rollout = state["cues.stereo.agent._extra_state"]["rollout"]
    assert rollout and rollout[0]["features"].shape[0] == 12  # the transitions, then their mirror images
    parts = [take_rows(learner, state, 0, 2, 6), take_rows(learner, state, 2, 6, 6)]
    assert parts[1]["cues.stereo._extra_state"]["previous"][0].shape[0] == 4
    assert torch.equal(parts[1]["cues.stereo.agent._extra_state"]["rollout"][0]["features"],
                       torch.cat([rollout[0]["features"][2:6], rollout[0]["features"][8:12]]))
    # What each of two processes holding those rows hands `gather_objects`: its batch and its entries.
    held = [(2, {k: v for k, v in parts[0].items() if k.endswith("_extra_state")}),
            (4, {k: v for k, v in parts[1].items() if k.endswith("_extra_state")})]
    joined = gather_rows(learner, parts[0], lambda mine: held, 2)
    _assert_same_state(joined, state)
    with pytest.raises(ValueError, match="rows 4..6 are not within the 6 environments"):
        take_rows(learner, state, 4, 7, 6)
    rows = [type(env).state_rows(env_state, 0, 2), type(env).state_rows(env_state, 2, 6)]
    assert rows[1]["num_envs"] == 4 and rows[1]["q_deg"].shape[0] == 4
    _assert_same_state(type(env).join_states(rows), env_state)
    with pytest.raises(ValueError, match="rows 4..6 are not within the 6 environments"):
        type(env).state_rows(env_state, 4, 7)


def _resuming(args: list[str], run: Path, *extra: str) -> list[str]:
    """``args`` resuming ``run`` (into a folder of their own), ``env.num_envs`` left to the checkpoint."""
    return [a for a in args if not a.startswith(("env.num_envs=", "hydra.run.dir="))] + [
        f"train.resume={run}", f"hydra.run.dir={run}", *extra]


@pytest.mark.integration
def test_a_run_resumes_with_another_number_of_processes(tmp_path, textures):
    """Written by 2 processes of 3 environments, resumed by 1 of 6; written by 1 of 6, resumed by 2
    of 3: both continue the same run (NAC: equal within the reductions' summation order). With PPO,
    whose minibatches are each process's, the run trains on."""
    split, whole = tmp_path / "split", tmp_path / "whole"
    assert _torchrun(*_tiny(textures, 3, split), "train.iterations=7", cwd=tmp_path).returncode == 0
    assert _single(*_tiny(textures, 6, whole), "train.iterations=7", cwd=tmp_path).returncode == 0
    # env.num_envs: the checkpoint's 6 environments over this run's processes
    done = _single(*_resuming(_tiny(textures, 3, split), split, "train.iterations=10"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    done = _torchrun(*_resuming(_tiny(textures, 6, whole), whole, "train.iterations=10"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    a, b = load_checkpoint(split / "checkpoint.pt"), load_checkpoint(whole / "checkpoint.pt")
    assert a["iteration"] == b["iteration"] == 10 and a["env"]["num_envs"] == b["env"]["num_envs"] == 6
    _close(a["learner"], b["learner"], "learner")
    _close(a["metrics"], b["metrics"], "metrics")
    _close(a["env"], b["env"], "env")
    assert a["config"]["env"]["num_envs"] == 6 and b["config"]["env"]["num_envs"] == 3  # each session's share

    ppo = tmp_path / "ppo"
    args = [o for o in _tiny(textures, 6, ppo) if "agent=nac" not in o] + ["env.fixation_iterations=5"]
    assert _single(*args, "train.iterations=7", cwd=tmp_path).returncode == 0
    held = load_checkpoint(ppo / "checkpoint.pt")["learner"]["cues.stereo.agent._extra_state"]["rollout"]
    assert held and held[0]["features"].shape[0] == 12  # a rollout under way (and its mirror), split over 2 processes
    done = _torchrun(*_resuming(args, ppo, "train.iterations=12"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    final = load_checkpoint(ppo / "checkpoint.pt")
    assert final["iteration"] == 12 and all(torch.isfinite(t).all() for t in final["learner"].values()
                                            if isinstance(t, torch.Tensor) and t.is_floating_point())
