"""aectorch.visualize: one trial of a learner recorded, animated, and from the command line."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from aectorch.evaluation import run_trials
from aectorch.coding import EncoderConfig
from aectorch.framework import JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol
from aectorch.visualize import TrialFrames, animate_trial, record_trial
from aectorch.visualize.__main__ import main

ROOT = Path(__file__).resolve().parents[2]
PROTOCOL = TrialProtocol(fixation_iterations=3, shift_m=0.1, shift_iterations=2, yoked_pursuit=True)
DISTANCE = 1.5


def _learner(**config) -> JointLearner:
    return JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=16)), **config), generator=torch.Generator().manual_seed(0))


def _texture() -> torch.Tensor:
    return TextureBank.procedural(1, size=64, seed=3).textures[0]


def _unwatched_errors(learner, texture, policy: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The same trial run plainly (no extra observations): every iteration's errors."""
    env = ActiveDepthEnv(1, textures=texture[None], distances_m=[DISTANCE], seed=0, protocol=PROTOCOL)
    env.set_trial(torch.zeros(1, dtype=torch.long), torch.full((1,), DISTANCE))
    learner.forget_transitions()
    saved = learner.generator.get_state()
    learner.generator.manual_seed(0)
    pursuit, vergence = [], []
    with torch.no_grad():
        while True:
            record = learner.iteration(env, learn=False, greedy=policy == "greedy")
            pursuit.append(record.pursuit_error_deg)
            vergence.append(record.vergence_error_deg)
            if record.trial_end:
                break
    learner.generator.set_state(saved)
    return torch.cat(pursuit), torch.cat(vergence)


@pytest.fixture(scope="module")
def frames() -> TrialFrames:
    return record_trial(_learner(), _texture(), DISTANCE, protocol=PROTOCOL, texture_name="pink")


@pytest.mark.parametrize("policy, render_scales", [("greedy", True), ("sampled", False)])
def test_the_watched_trial_is_the_evaluated_trial(policy, render_scales):
    learner, texture = _learner(render_scales=render_scales), _texture()
    got = record_trial(learner, texture, DISTANCE, protocol=PROTOCOL, policy=policy)
    assert len(got) == 6 and got.first.shape == got.second.shape == (6, 128, 128)
    assert got.cue == "stereo" and got.names == ("left", "right") and list(got.errors_deg) == ["pursuit", "vergence"]
    assert got.errors_deg["pursuit"].shape == got.errors_deg["vergence"].shape == (6,)
    assert got.fixation_end.tolist() == [False, False, True] * 2 and got.fixation.tolist() == [0, 0, 0, 1, 1, 1]
    assert 0 <= float(got.first.min()) and float(got.second.max()) <= 1 and not torch.equal(got.first, got.second)
    assert got.distance_m == DISTANCE and np.isnan(got.depth_prediction_m)  # the MLP was never fitted
    evaluated = run_trials(learner, texture[None], distances_m=[DISTANCE], seed=0, policy=policy, protocol=PROTOCOL)
    for movement, errors in got.errors_deg.items():
        assert torch.equal(evaluated[f"{movement}_deg"][0], errors[got.fixation_end])
    pursuit, vergence = _unwatched_errors(learner, texture, policy)
    assert torch.equal(pursuit, got.errors_deg["pursuit"]) and torch.equal(vergence, got.errors_deg["vergence"])


def test_the_viewer_watches_any_learned_cue_and_a_vergence_only_learner():
    learner = _learner(active_cues=["stereo"])
    got = record_trial(learner, _texture(), DISTANCE, protocol=PROTOCOL)
    assert got.cue == "stereo" and float(got.errors_deg["pursuit"].abs().max()) < 1e-4
    both = _learner()
    parallax = record_trial(both, _texture(), DISTANCE, protocol=PROTOCOL, cue="parallax")
    assert parallax.names == ("left_before", "right")[:1] + ("left",)
    assert torch.equal(parallax.first[0], parallax.first[1])  # the start image is taken once per fixation
    with pytest.raises(ValueError, match="cue must be one of the learner's cues"):
        record_trial(learner, _texture(), DISTANCE, protocol=PROTOCOL, cue="parallax")


def _same(a, b) -> bool:
    """Equal nested state: tensors exactly, dicts and sequences item by item, anything else by ==."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def test_the_learner_is_not_modified():
    learner = _learner()
    learner.generator.manual_seed(123)
    torch.rand(3, generator=learner.generator)
    state, generator = copy.deepcopy(learner.state_dict()), learner.generator.get_state()
    record_trial(learner, _texture(), DISTANCE, protocol=PROTOCOL, policy="sampled", seed=5)
    assert _same(state, learner.state_dict())
    assert torch.equal(generator, learner.generator.get_state())


def test_animate_trial_writes_one_gif_frame_per_iteration(frames, tmp_path):
    from PIL import Image

    for every, expected in ((1, 6), (4, 3)):  # every 4th: iterations 1 and 5, and always the last
        out = animate_trial(frames, tmp_path / f"trial{every}.gif", fps=5, every=every, dpi=40)
        with Image.open(out) as gif:
            assert gif.n_frames == expected and gif.size == (288, 200)
    with pytest.raises(ValueError, match="out must end in"):
        animate_trial(frames, tmp_path / "trial.png")
    from matplotlib.animation import FFMpegWriter

    if FFMpegWriter.isAvailable():
        assert animate_trial(frames, tmp_path / "trial.mp4", dpi=40).stat().st_size > 0
    else:
        with pytest.raises(ValueError, match="needs ffmpeg, which is missing"):
            animate_trial(frames, tmp_path / "trial.mp4")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("visualize")
    done = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "env.num_envs=2", "env.fixation_iterations=3", "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16",
         "train.iterations=6", "train.figures=false", "train.tensorboard=false", "train.progress=false",
         "eval.enabled=false", "hydra.run.dir=run"], cwd=folder, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return folder / "run" / "checkpoint.pt"


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "aectorch.visualize", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env=env)


@pytest.mark.integration
def test_command_line(checkpoint, tmp_path, capsys):
    from PIL import Image

    Image.fromarray((np.random.default_rng(0).random((40, 60)) * 255).astype(np.uint8)).save(tmp_path / "photo.png")
    done = _cli(f"checkpoint={checkpoint}", "out=trial.gif", "texture=photo.png", "distance=1.2", "dpi=40",
                cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "wrote trial.gif (6 frames)"
    with Image.open(tmp_path / "trial.gif") as gif:
        assert gif.n_frames == 6
    out = tmp_path / "sampled.gif"  # in-process: an index into the default test bank, every other frame
    assert main([f"checkpoint={checkpoint}", f"out={out}", "texture=2", "policy=sampled", "every=2", "dpi=40"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out} (4 frames)"  # iterations 1, 3, 5 and 6


@pytest.mark.integration
@pytest.mark.parametrize("args, key", [(["checkpoint=missing.pt"], "checkpoint"), (["distance=-1"], "distance")])
def test_bad_input_is_one_error_line(args, key, checkpoint, tmp_path):
    done = _cli(f"checkpoint={checkpoint}", "out=trial.gif", *args, cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {key}"), done.stderr
    assert not (tmp_path / "trial.gif").exists()


@pytest.mark.integration
@pytest.mark.parametrize("args, key", [
    (["texture=40"], "texture"), (["texture=nosuch.png"], "texture"), (["distance=50"], "distance"),
    (["out=trial.png"], "out"), (["fps=0"], "fps"), (["policy=argmax"], "policy"), (["renderer=opengl"], "renderer"),
])
def test_errors_name_the_key(args, key, checkpoint, tmp_path, capsys):
    assert main([f"checkpoint={checkpoint}", f"out={tmp_path / 'trial.gif'}", *args]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {key}"), errors
