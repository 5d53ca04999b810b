"""aectorch.integrations.lerobot against LeRobot's own loader and visualiser (run in .venv-lerobot:
`make test` does, through scripts/setup_lerobot.sh; LeRobot 0.4.4 cannot share the main torch)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset", reason="LeRobot runs in .venv-lerobot")
LeRobotDataset = lerobot_dataset.LeRobotDataset

from aectorch.coding import BinocularEncoder, EncoderConfig  # noqa: E402
from aectorch.framework import JointLearner, LearnerConfig, default_cues  # noqa: E402
from aectorch.integrations.lerobot import (  # noqa: E402
    FEATURES_STATE, StereoFrames, pretrain_encoder, record_trials, stereo_batches,
)
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
REPO = "aectorch/hoap3-sim"


def _world(seed: int = 0):
    # The whole shift before the first frame and pursuit by the left eye alone, so each recorded
    # state can be checked step by step.
    env = ActiveDepthEnv(1, protocol=TrialProtocol(shift_iterations=1, yoked_pursuit=False),
                         textures=TextureBank.procedural(4, size=(128, 128), seed=0), seed=seed)
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=16))), generator=torch.Generator().manual_seed(0))
    return env, learner


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    env, learner = _world()
    return record_trials(learner, env, 2, tmp_path_factory.mktemp("rec") / "ds", progress=False)


def test_two_trials_are_four_episodes_of_thirty_frames_read_by_lerobot(recording):
    ds = LeRobotDataset(REPO, root=recording)  # LeRobot's own loader
    assert ds.num_episodes == 4 and ds.num_frames == 120 and len(ds) == 120
    assert sorted(ds.meta.camera_keys) == ["observation.images.left", "observation.images.right"]
    assert ds.meta.features["observation.state"]["names"] == list(FEATURES_STATE)
    episodes = torch.stack([ds[i]["episode_index"] for i in range(120)])
    frames = torch.stack([ds[i]["frame_index"] for i in range(120)])
    assert torch.equal(episodes, torch.arange(4).repeat_interleave(30))
    assert torch.equal(frames, torch.arange(30).repeat(4))
    first = ds[0]
    assert first["observation.images.left"].shape == (3, 128, 128)
    assert first["observation.state"].shape == (5,) and first["action"].shape == (2,)
    assert first["reward"].shape == (2,)
    # A trial is two fixations at one distance: leftward (body +0.1 m), then rightward.
    for e in range(4):
        rows = [ds[30 * e + t] for t in range(30)]
        assert len({float(r["distance_m"]) for r in rows}) == 1
        assert {int(r["fixation"]) for r in rows} == {e % 2} and {int(r["trial_index"]) for r in rows} == {e // 2}
        shift = float(rows[0]["observation.state"][0])
        assert shift == pytest.approx(0.1 if e % 2 == 0 else -0.1)
        assert rows[0]["task"].endswith("leftward body shift" if e % 2 == 0 else "rightward body shift")


def test_recorded_values_are_what_the_simulation_produced(recording):
    # The same world and learner, stepped without the recorder: every recorded number must match.
    env, learner = _world()
    env.reset()
    ds = LeRobotDataset(REPO, root=recording)
    for t in range(60):  # the first trial: episodes 0 and 1
        left_before = env.pan_deg.clone()
        record = learner.iteration(env, learn=False, greedy=True)
        row = ds[t]
        action = torch.stack((record.parallax.increments_deg, record.stereo.increments_deg), 1)[0]
        reward = torch.stack((record.parallax.reward, record.stereo.reward), 1)[0]
        torch.testing.assert_close(row["action"], action.float(), rtol=0, atol=0)
        torch.testing.assert_close(row["reward"], reward.float(), rtol=0, atol=0)
        # the state at step k2: the left pan after the pursuit increment, the right pan before vergence
        expected_left = float(np.clip(left_before[0, 0] + action[0], -45, 45))
        assert float(row["observation.state"][1]) == pytest.approx(expected_left, abs=1e-5)
        assert float(row["observation.state"][2]) == pytest.approx(float(left_before[0, 1]), abs=1e-5)


def test_recorded_images_are_the_rendered_eyes(recording):
    env, _ = _world()
    env.reset()
    ds = LeRobotDataset(REPO, root=recording)
    # Frame 0 of a fixation with a policy that starts from pan 0: re-render the recorded pose.
    row = ds[0]
    shift, left_pan, right_pan = (float(v) for v in row["observation.state"][:3])
    env.apply_pursuit(torch.tensor([left_pan - float(env.left_pan_deg[0])]))
    pair = env.stereo_observation()["window"][0]
    expected = (pair.clamp(0, 1) * 255).round() / 255
    for eye, key in enumerate(("observation.images.left", "observation.images.right")):
        got = row[key]
        assert torch.equal(got[0], got[1]) and torch.equal(got[1], got[2])  # grey in three channels
        torch.testing.assert_close(got[0], expected[eye].float(), rtol=0, atol=1e-6)


def test_the_reverse_loader_feeds_and_trains_a_binocular_encoder(recording):
    frames = StereoFrames(recording)
    assert (frames.left, frames.right) == ("observation.images.left", "observation.images.right")
    left, right = frames[5]
    raw = LeRobotDataset(REPO, root=recording)[5]
    torch.testing.assert_close(left, raw["observation.images.left"].mean(0))
    assert left.shape == (128, 128) and 0 <= float(left.min()) and float(left.max()) <= 1
    encoder = BinocularEncoder(num_atoms=32, generator=torch.Generator().manual_seed(1))
    before = {k: d.atoms.detach().clone() for k, d in encoder.dictionaries.items()}
    rewards = pretrain_encoder(encoder, stereo_batches(recording, batch_size=16), steps=5)
    assert len(rewards) == 5 and all(np.isfinite(rewards))
    for key, d in encoder.dictionaries.items():
        assert not torch.equal(before[key], d.atoms)
        torch.testing.assert_close(d.atoms.norm(dim=0), torch.ones(32), rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="is not a camera"):
        StereoFrames(recording, left="observation.images.top", right="observation.images.right")


def test_lerobot_visualiser_reads_the_recording(recording, tmp_path):
    from lerobot.scripts.lerobot_dataset_viz import visualize_dataset

    ds = LeRobotDataset(REPO, root=recording, episodes=[1])
    path = visualize_dataset(ds, episode_index=1, save=True, output_dir=tmp_path)
    assert Path(path).is_file() and Path(path).stat().st_size > 10_000


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_record_cli_and_recording_during_training(tmp_path):
    from PIL import Image

    textures = tmp_path / "textures"
    textures.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray((rng.random((96, 96)) * 255).astype(np.uint8)).save(textures / f"t{i}.png")
    run, during = tmp_path / "run", tmp_path / "during"
    tiny = ["env.num_envs=3", "env.fixation_iterations=4", "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16", "train.iterations=12",
            "train.progress=false", "train.figures=false", "train.tensorboard=false", "eval.enabled=false",
            f"env.textures={textures}"]
    done = _run(str(ROOT / "train.py"), *tiny, f"record.lerobot={during}", "record.envs=2",
                f"hydra.run.dir={run}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    ds = LeRobotDataset(REPO, root=during)
    assert ds.num_episodes == 2 * 3 and ds.num_frames == 6 * 4  # 3 fixations x 2 recorded envs
    out = tmp_path / "cli"
    done = _run("-m", "aectorch.record", f"checkpoint={run / 'checkpoint.pt'}", f"textures={textures}",
                "trials=2", f"out={out}", "progress=false", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "recorded 4 episodes (16 frames)" in done.stdout
    ds = LeRobotDataset(REPO, root=out)
    assert ds.num_episodes == 4 and ds.num_frames == 16
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["robot_type"] == "hoap3-sim" and info["total_episodes"] == 4
    # bad input: one error line, exit 2
    done = _run("-m", "aectorch.record", f"checkpoint={run / 'checkpoint.pt'}", f"out={out}", cwd=tmp_path)
    assert done.returncode == 2 and "exists already" in done.stderr and "Traceback" not in done.stderr
