"""A LeRobot dataset's two cameras as stereo pairs without ground truth: recorded by aectorch's own
recorder with the eyes' full window (320 x 240: the pair world's windows need 160 eye px plus the
searched shifts), written out by scripts/lerobot_pairs.py and evaluated by python -m
aectorch.evaluate (run in .venv-lerobot, as tests/lerobot/test_lerobot.py)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("lerobot.datasets.lerobot_dataset", reason="LeRobot runs in .venv-lerobot")

from PIL import Image  # noqa: E402

from aectorch.coding import EncoderConfig  # noqa: E402
from aectorch.evaluate import main as evaluate  # noqa: E402
from aectorch.framework import JointLearner, LearnerConfig, default_cues  # noqa: E402
from aectorch.integrations.lerobot import StereoFrames, record_trials  # noqa: E402
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
#: The newest checkpoint of the migration fixtures: a small learner (2 iterations per fixation).
CHECKPOINT = sorted((ROOT / "tests" / "fixtures" / "checkpoints").glob("*.pt"))[-1]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """One trial of one environment, 2 iterations per fixation: 4 frames of 320 x 240 px."""
    env = ActiveDepthEnv(1, protocol=TrialProtocol(fixation_iterations=2), window="full",
                         textures=TextureBank.procedural(2, size=(128, 128), seed=0), seed=0)
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=16))),
                           generator=torch.Generator().manual_seed(0))
    return record_trials(learner, env, 1, tmp_path_factory.mktemp("rec") / "ds", progress=False)


def _script(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "lerobot_pairs.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.integration
def test_the_two_cameras_are_written_as_pairs_and_evaluated_without_ground_truth(recording, tmp_path, capsys):
    out = tmp_path / "pairs"
    done = _script(str(recording), str(out), "--every", "2", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "wrote 2 pairs of 320 x 240 px" in done.stdout
    assert sorted(p.name for p in out.iterdir()) == ["frame_000000", "frame_000002"]
    assert sorted(p.name for p in (out / "frame_000002").iterdir()) == ["left.png", "right.png"]  # no disparity
    frames = StereoFrames(recording)
    for index in (0, 2):
        for eye, image in zip(("left", "right"), frames[index]):
            written = np.asarray(Image.open(out / f"frame_{index:06d}" / f"{eye}.png"), dtype=np.float64) / 255
            np.testing.assert_allclose(written, image.double().numpy(), atol=0.5 / 255 + 1e-6)
    # the main command reads them as pairs without ground truth (a tiny run: 2 points, 2 iterations)
    result_file = tmp_path / "pairs.json"
    assert evaluate([f"checkpoint={CHECKPOINT}", f"pairs={out}", f"out={result_file}", "fixations=2",
                     "progress=false"]) == 0
    result = json.loads(result_file.read_text())
    assert result["summary"] == {} and [p["ground_truth"] for p in result["pairs"]] == [False, False]
    part = result["without_ground_truth"]
    assert part["pairs"] == ["frame_000000", "frame_000002"] and part["start_kinds"] == ["protocol"]
    assert part["summary"]["learner"]["protocol"]["n"] == 4 and part["summary"]["matcher"]["protocol"]["n"] == 4
    rows = result["per_fixation"]
    assert len(rows) == 2 * 2 * 2 and {r["start"] for r in rows} == {"protocol"}
    assert all(np.isfinite(r["reward"]) and r["stability_px"] >= 0 for r in rows)
    assert "without ground truth (frame_000000, frame_000002)" in capsys.readouterr().out
    # bad input: one error line, exit 2 (the script's main, in this process)
    script = _load_script()
    assert script.main([str(recording), str(out)]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert script.main([str(recording), str(tmp_path / "other"), "--left", "observation.images.left"]) == 2
    assert "give --left and --right together" in capsys.readouterr().err
    assert script.main([str(recording), str(tmp_path / "other"), "--left", "observation.images.top", "--right",
                        "observation.images.right"]) == 2
    assert "is not a camera" in capsys.readouterr().err
    assert script.main([str(recording), str(tmp_path / "other"), "--every", "0"]) == 2
    assert "--every must be an integer >= 1" in capsys.readouterr().err


def _load_script():
    spec = importlib.util.spec_from_file_location("lerobot_pairs", ROOT / "scripts" / "lerobot_pairs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
