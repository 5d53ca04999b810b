"""examples/: the minimal training loop runs, and it is the joint learner written out."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from aectorch.framework import JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TextureBank

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("minimal_loop", ROOT / "examples" / "minimal_loop.py")
minimal_loop = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(minimal_loop)


def test_the_minimal_loop_is_short_and_uses_the_public_api_only():
    source = (ROOT / "examples" / "minimal_loop.py").read_text()
    assert len(source.splitlines()) <= 120
    imports = [line for line in source.splitlines() if line.startswith(("from aectorch", "import aectorch"))]
    assert imports and not any("._" in line or ".runtime" in line for line in imports)


def test_the_minimal_loop_computes_what_the_joint_learner_computes():
    iterations, b = 62, 2  # two fixations, a trial's end and the first iteration after it
    out = minimal_loop.train(iterations, num_envs=b, seed=3, log_every=0)
    learner = JointLearner(LearnerConfig(cues=default_cues(symmetry=None)), generator=torch.Generator().manual_seed(3))
    env = ActiveDepthEnv(b, textures=TextureBank.default("train"), seed=3)
    for _ in range(iterations):
        learner.iteration(env)
    for cue, encoder in out["encoders"].items():
        for scale, d in encoder.dictionaries.items():
            assert torch.equal(d.atoms, learner.cues[cue].encoder.dictionaries[scale].atoms), (cue, scale)
        agent, theirs = out["agents"][cue], learner.cues[cue].agent
        mine, their_state = agent.state_dict(), theirs.state_dict()  # PPO by default: its networks, Adam, rollout
        assert mine.keys() == their_state.keys()
        for name, value in mine.items():
            if isinstance(value, torch.Tensor):
                assert torch.equal(value, their_state[name]), (cue, name)
    assert torch.equal(out["depth"].inputs, learner.depth_inputs)
    assert set(out["errors_deg"]) == {"pursuit", "vergence"} and len(out["errors_deg"]["pursuit"]) == 2 * b


@pytest.mark.integration
def test_the_minimal_loop_runs_from_the_command_line():
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "minimal_loop.py"), "31"], capture_output=True,
                          text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "iteration 31: MAE at fixation ends pursuit" in done.stdout
