"""python -m aectorch.evaluate: the command-line evaluation of a checkpoint."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from aectorch.runtime.config import to_experiment_config
from aectorch.evaluate import main
from aectorch.runtime import run_experiment

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[Path, Path]:
    from PIL import Image

    folder = tmp_path_factory.mktemp("eval")
    textures = folder / "textures"
    textures.mkdir()
    rng = np.random.default_rng(1)
    for i in range(2):
        Image.fromarray((rng.random((48, 48)) * 255).astype(np.uint8)).save(textures / f"t{i}.png")
    cfg = to_experiment_config(OmegaConf.from_dotlist([
        "env.num_envs=5", "env.fixation_iterations=2", "env.distances_m=[1.0,2.0]", "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16",
        "learner.depth_every_trials=10", "train.iterations=8", "train.progress=false", "train.figures=false",
        "train.tensorboard=false", "eval.enabled=false", f"env.textures={textures}",
    ]))
    run_experiment(cfg, folder / "run")
    return folder / "run" / "checkpoint.pt", textures


@pytest.mark.integration
def test_writes_the_result_json_and_figure(run, tmp_path, capsys):
    checkpoint, textures = run
    out, figure = tmp_path / "e.json", tmp_path / "e.png"
    code = main([f"checkpoint={checkpoint}", f"textures={textures}", f"out={out}", "depths=[1.0,2.5]",
                 "batch_size=3", "progress=false", f"figure={figure}"])
    assert code == 0
    result = json.loads(out.read_text())
    for key in ("vergence_mae_deg", "pursuit_mae_deg", "depth_mae_m", "per_distance", "trials", "vergence_test"):
        assert key in result, key
    assert result["trials"] == 4 and [r["distance_m"] for r in result["per_distance"]] == [1.0, 2.5]
    assert result["iteration"] == 8 and result["checkpoint"] == str(checkpoint)
    assert result["textures"] == str(textures) and result["renderer"] == "torch"
    assert result["policy"] == "greedy"
    assert result["pan_range_deg"] == [-45.0, 45.0] and result["vergence_range_deg"] == [-2.0, 40.0]  # the run's
    assert np.isfinite(result["depth_mae_m"]) and figure.is_file()
    assert "vergence test" in capsys.readouterr().out
    # Another vergence range replaces the run's for the trials: a tiny one holds the vergence near parallel.
    narrow = tmp_path / "narrow.json"
    assert main([f"checkpoint={checkpoint}", f"textures={textures}", f"out={narrow}", "depths=[1.0]", "batch_size=3",
                 "progress=false", "vergence_range_deg=[-0.01,0.01]"]) == 0
    result = json.loads(narrow.read_text())
    assert result["vergence_range_deg"] == [-0.01, 0.01]
    # the optimum at 1 m is 3.43 deg of vergence: every end is at least 3.4 deg off
    assert min(abs(e) for r in result["per_trial"] for e in r["vergence_errors_deg"]) > 3.4


@pytest.mark.integration
def test_tracking_writes_its_rows_and_the_report_reads_them(run, tmp_path, capsys):
    """``tracking=[...]``: the moving object's test (per speed and per trial); then
    experiments/moving_objects/report.py over two run folders, with its figure."""
    from tests.end_to_end import study_module

    report = study_module("moving_objects", "report").main

    checkpoint, textures = run
    for seed in (0, 1):
        folder = tmp_path / f"run{seed}"
        folder.mkdir()
        code = main([f"checkpoint={checkpoint}", f"textures={textures}", f"out={folder / 'tracking.json'}",
                     "depths=[1.0]", "tracking=[0,1.5]", "skip=1", f"seed={seed}", "progress=false",
                     f"figure={folder / 'tracking.png'}"])
        assert code == 0 and (folder / "tracking.png").exists()
    result = json.loads((tmp_path / "run0" / "tracking.json").read_text())["tracking"]
    assert [row["speed_deg"] for row in result["per_speed"]] == [0.0, 1.5]
    assert [row["speed_deg"] for row in result["per_trial"]] == [0.0, 0.0, 1.5, -1.5]
    assert {"pursuit_tracking_deg", "vergence_tracking_deg"} <= set(result["per_trial"][0])
    capsys.readouterr()
    assert report([str(tmp_path / "run0"), str(tmp_path / "run1"), "--plot",
                   str(tmp_path / "t.png"), "--target", "0.2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("2 runs") and lines[3].startswith("| 0 | ") and " +- " in lines[4]
    assert (tmp_path / "t.png").exists()
    # --within: the percentage of fixations within the limit, per run, then mean +- sd over the runs
    limit = 0.5 * (result["per_trial"][2]["pursuit_tracking_deg"][0] + result["per_trial"][2]["pursuit_tracking_deg"][1])
    assert report([str(tmp_path / "run0"), str(tmp_path / "run1"), "--within", str(limit)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].endswith(f"| pursuit within {limit:g} (%) | vergence within {limit:g} (%) |")
    percent = []
    for seed in (0, 1):
        rows = json.loads((tmp_path / f"run{seed}" / "tracking.json").read_text())["tracking"]["per_trial"]
        errors = [e for row in rows if abs(row["speed_deg"]) == 1.5 for e in row["pursuit_tracking_deg"]]
        percent.append(100.0 * sum(e <= limit for e in errors) / len(errors))
    assert lines[4].split(" | ")[-2].split(" +- ")[0] == f"{sum(percent) / 2:.1f}"
    assert report([str(run[0].parent)]) == 2  # no tracking.json there


@pytest.mark.integration
@pytest.mark.parametrize("args, key", [
    (["textures={t}", "out={o}"], "checkpoint"),
    (["checkpoint={c}"], "out"),
    (["checkpoint={c}", "out={o}", "nosuch=1"], "nosuch"),
    (["checkpoint={c}", "out={o}", "batch_size=0"], "batch_size"),
    (["checkpoint={c}", "out={o}", "depths=[0.0]"], "depths"),
    (["checkpoint={c}", "out={o}", "renderer=opengl"], "renderer"),
    (["checkpoint={c}", "out={o}", "textures=/nonexistent"], "textures"),
    (["checkpoint={c}.missing", "out={o}"], "checkpoint"),
    (["checkpoint={c}", "out={o}", "progress=maybe"], "progress"),
    (["checkpoint={c}", "out={o}", "policy=argmax"], "policy"),
    (["checkpoint={c}", "out={o}", "tracking=[-1.0]"], "tracking"),
    (["checkpoint={c}", "out={o}", "tracking=[1.0]", "skip=1", "depth_speed=-0.5"], "object_depth_speed_m"),
    (["checkpoint={c}", "out={o}", "vergence_range_deg=[1,2]"], "vergence_range_deg"),
])
def test_errors_name_the_key(args, key, run, tmp_path, capsys):
    checkpoint, textures = run
    out = tmp_path / "e.json"
    argv = [a.format(c=checkpoint, t=textures, o=out) for a in args]
    assert main(argv) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and key in errors[0], errors
    assert not out.exists()


def test_corrupt_checkpoint_and_help(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    assert main([f"checkpoint={bad}", f"out={tmp_path / 'e.json'}"]) == 2
    assert "bad.pt" in capsys.readouterr().err
    assert main(["--help"]) == 0 and "textures     a folder of held-out images" in capsys.readouterr().out


@pytest.mark.integration
def test_module_entry_point_exits_2():
    done = subprocess.run([sys.executable, "-m", "aectorch.evaluate", "out=x.json"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PYOPENGL_PLATFORM="osmesa"))
    assert done.returncode == 2 and done.stderr.startswith("error: checkpoint")
