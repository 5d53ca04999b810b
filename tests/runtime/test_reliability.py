"""Reliability: reproducible runs, whole-checkpoint equality on resume, the watchdog, provenance,
and bad files / contradictory options stopped before any work with one line."""

from __future__ import annotations

import json
import math
import re
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from aectorch.runtime import load_checkpoint, run_experiment, save_checkpoint
from aectorch.coding import EncoderConfig
from aectorch.framework import JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol
from aectorch.runtime.watchdog import Watchdog, WatchdogConfig, WatchdogError
from aectorch.runs import Run

from tests.runtime.test_train import ROOT, _cfg, _lines, _train, _without_time, TINY  # noqa: F401  (shared fixtures)
from tests.runtime.test_train import textures  # noqa: F401


def _assert_equal_everywhere(a, b, path="checkpoint"):
    """Every tensor and value of two checkpoints is equal (NaN equal to NaN), except the wall
    time and the config's record of where the run was resumed from."""
    assert type(a) is type(b), path
    if isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape, path
        assert torch.equal(a, b) or (a.is_floating_point() and torch.equal(a.isnan(), b.isnan())
                                     and torch.equal(a.nan_to_num(), b.nan_to_num())), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            if key != "elapsed_s" and f"{path}.{key}" != "checkpoint.config.train.resume":
                _assert_equal_everywhere(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_equal_everywhere(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), path
    else:
        assert a == b, path


# -- reproducible -----------------------------------------------------------------------------------
@pytest.mark.integration
def test_same_seed_and_config_give_the_same_run(tmp_path, textures):
    one, two = tmp_path / "one", tmp_path / "two"
    run_experiment(_cfg(textures), one)
    run_experiment(_cfg(textures), two)
    assert _without_time(_lines(one)) == _without_time(_lines(two))
    _assert_equal_everywhere(load_checkpoint(one / "checkpoint.pt"), load_checkpoint(two / "checkpoint.pt"))
    other = tmp_path / "other"
    run_experiment(_cfg(textures, "seed=1"), other)  # and the seed matters
    assert _without_time(_lines(one)) != _without_time(_lines(other))


@pytest.mark.integration
def test_planned_stop_and_sigterm_resume_to_the_same_checkpoint_tensors(tmp_path, textures):
    straight = tmp_path / "straight"
    run_experiment(_cfg(textures), straight)
    reference = load_checkpoint(straight / "checkpoint.pt")
    # a planned stop at 6 of 12, then resumed
    planned = tmp_path / "planned"
    run_experiment(_cfg(textures, "train.iterations=6"), planned)
    run_experiment(_cfg(textures, f"train.resume={planned}"), planned)
    # SIGTERM in the middle (during iteration 7's callbacks: the run stops when 7 is complete), then resumed
    killed = tmp_path / "killed"

    def terminate(done, record):
        if done == 7:
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        run_experiment(_cfg(textures), killed, callback=terminate)
    assert load_checkpoint(killed / "checkpoint.pt")["iteration"] == 7
    run_experiment(_cfg(textures, f"train.resume={killed}"), killed)
    for run in (planned, killed):
        _assert_equal_everywhere(reference, load_checkpoint(run / "checkpoint.pt"))
        # metrics continue without duplicates or gaps
        assert _without_time(_lines(run)) == _without_time(_lines(straight))


@pytest.mark.integration
def test_tensorboard_continues_without_duplicates_or_gaps(tmp_path, textures):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run = tmp_path / "run"
    cfg = ["train.tensorboard=true"]
    run_experiment(_cfg(textures, *cfg, "train.iterations=6"), run)
    run_experiment(_cfg(textures, *cfg, f"train.resume={run}"), run)
    events = EventAccumulator(str(run / "tb"))
    events.Reload()
    steps = [e.step for e in events.Scalars("pursuit_mae_deg")]
    assert steps == list(range(2, 13, 2))


@pytest.mark.integration
def test_the_nan_fill_of_new_tensors_changes_no_bit(tmp_path, textures, monkeypatch):
    """Deterministic runs leave torch's NaN fill of new tensors off (5 % of an iteration's CPU time):
    with it on, every bit of the checkpoint is the same, so the run reads no memory it did not write."""
    import aectorch.runtime as runtime

    filled = []
    cfg = _cfg(textures, "train.iterations=30", "train.checkpoint_every=30")
    run_experiment(cfg, tmp_path / "plain", callback=lambda done, record: filled.append(torch.empty(8).isnan().all()))
    monkeypatch.setattr(runtime, "FILL_UNINITIALIZED_MEMORY", True)
    run_experiment(cfg, tmp_path / "filled", callback=lambda done, record: filled.append(torch.empty(8).isnan().all()))
    assert len(filled) == 60 and torch.stack(filled[30:]).all()  # the fill was on in the second run
    assert torch.utils.deterministic.fill_uninitialized_memory  # restored for the caller
    _assert_equal_everywhere(load_checkpoint(tmp_path / "plain" / "checkpoint.pt"),
                             load_checkpoint(tmp_path / "filled" / "checkpoint.pt"))


# -- provenance --------------------------------------------------------------------------------------
@pytest.mark.integration
def test_run_folder_records_versions_commit_and_device(tmp_path, textures):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=4"), run)
    sessions = Run(run).provenance["sessions"]
    assert len(sessions) == 1
    info = sessions[0]
    import aectorch

    assert info["aectorch"] == aectorch.__version__ and info["torch"] == torch.__version__
    assert info["device"] == "cpu" and info["start_iteration"] == 0
    assert info["deterministic_algorithms"] is True
    assert info["git"] is None or len(info["git"]["commit"]) == 40
    assert not torch.are_deterministic_algorithms_enabled()  # restored for the caller
    run_experiment(_cfg(textures, f"train.resume={run}", "train.iterations=6"), run)
    resumed = Run(run)
    assert [s["start_iteration"] for s in resumed.provenance["sessions"]] == [0, 4]
    assert resumed.summary["provenance"]["start_iteration"] == 4


# -- the watchdog ------------------------------------------------------------------------------------
@pytest.mark.integration
def test_watchdog_stops_on_nan_and_keeps_the_last_healthy_checkpoint(tmp_path, textures, monkeypatch, caplog):
    learners = []  # the run's learner, captured as it is built (its real __init__ runs)
    build = JointLearner.__init__

    def capture(self, *args, **kwargs):
        build(self, *args, **kwargs)
        learners.append(self)

    def poison(done, record):  # what a diverging update does: one atom goes NaN
        if done == 5:
            with torch.no_grad():
                learners[0].stereo.encoder.dictionaries["fine"].atoms[3, 7] = float("nan")

    monkeypatch.setattr(JointLearner, "__init__", capture)
    run = tmp_path / "run"
    with pytest.raises(WatchdogError, match=r"non-finite values \(NaN or inf\) in learner\.cues\.stereo\.encoder\.dictionaries\.fine\.atoms at iteration 5"):
        run_experiment(_cfg(textures), run, callback=poison)
    checkpoint = load_checkpoint(run / "checkpoint.pt")
    assert checkpoint["iteration"] == 4
    assert all(bool(t.isfinite().all()) for t in checkpoint["learner"].values()
               if isinstance(t, torch.Tensor) and t.is_floating_point() and t.numel())
    # The resume command the stop printed works as printed: the run finishes from iteration 4.
    printed = re.search(r"python train\.py (train\.resume=\S+ watchdog\.mode=warn)", caplog.text)
    assert printed, caplog.text[-2000:]
    done = _train(*printed.group(1).split(), cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 12


def _record_and_learner():
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3),
                         textures=TextureBank.procedural(4, size=(64, 64), seed=0), seed=0)
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=16))), generator=torch.Generator().manual_seed(0))
    learner.iteration(env)
    return learner.iteration(env), learner  # the second has TD errors


def _with(record, cue: str, **fields):
    """``record`` with fields of one cue's record replaced."""
    return record._replace(cues={**record.cues, cue: record.cues[cue]._replace(**fields)})


def test_watchdog_detects_divergence_and_collapse():
    record, learner = _record_and_learner()
    healthy = Watchdog(WatchdogConfig())
    assert healthy.check(1, record, learner) == []
    exploding = _with(record, "parallax", td_error=torch.full((2,), 1e4))
    with pytest.raises(WatchdogError, match="parallax mean |TD error| 1e\\+04 > watchdog.td_error_max"):
        Watchdog(WatchdogConfig()).check(2, exploding, learner)
    collapsed = _with(record, "stereo", entropy=torch.zeros(2))
    dog = Watchdog(WatchdogConfig(entropy_window=3))
    assert dog.check(1, collapsed, learner) == [] and dog.check(2, collapsed, learner) == []
    with pytest.raises(WatchdogError, match=r"stereo policy entropy 0 nats \(mean of iterations 1-3\)"):
        dog.check(3, collapsed, learner)
    # one deterministic iteration in a window is a confident state, not a collapse
    dog = Watchdog(WatchdogConfig(entropy_window=3))
    assert [dog.check(i, r, learner) for i, r in ((1, collapsed), (2, record), (3, record))] == [[], [], []]
    # after the grace period a deterministic policy is fine
    late = Watchdog(WatchdogConfig(entropy_grace_iterations=20, entropy_window=3))
    assert [late.check(i, collapsed, learner) for i in (50, 51, 52)] == [[], [], []]
    # dead atoms: counted over a window
    dog = Watchdog(WatchdogConfig(dead_atoms_window=3))
    counts = torch.zeros_like(record.parallax.atom_counts)
    counts[:, :4] = 10  # 12 of 16 atoms never chosen
    dying = _with(record, "parallax", atom_counts=counts)
    assert dog.check(1, dying, learner) == [] and dog.check(2, dying, learner) == []
    with pytest.raises(WatchdogError, match=r"parallax dictionary \(scale 0\): 75% of the atoms never chosen"):
        dog.check(3, dying, learner)
    nan_reward = _with(record, "stereo", reward=torch.tensor([0.0, float("nan")]))
    with pytest.raises(WatchdogError, match="non-finite values .* in stereo reward at iteration 7"):
        Watchdog(WatchdogConfig()).check(7, nan_reward, learner)
    # finite values whose sum overflows are finite; infinities of either sign (whose sum is NaN) are not
    huge = _with(record, "stereo", reward=torch.tensor([3e38, 3e38]))
    assert Watchdog(WatchdogConfig()).check(8, huge, learner) == []
    for values in ([float("inf"), float("-inf")], [1.0, float("-inf")]):
        with pytest.raises(WatchdogError, match="non-finite values .* in parallax TD error at iteration 9"):
            Watchdog(WatchdogConfig()).check(9, _with(record, "parallax", td_error=torch.tensor(values)), learner)


def test_watchdog_warn_mode_warns_once_per_kind_and_off_mode_is_silent():
    record, learner = _record_and_learner()
    exploding = _with(record, "parallax", td_error=torch.full((2,), 1e4))
    dog = Watchdog(WatchdogConfig(mode="warn"))
    with pytest.warns(RuntimeWarning, match="TD error"):
        assert len(dog.check(1, exploding, learner)) == 1
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(dog.check(2, exploding, learner)) == 1  # reported, not warned again
        assert Watchdog(WatchdogConfig(mode="off")).check(1, exploding, learner) == []
    restored = Watchdog(WatchdogConfig(mode="warn"))
    restored.load_state_dict(dog.state_dict())
    assert restored.warned == {"td_error"}


@pytest.mark.parametrize("field, value", [
    ("mode", "loud"), ("td_error_max", 0), ("entropy_min_nats", -1.0), ("entropy_grace_iterations", -1), ("entropy_grace_iterations", 0.5), ("entropy_window", 0),
    ("dead_atoms_window", 0), ("dead_atoms_max_fraction", 0.0),
])
def test_watchdog_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=f"watchdog.{field} must be"):
        WatchdogConfig(**{field: value})


@pytest.mark.integration
def test_train_py_exits_3_with_one_watchdog_line_and_a_checkpoint(tmp_path, textures):
    run = tmp_path / "run"
    # A threshold below any TD error: the first learning step trips it.
    done = _train(*TINY, f"env.textures={textures}", "eval.enabled=false", "watchdog.td_error_max=1e-30",
                  f"hydra.run.dir={run}", cwd=tmp_path)
    assert done.returncode == 3, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("watchdog:")]
    assert len(lines) == 1 and "TD error" in lines[0] and "watchdog.td_error_max" in lines[0]
    assert "watchdog.mode=warn" in done.stderr
    # The first checkpoint (train.checkpoint_every=4) was not reached: iteration 0's was written.
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 0


# -- bad files and contradictions stop before any work ----------------------------------------------
@pytest.mark.integration
def test_unreadable_or_missing_images_are_named(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    broken = tmp_path / "broken"
    broken.mkdir()
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(broken / "good.png")
    (broken / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    for folder, expected in ((tmp_path / "missing", "no such folder"), (empty, "holds no images"),
                             (broken, "cannot read the image")):
        run = tmp_path / f"run-{folder.name}"
        done = _train(f"env.textures={folder}", f"hydra.run.dir={run}", cwd=tmp_path)
        assert done.returncode == 2, done.stderr[-2000:]
        errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and "env.textures" in errors[0] and expected in errors[0], done.stderr
        assert "Traceback" not in done.stderr
        assert not (run / "checkpoint.pt").exists() and not (run / "metrics.jsonl").exists()
        if folder is broken:
            assert "bad.png" in errors[0]


@pytest.mark.integration
def test_resume_rejects_contradicting_options_and_incompatible_checkpoints(tmp_path, textures):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=4"), run)
    common = [*TINY, f"env.textures={textures}", "eval.enabled=false", f"train.resume={run}"]
    done = _train(*common, "env.num_envs=7", cwd=tmp_path)
    assert done.returncode == 2
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "env.num_envs=7 with 1 process(es) makes a batch of 7, but the checkpoint" in errors[0]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 4  # nothing was touched
    # A checkpoint whose learner state does not fit its config (another aectorch version, say).
    payload = load_checkpoint(run / "checkpoint.pt")
    payload["learner"] = {k: v for k, v in payload["learner"].items() if "stereo" not in k}
    save_checkpoint(run / "checkpoint.pt", payload)
    done = _train(*common, cwd=tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "learner state" in errors[0] and "checkpoint.pt" in errors[0], done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.integration
def test_recording_without_lerobot_says_where_it_lives(tmp_path, textures):
    try:
        import lerobot  # noqa: F401
    except ImportError:
        pass
    else:  # .venv-lerobot: the recording itself is tested in tests/lerobot
        return
    done = _train(*TINY, f"env.textures={textures}", f"record.lerobot={tmp_path / 'ds'}",
                  f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert done.returncode == 2
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "record.lerobot needs LeRobot" in errors[0] and ".venv-lerobot" in errors[0]
    import subprocess
    import sys

    run = tmp_path / "tiny"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    done = subprocess.run([sys.executable, "-m", "aectorch.record", f"checkpoint={run / 'checkpoint.pt'}",
                           f"out={tmp_path / 'cli'}"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "needs LeRobot" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without CUDA")
def test_cuda_device_without_cuda_is_rejected_before_any_work(textures):
    from aectorch.runtime.resources import validate_resources

    with pytest.raises(ValueError, match="env.device='cuda', but this torch .* sees no CUDA device"):
        validate_resources(_cfg(textures, "env.device=cuda"))


@pytest.mark.integration
def test_a_checkpoint_with_other_watchdog_options_still_resumes(tmp_path, textures):
    # The watchdog (and recording) sections come from the command line on resume: options of
    # another aectorch version stored there must not block it.
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=4"), run)
    payload = load_checkpoint(run / "checkpoint.pt")
    payload["config"]["watchdog"]["entropy_grace_fraction"] = 0.1  # an option this version lacks
    save_checkpoint(run / "checkpoint.pt", payload)
    run_experiment(_cfg(textures, f"train.resume={run}", "train.iterations=6"), run)
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 6


@pytest.mark.integration
def test_resume_after_a_kill_that_tore_the_last_metrics_line(tmp_path, textures):
    # SIGKILL (out of memory, a hard scheduler limit) can cut a metrics line in half.
    straight, run = tmp_path / "straight", tmp_path / "run"
    run_experiment(_cfg(textures), straight)
    run_experiment(_cfg(textures, "train.iterations=8"), run)
    with (run / "metrics.jsonl").open("a") as f:
        f.write('{"iteration": 10, "env_iterations": 5')  # torn, after the checkpoint's iteration 8
    run_experiment(_cfg(textures, f"train.resume={run}"), run)
    assert _without_time(_lines(run)) == _without_time(_lines(straight))


@pytest.mark.integration
def test_sigterm_while_finishing_leaves_a_run_that_resume_finishes_without_training(tmp_path, textures):
    """SIGTERM during the final evaluation: status 130 and one line naming the resume command; the
    folder holds the finished training and no half-written result; ``train.resume=`` then writes
    the evaluation and the summary without training again."""
    run = tmp_path / "run"
    args = [*TINY, f"env.textures={textures}", f"eval.textures={textures}", "env.fixation_iterations=30",
            "train.tensorboard=false", f"hydra.run.dir={run}"]
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    process = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=tmp_path, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not (run / "figures" / "training.png").exists():  # drawn just before the evaluation
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()[1][-3000:]
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr[-3000:]
    assert "interrupted while finishing the run" in stderr and f"train.resume={run}" in stderr
    assert "Traceback" not in stderr
    assert not (run / "summary.json").exists() and not (run / "evaluation.json").exists()
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 12
    metrics = (run / "metrics.jsonl").read_text()
    done = _train(f"train.resume={run}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (run / "metrics.jsonl").read_text() == metrics  # no iteration was trained again
    summary = Run(run).summary
    assert summary["iterations"] == 12 and "evaluation" in json.dumps(summary)
    assert Run(run).evaluation()["trials"] > 0


@pytest.mark.integration
@pytest.mark.parametrize("limit_bytes", [4000, 200])
def test_a_full_disk_stops_the_run_and_keeps_a_checkpoint_that_resumes_to_the_same_result(tmp_path, textures,
                                                                                          limit_bytes):
    """A file-size limit (RLIMIT_FSIZE: writes fail with EFBIG, as on a full disk) set after the
    checkpoint of iteration 4 was written: the next write fails (metrics.jsonl or checkpoint.pt,
    by the limit), the run stops with `WriteFailed` naming the file, the checkpoint of iteration 4
    still loads, and resumed without the limit the run ends bit-identical to an uninterrupted one."""
    import resource

    from aectorch.runtime.outputs import WriteFailed

    straight = tmp_path / "straight"
    run_experiment(_cfg(textures), straight)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)

    def fill_the_disk(done, record):
        if done == 5:  # the checkpoint of iteration 4 is written
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, hard))

    full = tmp_path / "full"
    try:
        with pytest.raises(WriteFailed, match=r"cannot write .*(metrics\.jsonl|checkpoint\.pt): File too large"):
            run_experiment(_cfg(textures), full, callback=fill_the_disk)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert load_checkpoint(full / "checkpoint.pt")["iteration"] == 4
    assert not [p.name for p in full.iterdir() if p.name.endswith(".tmp")]  # no half-written file left
    run_experiment(_cfg(textures, f"train.resume={full}"), full)
    _assert_equal_everywhere(load_checkpoint(straight / "checkpoint.pt"), load_checkpoint(full / "checkpoint.pt"))
    assert _without_time(_lines(full)) == _without_time(_lines(straight))


@pytest.mark.integration
def test_train_py_says_which_write_failed_and_how_to_resume(tmp_path, textures):
    run = tmp_path / "run"
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    done = subprocess.run(["prlimit", "--fsize=100000", sys.executable, str(ROOT / "train.py"), *TINY,
                           f"env.textures={textures}", "eval.enabled=false", f"hydra.run.dir={run}"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 4, done.stderr[-3000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "cannot write" in lines[0] and f"train.resume={run}" in lines[0], done.stderr[-2000:]
    assert "Traceback" not in done.stderr


def test_a_full_disk_under_tensorboard_raises_one_write_failed_and_a_resume_purges_the_later_events(tmp_path,
                                                                                                    capfd):
    """TensorBoard writes in its own thread; `RunFolder.log_line` flushes it, so a failed write
    stops the run like one of metrics.jsonl (`WriteFailed` naming tb/, no thread traceback), and
    a resume (purge_step) hides the events after its checkpoint from TensorBoard's reader."""
    import resource

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from aectorch.runtime.outputs import RunFolder, WriteFailed

    folder = RunFolder(tmp_path / "run")
    folder.start({}, {}, resumed_at=None, tensorboard=True)
    line = {"iteration": 0, **{f"k{k}": float(k) for k in range(30)}}  # short keys: TensorBoard grows faster
    with folder.open_metrics() as file:
        folder.log_line(file, line)
        events = next((tmp_path / "run" / "tb").iterdir())
        soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (events.stat().st_size + 100, hard))
        try:
            with pytest.raises(WriteFailed, match=r"cannot write .*tb: File too large"):
                for iteration in range(1, 10):
                    folder.log_line(file, {**line, "iteration": iteration})
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    folder.close()
    folder.release()
    assert "Traceback" not in capfd.readouterr().err  # the writer thread's failure is not printed
    assert (tmp_path / "run" / "metrics.jsonl").read_text().count("\n") == 2  # the line whose events failed
    resumed = RunFolder(tmp_path / "run")
    resumed.start({}, {}, resumed_at=0, tensorboard=True)
    with resumed.open_metrics() as file:
        resumed.log_line(file, {**line, "iteration": 1, "k0": 7.0})
    resumed.close()
    accumulator = EventAccumulator(str(tmp_path / "run" / "tb"))
    accumulator.Reload()
    scalars = accumulator.Scalars("k0")
    assert [(s.step, s.value) for s in scalars] == [(0, 0.0), (1, 7.0)]
