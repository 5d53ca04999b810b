"""python -m aectorch.report's commands that compute on checkpoints or the head's geometry: matcher,
offsets, depth-readout and depth-tolerance (docs/results.md shows their tables)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from aectorch.report.__main__ import main
from aectorch.runs import Run


def _images(folder: Path, count: int = 3) -> Path:
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(count):
        Image.fromarray((rng.random((64, 64)) * 255).astype(np.uint8)).save(folder / f"t{i}.png")
    return folder


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A run of a few seconds on three random images (train and eval), calibrated on 15 greedy trials."""
    from omegaconf import OmegaConf

    from aectorch.runtime import run_experiment
    from aectorch.runtime.config import to_experiment_config

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("tiny")
    images = _images(tmp / "images")
    dotlist = ["env.num_envs=5", "env.fixation_iterations=2", "env.distances_m=[1.0,1.5,2.0,2.5,3.0]",
               "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16",
               "learner.depth_every_trials=10", "eval.distances_m=[1.0]", "eval.batch_size=8", "train.iterations=8",
               "train.log_every=2", "train.progress=false", "train.figures=false", "train.tensorboard=false",
               "train.metrics_window=10", f"env.textures={images}", f"eval.textures={images}",
               "train.depth_calibration_trials=15"]
    run_experiment(to_experiment_config(OmegaConf.from_dotlist(dotlist)), tmp / "run")
    return tmp / "run", images


def test_matcher_runs_the_learners_trials_and_prints_what_it_writes(tmp_path, capsys):
    images = _images(tmp_path / "images", 2)
    out = tmp_path / "matcher.json"
    assert main(["matcher", "--textures", str(images), "--depths", "2.0", "--free", "--json", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    results = json.loads(out.read_text())
    assert list(results) == ["matcher, the learner's actions", "matcher, unconstrained"]
    assert len(lines) == 4 and lines[0].startswith("| controller | trials | pursuit MAE (deg)")
    for line, (name, result) in zip(lines[2:], results.items()):
        assert result["trials"] == 2 and len(result["per_trial"]) == 2 and result["textures"] == str(images)
        assert line.startswith(f"| {name} | 2 | {result['pursuit_mae_deg']:.3f} | {result['vergence_mae_deg']:.3f} |")
        # A cross-correlation matcher on noise images fixates within a pixel.
        assert result["fractions"]["both"]["within"] == 1.0 and result["vergence_mae_deg"] < 0.1


@pytest.mark.integration
def test_offsets_computes_a_checkpoints_diagnostic_and_tabulates_stored_ones(tiny_run, tmp_path, capsys):
    run, images = tiny_run
    out, plot = tmp_path / "offsets.json", tmp_path / "offsets.png"
    args = ["offsets", f"tiny={run / 'checkpoint.pt'}", "--textures", str(images), "--depths", "1.0", "3.0",
            "--step", "0.25", "--json", str(out), "--plot", str(plot)]
    assert main(args) == 0
    computed = capsys.readouterr().out.splitlines()
    stored = json.loads(out.read_text())
    assert stored["textures"] == str(images) and list(stored["cues"]) == ["parallax", "stereo"]
    summary = stored["cues"]["stereo"]
    assert summary["trials"] == 6 and 0 <= summary["reward_peak_within_px"] <= 1  # 3 images x 2 distances
    assert summary["mean_readout_limit_cycle_abs_deg"] >= 0 and plot.stat().st_size > 1000
    # The stored measurement gives the same column, number for number, without a checkpoint.
    assert main(["offsets", f"tiny={out}", f"again={out}"]) == 0
    again = capsys.readouterr().out.splitlines()
    assert computed[0] == "| cues: parallax / stereo | tiny |" and len(computed) == len(again) == 10
    for one, two in zip(computed[2:9], again[2:9]):
        cells = two.split(" | ")
        assert one == " | ".join(cells[:-1]) + " |" and cells[-2] == cells[-1][:-2]
    peak = f"{stored['cues']['parallax']['reward_peak_abs_deg']:.3f} / {summary['reward_peak_abs_deg']:.3f}"
    assert computed[2] == f"| the reward's peak: mean distance from the optimum (deg) | {peak} |"
    assert computed[-1] == f"(6 conditions of {images})"


@pytest.mark.parametrize("args, message", [
    (["offsets", "a=x.json", "b=y.json", "--json", "o.json"], "--json and --plot take one learner"),
    (["offsets", "nolabel"], "learners are label="),
    (["depth-tolerance", "--depth-m", "0"], "depth_m must be > 0"),
    (["depth-readout", "missing.pt", "--calibration", "5"], "at least 10"),
])
def test_the_diagnostics_reject_bad_arguments_in_one_line(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_offsets_refuses_learners_of_different_cues(tmp_path, capsys):
    both = {"checkpoint": "a", "textures": "t", "cues": {"parallax": {"trials": 1}, "stereo": {"trials": 1}}}
    one = {**both, "cues": {"stereo": {"trials": 1}}}
    (tmp_path / "both.json").write_text(json.dumps(both))
    (tmp_path / "one.json").write_text(json.dumps(one))
    assert main(["offsets", f"a={tmp_path / 'both.json'}", f"b={tmp_path / 'one.json'}"]) == 2
    assert "the same cues" in capsys.readouterr().err


@pytest.mark.integration
def test_depth_readout_compares_read_outs_of_the_same_trials(tiny_run, tmp_path, capsys):
    """Its calibrated read-out is train.py's ``train.depth_calibration_trials``; the cache gives the same."""
    run, _ = tiny_run
    args = ["depth-readout", str(run / "best.pt"), "--calibration", "12", "15", "--cache", str(tmp_path / "t.pt")]
    assert main([*args, "--json", str(tmp_path / "a.json")]) == 0
    out = capsys.readouterr().out
    assert "| distance_m | MLP | calibrated 12 | calibrated 12 + training | calibrated 15 |" in out
    result = json.loads((tmp_path / "a.json").read_text())
    maes = result["textures"]["depth_mae_m"]
    assert maes["calibrated 15"] == pytest.approx(Run(run).evaluation("evaluation.json")["depth_mae_m"])
    assert maes["calibrated 12"] != maes["calibrated 15"]
    assert all(math.isfinite(maes[k]) for k in ("vergence", "pursuit", "all four", "calibrated 15 + training"))
    assert 0 < maes["Gaussian floor"] < math.inf
    assert result["textures"]["trials"] == 3 and [r["distance_m"] for r in result["textures"]["per_distance"]] == [1.0]
    assert main([*args, "--json", str(tmp_path / "b.json")]) == 0  # from the cache: the same numbers
    assert (tmp_path / "b.json").read_text() == (tmp_path / "a.json").read_text()


def test_depth_tolerance_is_the_eye_error_that_moves_the_geometrys_depth(capsys):
    from aectorch.report.depth import _geometry, tolerance_table

    assert main(["depth-tolerance", "--distances", "1.0", "3.0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == "| distance_m | q1 | q2 | q3 | q4 | all four alike |" and len(lines) == 5
    rows = tolerance_table([1.0, 3.0])
    assert lines[3] == "| 1.0 | " + " | ".join(f"{rows[0][k]:.3f}" for k in ("q1", "q2", "q3", "q4", "all four alike")) + " |"
    # The oracle: the exact geometry moved 1 cm farther changes each input by a fifth of its tolerance.
    env = _geometry(0.1)
    for row in rows:
        d = torch.tensor([row["distance_m"]], dtype=torch.float64)
        change = (env.ideal_q_deg(d + 0.01) - env.ideal_q_deg(d))[0].abs()
        for j in range(4):
            assert float(change[j]) == pytest.approx(row[f"q{j + 1}"] / 5, rel=0.02)
    assert 0.1 < rows[0]["q2"] < 0.25 and rows[1]["q2"] < rows[0]["q2"] / 5  # vergence: 0.17 deg at 1 m


@pytest.mark.integration
def test_offsets_sweeps_the_pan_cues_of_a_learner_with_the_slip_cue(tmp_path, capsys):
    """``+experiment=slip``'s learner also learns a velocity (the slip cue), which no offset moves:
    the diagnostic sweeps its parallax and stereo cues, comparable with a default learner's."""
    from omegaconf import OmegaConf

    from aectorch.runtime import load_learner, run_experiment
    from aectorch.runtime.config import to_experiment_config

    torch.set_num_threads(1)
    images = _images(tmp_path / "images", 2)
    dotlist = ["env.num_envs=4", "env.fixation_iterations=2", "env.pursuit_velocity=true",
               "learner.cues.slip.symmetry=mirror", "train.iterations=2", "train.progress=false",
               "train.figures=false", "train.tensorboard=false", "eval.enabled=false", f"env.textures={images}"]
    dotlist += [f"learner.cues.{cue}.encoder.num_atoms=16" for cue in ("slip", "parallax", "stereo")]
    run_experiment(to_experiment_config(OmegaConf.from_dotlist(dotlist)), tmp_path / "run")
    checkpoint, out = tmp_path / "run" / "checkpoint.pt", tmp_path / "offsets.json"
    assert sorted(load_learner(checkpoint)[1].cues) == ["parallax", "slip", "stereo"]
    assert main(["offsets", f"slip={checkpoint}", "--textures", str(images), "--depths", "1.0", "--step", "0.5",
                 "--span", "2", "--json", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| cues: parallax / stereo | slip |" and len(lines) == 14
    stored = json.loads(out.read_text())["cues"]
    assert list(stored) == ["parallax", "stereo"] and stored["stereo"]["trials"] == 2
    # Beyond the default span's 1 deg: the rows of the steps away from the optimum (offsets -2 and +2).
    for line, side in zip(lines[9:11], ("below", "above")):
        cells = [f"{stored[cue][f'away_far_{side}']:.1%}" for cue in stored]
        assert line == f"| the mean read-out steps away from the optimum, over 1 deg {side} it | {' / '.join(cells)} |"
    assert lines[11].startswith("| capture range below the optimum") and lines[12].startswith("| capture range above")
    assert main(["offsets", "x=missing.pt", "--span", "0"]) == 2 and "--span must be in" in capsys.readouterr().err
