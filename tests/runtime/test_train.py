"""train.py and aectorch.runtime: run folder, resume, interruption, config errors, presets."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from aectorch.runtime.config import ExperimentConfig, to_experiment_config
from aectorch.runtime.presets import LIFELONG, PAPER_PRESET, ROBUST_VERGENCE, ROLL_PERTURBATION
from aectorch.runtime.resources import validate_resources
from aectorch.runtime import CHECKPOINT_FORMAT, load_checkpoint, load_learner, run_experiment, save_checkpoint
from aectorch.runs import Run
from aectorch.sim import TrialProtocol
from aectorch.sim.movements.vergence import Vergence
from aectorch.coding.readouts import code_summary
from aectorch.control import PAPER_ACTIONS_DEG

ROOT = Path(__file__).resolve().parents[2]
TINY = [
    "env.num_envs=5", "env.fixation_iterations=2", "env.distances_m=[1.0,2.0]",
    "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16", "learner.depth_every_trials=10", "eval.distances_m=[1.0]",
    "eval.batch_size=8", "train.iterations=12", "train.log_every=2", "train.checkpoint_every=4",
    "train.progress=false",
]
QUIET = ["train.figures=false", "train.tensorboard=false", "eval.enabled=false"]


@pytest.fixture(scope="module")
def textures(tmp_path_factory) -> Path:
    from PIL import Image

    folder = tmp_path_factory.mktemp("textures")
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray((rng.random((64, 64)) * 255).astype(np.uint8)).save(folder / f"t{i}.png")
    return folder


def _cfg(textures: Path, *extra: str) -> ExperimentConfig:
    dotlist = TINY + QUIET + [f"env.textures={textures}", f"eval.textures={textures}", *extra]
    return to_experiment_config(OmegaConf.from_dotlist(dotlist))


def _train(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    env.pop("AECTORCH_DEBUG", None)
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _lines(run: Path) -> list[dict]:
    return Run(run).metrics


def _without_time(lines: list[dict]) -> list[dict]:
    return [{k: v for k, v in line.items() if k != "elapsed_s"} for line in lines]


def _assert_same_state(a, b, where: str = "state") -> None:
    """Equal nested states: tensors exactly, dicts key by key, sequences item by item, else ==."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.shape == b.shape and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for key in a:
            _assert_same_state(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same_state(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


@pytest.mark.integration
def test_train_py_writes_the_run_folder(tmp_path, textures):
    run = tmp_path / "run"
    done = _train(*TINY, f"env.textures={textures}", f"eval.textures={textures}",
                  "+experiment=roll_perturbation", f"hydra.run.dir={run}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    for name in ("config.yaml", "metrics.jsonl", "checkpoint.pt", "evaluation.json", "summary.json",
                 "figures/dictionaries.png", "figures/training.png", "figures/perturbation.png",
                 "figures/evaluation.png"):
        assert (run / name).is_file(), name
    assert any((run / "tb").iterdir())
    lines = _lines(run)
    assert [line["iteration"] for line in lines] == list(range(2, 13, 2))
    keys = {"iteration", "env_iterations", "elapsed_s", "roll_left_deg", "roll_right_deg", "perturbations",
            "pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m", "depth_recent_m",
            *(f"{m}_recent_{w}" for m in ("pursuit", "vergence") for w in ("deg", "1px"))}
    for cue in ("parallax", "stereo"):
        keys |= {f"{cue}/reward", f"{cue}/entropy", f"{cue}/td_error"}
        keys |= {f"{cue}/{s}/{m}" for s in ("wide", "coarse", "fine", "full") for m in ("error", "atom_usage")}
    assert set(lines[-1]) == keys and lines[-1]["env_iterations"] == 60
    # The roll: the right eye from iteration 4 (0-based, 0.4 of 12; line 6 reports after it), both from 9.
    deg = ROLL_PERTURBATION["perturbations"][0]["params"]["deg"]
    rolls = [(line["iteration"], line["roll_left_deg"], line["roll_right_deg"]) for line in lines]
    assert rolls == [(2, 0, 0), (4, 0, 0), (6, 0, deg), (8, 0, deg), (10, deg, deg), (12, deg, deg)]
    assert [line["perturbations"] for line in lines][1:5] == [[], ["right eye rolled"], ["right eye rolled"],
                                                              ["right eye rolled", "both eyes rolled"]]
    checkpoint = load_checkpoint(run / "checkpoint.pt")
    assert checkpoint["iteration"] == 12 and checkpoint["env"]["roll_deg"].eq(deg).all()
    assert set(checkpoint["initial_dictionaries"]) == {f"{cue}/{s}" for cue in ("parallax", "stereo")
                                                       for s in ("wide", "coarse", "fine", "full")}
    evaluation = Run(run).evaluation()
    assert evaluation["trials"] == 3
    summary = Run(run).summary
    assert summary["iterations"] == 12 and "evaluation" in summary
    # The learned code's read-outs, per dictionary: of its final state and of its random start.
    assert set(summary["code"]) == set(summary["code_initial"]) == set(checkpoint["initial_dictionaries"])
    atoms = checkpoint["learner"]["cues.stereo.encoder.dictionaries.fine.atoms"]
    assert summary["code"]["stereo/fine"] == json.loads(json.dumps(code_summary(atoms)))
    assert summary["code_initial"]["stereo/fine"] == json.loads(json.dumps(
        code_summary(checkpoint["initial_dictionaries"]["stereo/fine"])))
    assert (run / "figures" / "code.png").is_file()
    assert summary["final"] == {k: v for k, v in lines[-1].items() if k in summary["final"]}
    assert len(summary["final"]) == len(keys) - 6
    assert [e["iteration"] for e in summary["perturbation"]["events"]] == [5, 10]
    recovery = summary["perturbation"]["recovery"]["right eye rolled"]
    assert recovery["iteration"] == 4 and recovery["stop"] == 9 and recovery["vergence"]["key"] == "vergence_recent_deg"


@pytest.mark.integration
def test_resume_is_bit_identical(tmp_path, textures):
    import gc

    straight = tmp_path / "straight"
    frozen_before, frozen = gc.get_freeze_count(), []
    # (and the loop runs with the heap frozen, handed back to the collector afterwards)
    run_experiment(_cfg(textures), straight, callback=lambda it, record: frozen.append(gc.get_freeze_count()))
    assert len(frozen) == 12 and min(frozen) > frozen_before + 1000
    assert gc.get_freeze_count() == frozen_before
    half = tmp_path / "half"
    run_experiment(_cfg(textures, "train.iterations=6"), half)
    assert load_checkpoint(half / "checkpoint.pt")["iteration"] == 6
    run_experiment(_cfg(textures, f"train.resume={half}"), tmp_path / "ignored")
    a, b = load_checkpoint(straight / "checkpoint.pt"), load_checkpoint(half / "checkpoint.pt")
    assert b["iteration"] == 12
    _assert_same_state(a["learner"], b["learner"])
    assert _without_time(_lines(straight)) == _without_time(_lines(half))
    assert not (tmp_path / "ignored").exists()


@pytest.mark.integration
@pytest.mark.parametrize("fault", ["ctrl-c", "error"])
def test_interruption_leaves_a_checkpoint_and_resume_completes(tmp_path, textures, monkeypatch, fault):
    """Ctrl-C in the middle of iteration 8 (its parallax step has learned) stops the run when the
    iteration is complete: checkpoint 8. An error there leaves the last checkpoint written (4,
    train.checkpoint_every=4). Either resumes to the uninterrupted run's state."""
    straight = tmp_path / "straight"
    run_experiment(_cfg(textures), straight)
    original = Vergence.act  # the stereo cue's movement: what the learner's step calls
    calls = {"n": 0}

    def failing(self, delta):
        calls["n"] += 1
        if calls["n"] == 8:
            if fault == "ctrl-c":
                os.kill(os.getpid(), signal.SIGINT)
            else:
                raise RuntimeError("a bug in the middle of an iteration")
        return original(self, delta)

    run = tmp_path / "run"
    monkeypatch.setattr(Vergence, "act", failing)
    with pytest.raises(KeyboardInterrupt if fault == "ctrl-c" else RuntimeError):
        run_experiment(_cfg(textures), run)
    monkeypatch.setattr(Vergence, "act", original)
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == (8 if fault == "ctrl-c" else 4)
    run_experiment(_cfg(textures, f"train.resume={run}"), run)
    _assert_same_state(load_checkpoint(straight / "checkpoint.pt")["learner"],
                       load_checkpoint(run / "checkpoint.pt")["learner"])
    assert _without_time(_lines(straight)) == _without_time(_lines(run))
    cfg, learner = load_learner(run / "checkpoint.pt")
    assert cfg.train.iterations == 12 and learner.parallax.encoder.dictionaries["coarse"].atoms.shape[1] == 16


@pytest.mark.integration
def test_sigterm_checkpoints_the_last_completed_iteration(tmp_path, textures):
    # kill, timeout and batch schedulers send SIGTERM: it must not lose the run.
    import signal

    straight = tmp_path / "straight"
    run_experiment(_cfg(textures), straight)

    def terminate(done, record):
        if done == 5:
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt, match="signal"):
        run_experiment(_cfg(textures), run, callback=terminate)
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is restored
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 5  # the iteration it arrived in, completed
    run_experiment(_cfg(textures, f"train.resume={run}"), run)
    _assert_same_state(load_checkpoint(straight / "checkpoint.pt")["learner"],
                       load_checkpoint(run / "checkpoint.pt")["learner"])


@pytest.mark.integration
def test_train_py_exits_130_without_a_traceback_on_sigterm(tmp_path, textures):
    # The command line: one message with the checkpoint and how to resume, status 130, no traceback.
    import signal
    import time

    run = tmp_path / "run"
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    env.pop("AECTORCH_DEBUG", None)
    args = [*TINY, *QUIET, "train.iterations=100000", f"env.textures={textures}", f"hydra.run.dir={run}"]
    proc = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not (run / "checkpoint.pt").exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-2000:]
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and f"train.resume={run}" in err, err[-2000:]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] >= 4


def test_checkpoint_errors_name_the_path(tmp_path):
    with pytest.raises(ValueError, match="no checkpoint at .*missing.pt"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        load_checkpoint(tmp_path / "bad.pt")
    save_checkpoint(tmp_path / "ok.pt", {"format": CHECKPOINT_FORMAT, "config": {}, "x": 1})
    assert load_checkpoint(tmp_path / "ok.pt")["x"] == 1
    save_checkpoint(tmp_path / "newer.pt", {"format": CHECKPOINT_FORMAT + 1, "config": {}})
    with pytest.raises(ValueError, match=f"newer.pt.*format {CHECKPOINT_FORMAT + 1} is not one this aectorch reads"):
        load_checkpoint(tmp_path / "newer.pt")
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


@pytest.mark.parametrize("override, field", [
    ("env.num_envs=0", "env.num_envs"),
    ("env.renderer=opengl", "env.renderer"),
    ("env.textures=/nonexistent", "env.textures"),
    ("train.iterations=abc", "train.iterations"),
    ("nosuchkey=1", "nosuchkey"),
    ("perturbation.roll_deg=3.0", None),  # valid
    ("perturbation.first_fraction=0.9", None),  # valid without a roll
    ("+experiment=roll_perturbation", None),
    ("+experiment=slip", None),
    ("+experiment=robust_vergence", None),
    ("+experiment=lifelong", None),
    ("env.velocity_memory=true", "env.velocity_memory"),
])
def test_config_errors_name_the_field(override, field, textures):
    from hydra import compose, initialize

    from aectorch.runtime.store import register_configs

    register_configs()
    with initialize(version_base=None, config_path=None):
        try:
            raw = compose(config_name="train", overrides=[override])
            cfg = to_experiment_config(raw)
            validate_resources(cfg)
        except Exception as err:  # Hydra's override errors or our ValueError
            assert field is not None, err
            text = f"{err} {err.__cause__ or ''}"
            assert field in text, text
        else:
            assert field is None


@pytest.mark.integration
def test_bad_override_exits_2_before_any_work(tmp_path):
    run = tmp_path / "run"
    for override, field in (("env.num_envs=0", "env.num_envs"), ("train.iterations=abc", "train.iterations")):
        done = _train(override, f"hydra.run.dir={run}", cwd=tmp_path)
        assert done.returncode == 2, done.stderr[-2000:]
        errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and field in errors[0], done.stderr[-2000:]
        assert not (run / "checkpoint.pt").exists() and not (run / "metrics.jsonl").exists()


def _value(cfg, dotted: str):
    node = cfg
    for part in dotted.split("."):
        node = node[part] if isinstance(node, dict) else getattr(node, part)
    return list(node) if isinstance(node, tuple) else node


def test_preset_paper_and_perturbation_fractions():
    from hydra import compose, initialize

    from aectorch.runtime.config import PerturbationConfig
    from aectorch.runtime.store import register_configs

    register_configs()
    with initialize(version_base=None, config_path=None):
        default = to_experiment_config(compose(config_name="train"))
        paper = to_experiment_config(compose(config_name="train", overrides=["preset=paper", "learner.cues.parallax.encoder.num_atoms=32", "learner.cues.stereo.encoder.num_atoms=32"]))
        roll = to_experiment_config(compose(config_name="train", overrides=["+experiment=roll_perturbation"]))
        robust = to_experiment_config(compose(config_name="train", overrides=["+experiment=robust_vergence"]))
        lifelong = to_experiment_config(compose(config_name="train", overrides=["+experiment=lifelong"]))
    # the robust_vergence preset too lists only what differs, and sets it
    assert all(_value(default, key) != value for key, value in ROBUST_VERGENCE.items()), ROBUST_VERGENCE
    assert all(_value(robust, key) == value for key, value in ROBUST_VERGENCE.items()), ROBUST_VERGENCE
    assert all(_value(default, key) != value for key, value in LIFELONG.items()), LIFELONG
    assert all(_value(lifelong, key) == value for key, value in LIFELONG.items()), LIFELONG
    parallax, stereo = lifelong.learner.cues["parallax"], lifelong.learner.cues["stereo"]
    assert parallax.learn_until == 2400 and parallax.reopen_drop is None
    assert stereo.learn_until == 24000 and stereo.reopen_drop == 0.1  # settles past the run, reopens on a fall
    for name, cue in paper.learner.cues.items():
        assert list(cue.actions_deg) == PAPER_PRESET[f"learner.cues.{name}.actions_deg"] == list(PAPER_ACTIONS_DEG)
        assert cue.encoder.num_atoms == 32  # the command line wins
        assert cue.symmetry is None and cue.scales == ("coarse", "fine")
    assert paper.env.fixation_iterations == 30
    # the preset lists only what differs from the defaults
    assert all(_value(default, key) != value for key, value in PAPER_PRESET.items()), PAPER_PRESET
    assert paper.train.iterations == 6000 and paper.env.shift_iterations == default.env.shift_iterations
    assert default.train.iterations == ExperimentConfig().train.iterations
    assert default.perturbation.roll_deg == 0 and not default.events()
    deg = ROLL_PERTURBATION["perturbations"][0]["params"]["deg"]
    assert roll.train.iterations == 3000
    assert [(e.start, e.eyes, e.perturbation.deg) for e in roll.events()] == [(1200, (1,), deg), (2400, (0,), deg)]
    # the old key: two roll events, the same as the list's
    short = PerturbationConfig(roll_deg=3.0).events(100)
    assert [(e.start, e.eyes, e.perturbation.deg, e.label) for e in short] == [
        (50, (1,), 3.0, "right eye rolled"), (75, (0,), 3.0, "both eyes rolled")]
    with pytest.raises(ValueError, match="perturbation.first_fraction"):
        PerturbationConfig(roll_deg=3.0, first_fraction=0.8, second_fraction=0.7)


@pytest.mark.integration
def test_multirun_makes_one_folder_per_seed(tmp_path, textures):
    sweep = tmp_path / "sweep"
    done = _train("-m", "seed=0,1", *TINY, *QUIET, "train.iterations=2", f"env.textures={textures}",
                  f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    for job in ("0", "1"):
        assert load_checkpoint(sweep / job / "checkpoint.pt")["config"]["seed"] == int(job)


@pytest.mark.integration
@pytest.mark.slow
def test_compile_gives_the_same_run_as_eager(tmp_path, textures):
    """train.compile=true: same metrics and learner state as eager, within float tolerance. On the
    torch backend (what CUDA runs), where the flag compiles the encoders; on CPU with the fused
    kernels it compiles nothing (`test_compile_leaves_the_fused_cpu_kernels_eager`)."""
    from aectorch.coding import use_backend

    runs = {}
    for mode in ("false", "true"):
        with use_backend("torch"):
            summary = run_experiment(_cfg(textures, f"train.compile={mode}", "train.iterations=6"),
                                     tmp_path / mode)
        assert summary["iterations"] == 6 and summary["final"]["parallax/reward"] < 0
        runs[mode] = (_lines(tmp_path / mode), load_checkpoint(tmp_path / mode / "checkpoint.pt")["learner"])
    (eager_lines, eager_state), (compiled_lines, compiled_state) = runs["false"], runs["true"]
    assert len(eager_lines) == len(compiled_lines)
    for a, b in zip(eager_lines, compiled_lines):
        for key, value in a.items():
            if key == "elapsed_s" or value is None:
                continue
            assert b[key] == pytest.approx(value, rel=1e-4, abs=1e-5), key
    # The wide scale's 6 x 6 patches come from four pyramid levels of smoothing, so their contrast
    # is low and normalising them amplifies float32 rounding: its features differ by up to ~2e-5
    # (relative) between the fused compiled kernels and eager (the other scales ~3e-7), and the
    # running feature variances (feature_m2) accumulate that to ~2e-4 over six iterations.
    for key, value in eager_state.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point():
            torch.testing.assert_close(compiled_state[key], value, rtol=1e-3, atol=1e-5, msg=key)


def test_compile_leaves_the_fused_cpu_kernels_eager():
    """On CPU the hot paths are the fused kernels: train.compile compiles nothing there (it measured
    0.87x eager), and on the torch backend it compiles both encoders and the renderer."""
    from aectorch.coding import use_backend
    from aectorch.ops import native
    from aectorch.runtime.builders import build_env, build_learner, compile_hot_path

    cfg = to_experiment_config(OmegaConf.from_dotlist(TINY))
    env, learner = build_env(cfg), build_learner(cfg)
    if native.available():
        assert compile_hot_path(learner, env) == []
        assert all(c.encoder._compiled_call_impl is None for c in learner.cues.values())
    with use_backend("torch"):
        assert compile_hot_path(learner, env) == ["parallax encoder", "stereo encoder", "renderer"]


@pytest.mark.integration
def test_keep_best_writes_the_best_training_window_and_evaluates_it(tmp_path, textures):
    cfg = _cfg(textures, "train.metrics_window=10", "eval.enabled=true")
    summary = run_experiment(cfg, tmp_path)
    lines = [line for line in _lines(tmp_path)
             if line["iteration"] * 5 // 2 >= 10]  # windows of 10 fixation ends (5 envs, h = 2)
    scores = {line["iteration"]: line["pursuit_mae_deg"] + line["vergence_mae_deg"] for line in lines}
    best_iteration = min(scores, key=lambda i: (scores[i], i))
    assert summary["best"]["iteration"] == best_iteration < 12  # not simply the last state
    assert summary["best"]["score"] == pytest.approx(scores[best_iteration])
    best = load_checkpoint(tmp_path / "best.pt")
    assert best["iteration"] == best_iteration and best["best"]["iteration"] == best_iteration
    assert summary["evaluation"]["checkpoint"] == "best.pt"
    assert "depth_calibration" not in summary and not (tmp_path / "calibrated.pt").exists()  # off by default
    # The evaluation is of best.pt's learner: evaluating it again gives the same numbers.
    from aectorch.evaluation import evaluate
    from aectorch.sim import TextureBank

    _, learner = load_learner(tmp_path / "best.pt")
    again = evaluate(learner, TextureBank.from_folder(textures),
                     protocol=TrialProtocol(fixation_iterations=2, shift_iterations=20, yoked_pursuit=True),
                     distances_m=[1.0], batch_size=8, progress=False)
    assert again["pursuit_mae_deg"] == pytest.approx(summary["evaluation"]["pursuit_mae_deg"])
    # Without keep_best nothing is chosen and the last state is evaluated.
    off = tmp_path / "off"
    summary = run_experiment(_cfg(textures, "train.metrics_window=10", "train.keep_best=false", "eval.enabled=true"), off)
    assert "best" not in summary and not (off / "best.pt").exists()
    assert summary["evaluation"]["checkpoint"] == "checkpoint.pt"


@pytest.mark.integration
def test_depth_calibration_refits_the_evaluated_mlp_on_greedy_training_trials(tmp_path, textures):
    five = "env.distances_m=[1.0,1.5,2.0,2.5,3.0]"
    summary = run_experiment(_cfg(textures, five, "train.metrics_window=10", "eval.enabled=true",
                                  "train.depth_calibration_trials=15"), tmp_path)
    done = summary["depth_calibration"]
    assert done["skipped"] is False and (done["textures"], done["trials"]) == (3, 15)
    assert summary["evaluation"]["checkpoint"] == "calibrated.pt"
    best, calibrated = load_checkpoint(tmp_path / "best.pt"), load_checkpoint(tmp_path / "calibrated.pt")
    assert calibrated["iteration"] == best["iteration"] and calibrated["depth_calibration"]["source"] == "best.pt"
    changed = {k for k, v in best["learner"].items()
               if isinstance(v, torch.Tensor) and not torch.equal(v, calibrated["learner"][k])}
    # Only the MLP moved (and its trained flag, when training had not fitted it yet).
    assert changed and all(k.startswith("depth_learner.mlp.") or k == "depth_learner.trained" for k in changed), changed
    # Its depth MAE on the 15 calibration trials (texture i mod 3, distance i mod 5: every pair
    # once) is what the summary says.
    from aectorch.evaluation import evaluate, run_trials
    from aectorch.sim import TextureBank

    _, learner = load_learner(tmp_path / "calibrated.pt")
    bank = TextureBank.from_folder(textures)
    trials = run_trials(learner, bank,
                        protocol=TrialProtocol(fixation_iterations=2, shift_iterations=20, yoked_pursuit=True),
                        distances_m=[1.0, 1.5, 2.0, 2.5, 3.0], batch_size=8, seed=0)
    assert trials["depth_error_m"].abs().mean().item() == pytest.approx(done["depth_mae_m_after"], rel=1e-5)
    # The evaluation is of calibrated.pt: evaluating it again gives the same numbers.
    again = evaluate(learner, bank,
                     protocol=TrialProtocol(fixation_iterations=2, shift_iterations=20, yoked_pursuit=True),
                     distances_m=[1.0], batch_size=8)
    assert again["depth_mae_m"] == pytest.approx(summary["evaluation"]["depth_mae_m"])
    off = run_experiment(_cfg(textures, five, "train.metrics_window=10", "eval.enabled=true",
                              "train.depth_calibration_trials=5"), tmp_path / "off")
    assert off["depth_calibration"] == {"trials": 5, "skipped": True}  # too few for a fit
    assert off["evaluation"]["checkpoint"] == "best.pt" and not (tmp_path / "off" / "calibrated.pt").exists()
    assert off["evaluation"]["pursuit_mae_deg"] == pytest.approx(summary["evaluation"]["pursuit_mae_deg"])


def test_start_spread_draws_the_training_start_states(textures):
    from aectorch.runtime import build_env

    plain = build_env(_cfg(textures))
    assert torch.all(plain.left_pan_deg == 0) and torch.all(plain.vergence_deg == 0)
    env = build_env(_cfg(textures, "env.pursuit_start_deg=1.0", "env.pursuit_start_spread_deg=3.0",
                         "env.vergence_start_spread_deg=0.5"))
    pan, vergence = env.left_pan_deg, env.vergence_deg
    assert pan.min() >= -2.0 and pan.max() <= 4.0 and pan.unique().numel() == pan.numel()
    assert vergence.abs().max() <= 0.5 and vergence.unique().numel() == vergence.numel()
    for override in ("env.pursuit_start_spread_deg=-1", "env.vergence_start_spread_deg=nan"):
        field = override.split("=")[0]
        with pytest.raises(ValueError, match=field.replace(".", r"\.")):
            _cfg(textures, override)


def test_the_oculomotor_range_is_on_by_default_and_reaches_the_environments_and_the_evaluation(textures):
    from aectorch.runtime import build_env

    cfg = _cfg(textures)
    assert cfg.env.pan_range_deg == [-45.0, 45.0] and cfg.env.vergence_range_deg == [-2.0, 40.0]
    env = build_env(_cfg(textures, "env.pan_range_deg=[-30,30]", "env.vergence_range_deg=[-1,20]"))
    assert env.pan_range_deg == (-30.0, 30.0) and env.vergence_range_deg == (-1.0, 20.0)
    env.apply_vergence(torch.full((env.num_envs,), -5.0))
    assert torch.allclose(env.vergence_deg, torch.full_like(env.vergence_deg, -1.0))
    protocol = _cfg(textures, "env.vergence_range_deg=[-1,20]").env.protocol
    assert protocol.vergence_range_deg == (-1.0, 20.0) and protocol.pan_range_deg == (-45.0, 45.0)
    for override, field in (("env.vergence_range_deg=[1,20]", "env.vergence_range_deg must hold 0"),
                            ("env.pan_range_deg=[-60,10]", "env.pan_range_deg must lie within the HOAP-3's"),
                            ("env.pan_range_deg=[1]", r"env.pan_range_deg must be a \(low, high\) pair")):
        with pytest.raises(ValueError, match=field):
            _cfg(textures, override)


@pytest.mark.integration
def test_fork_continues_a_run_with_changed_settings(tmp_path, textures, capsys, script):
    fork_run = script("fork_run")
    straight, source = tmp_path / "straight", tmp_path / "source"
    run_experiment(_cfg(textures), straight)
    run_experiment(_cfg(textures, "train.iterations=8"), source)
    # Without overrides a fork is a resume into another folder: bit-identical to the straight run.
    assert fork_run.main([str(source / "checkpoint.pt"), str(tmp_path / "same"), "--iterations", "12",
                          "--no-progress"]) == 0
    _assert_same_state(load_checkpoint(straight / "checkpoint.pt")["learner"],
                       load_checkpoint(tmp_path / "same" / "checkpoint.pt")["learner"])
    assert [line["iteration"] for line in _lines(tmp_path / "same")] == \
        [line["iteration"] for line in _lines(straight)]
    # With a frozen dictionary the dictionaries stay those of iteration 8, the policies move on.
    assert fork_run.main([str(source / "checkpoint.pt"), str(tmp_path / "frozen"), "learner.cues.parallax.encoder.lr=0", "learner.cues.stereo.encoder.lr=0",
                          "--iterations", "12", "--no-progress"]) == 0
    before = load_checkpoint(source / "checkpoint.pt")
    after = load_checkpoint(tmp_path / "frozen" / "checkpoint.pt")
    assert after["iteration"] == 12 and after["config"]["learner"]["cues"]["stereo"]["encoder"]["lr"] == 0
    atoms = [k for k in before["learner"] if k.endswith("atoms")]
    assert atoms and all(torch.equal(before["learner"][k], after["learner"][k]) for k in atoms)
    actor = "cues.parallax.agent.policy.weight"  # PPO, the default agent
    assert not torch.equal(before["learner"][actor], after["learner"][actor])
    assert load_checkpoint(source / "checkpoint.pt")["iteration"] == 8  # the source is untouched
    # A perturbation experiment forked from an unperturbed run: its events may start at the fork.
    # (in train.py's grammar, as docs/results.md writes it, and the options before or after it)
    assert fork_run.main([str(source / "checkpoint.pt"), str(tmp_path / "rolled"), "--iterations", "10",
                          "perturbations=[{kind:roll,start:8,eye:right,params:{deg:5}}]", "--no-progress"]) == 0
    assert load_checkpoint(tmp_path / "rolled" / "checkpoint.pt")["env"]["roll_deg"][0].tolist() == [0.0, 5.0]
    # Bad arguments stop before anything is written, naming what is wrong.
    for args, message in [(["learner.cues.stereo.encoder.lr=-1"], "learner.cues.stereo.encoder.lr"), (["nosuch.key=1"], "nosuch"),
                          (["perturbations=[{kind:roll"], "cannot be parsed"),
                          (["--iterations", "8"], "above the checkpoint's iteration 8")]:
        target = tmp_path / "bad"
        argv = [str(source / "checkpoint.pt"), str(target), *args]
        argv += [] if "--iterations" in args else ["--iterations", "12"]
        assert fork_run.main(argv) == 2
        assert message in capsys.readouterr().err and not target.exists()


def test_threads_zero_uses_every_core_shared_among_processes():
    from aectorch.runtime import available_threads

    cores = len(os.sched_getaffinity(0))
    assert available_threads() == cores
    assert available_threads(cores * 2) == 1
    assert to_experiment_config(OmegaConf.create({"train": {"threads": 0}})).train.threads == 0
    with pytest.raises(ValueError, match="threads"):
        to_experiment_config(OmegaConf.create({"train": {"threads": -1}}))


@pytest.mark.integration
def test_a_resume_reads_its_checkpoint_and_validates_its_resources_once(tmp_path, textures, monkeypatch):
    """The resume's rules live in `prepare_run`, which reads the checkpoint and checks the
    resources once; `run_experiment` given its result does neither again."""
    import aectorch.runtime.checkpoint as checkpoint_module
    from aectorch.runtime import prepare_run

    half = tmp_path / "half"
    run_experiment(_cfg(textures, "train.iterations=6"), half)
    calls = {"load": 0, "validate": 0}
    load, validate = checkpoint_module.load_checkpoint, checkpoint_module.validate_resources

    def counted_load(path):
        calls["load"] += 1
        return load(path)

    def counted_validate(cfg):
        calls["validate"] += 1
        return validate(cfg)

    monkeypatch.setattr(checkpoint_module, "load_checkpoint", counted_load)
    monkeypatch.setattr(checkpoint_module, "validate_resources", counted_validate)
    cfg, checkpoint = prepare_run(_cfg(textures, f"train.resume={half}"), {"train.resume"})
    assert cfg.train.iterations == 6 and checkpoint["iteration"] == 6  # the run's own, unless given
    cfg.train.iterations = 8
    run_experiment(cfg, tmp_path / "ignored", checkpoint=checkpoint)
    assert calls == {"load": 1, "validate": 1}
    assert load_checkpoint(half / "checkpoint.pt")["iteration"] == 8
    new = _cfg(textures, "train.iterations=2")  # a new run, as train.py starts it
    calls.update(load=0, validate=0)
    cfg, checkpoint = prepare_run(new, set())
    run_experiment(cfg, tmp_path / "new", checkpoint=checkpoint)
    assert checkpoint is None and calls == {"load": 0, "validate": 1}
    with pytest.raises(ValueError, match="learner.cues.stereo.encoder.num_atoms=32 contradicts the resumed run's"):
        prepare_run(_cfg(textures, f"train.resume={half}", "learner.cues.stereo.encoder.num_atoms=32"),
                    {"train.resume", "learner.cues.stereo.encoder.num_atoms"})
