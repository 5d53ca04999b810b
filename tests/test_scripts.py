"""The analysis scripts under scripts/ (the tables of runs are python -m aectorch.report's: tests/test_report.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest


def test_soak_report_splits_memory_by_process_and_finds_growth(tmp_path, script):
    soak = script("soak")
    lines = [{"iteration": i, "pursuit_mae_deg": 1.0, "vergence_mae_deg": 0.5, "depth_mae_m": None if i < 20 else 0.1,
              "parallax/td_error": 0.01 * (1 + i % 3), "stereo/td_error": 0.02, "parallax/entropy": 0.1,
              "stereo/entropy": 0.05} for i in range(10, 110, 10)]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    # Process 1 (started at t=0) grows by 1 MB per 10 iterations; process 2 (started at t=100, a
    # resume from iteration 50, so the iterations increase across the boundary) is flat at 500 MB.
    memory = [{"iteration": i, "rss_mb": 600.0 + i / 10, "time": float(i)} for i in (10, 20, 30, 40, 50)]
    memory += [{"iteration": i, "rss_mb": 500.0, "time": 100.0 + i} for i in (60, 70, 80)]
    (tmp_path / "memory.jsonl").write_text("".join(json.dumps(m) + "\n" for m in memory))
    (tmp_path / "provenance.json").write_text(json.dumps({"sessions": [
        {"started": "1970-01-01T00:00:00+00:00"}, {"started": "1970-01-01T00:01:40+00:00"}]}))
    out = soak.report(tmp_path, since=50)
    assert out["iterations"] == 100 and out["nonfinite_values"] == 0 and out["null_values_besides_early_depth"] == 0
    assert out["td_error_range"]["parallax"] == pytest.approx([0.01, 0.03])
    assert out["from_iteration_50"]["depth_mae_m"] == pytest.approx([0.1, 0.1])
    first, second = out["memory_by_process"]
    assert first["iterations"] == [10, 50] and first["growth_mb_per_10k"] == pytest.approx(1000.0)
    assert second["iterations"] == [60, 80] and second["growth_mb_per_10k"] == pytest.approx(0.0)
    # Without provenance the boundary is invisible here (the iterations increase): one process.
    (tmp_path / "provenance.json").unlink()
    assert len(soak.report(tmp_path)["memory_by_process"]) == 1


def _tiny_dotlist(tmp_path: Path) -> list[str]:
    """A run of a few seconds on three random textures (train and eval)."""
    import numpy as np
    import torch
    from PIL import Image

    torch.set_num_threads(1)
    folder = tmp_path / "textures"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray((rng.random((64, 64)) * 255).astype(np.uint8)).save(folder / f"t{i}.png")
    return ["env.num_envs=5", "env.fixation_iterations=2", "env.distances_m=[1.0,1.5,2.0,2.5,3.0]",
            "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16", "learner.depth_every_trials=10", "eval.distances_m=[1.0]",
            "eval.batch_size=8", "train.iterations=12", "train.log_every=2", "train.progress=false",
            "train.figures=false", "train.tensorboard=false", "train.metrics_window=10",
            f"env.textures={folder}", f"eval.textures={folder}"]


def test_depth_calibration_script_gives_what_train_py_evaluates(tmp_path, capsys, script):
    """scripts/depth_calibration.py --design spread reproduces train.depth_calibration_trials."""
    from omegaconf import OmegaConf

    from aectorch.runtime.config import to_experiment_config
    from aectorch.runtime import run_experiment

    dotlist = _tiny_dotlist(tmp_path)
    calibrated = run_experiment(to_experiment_config(OmegaConf.from_dotlist(dotlist + ["train.depth_calibration_trials=15"])),
                                tmp_path / "run")
    capsys.readouterr()
    calibration = script("depth_calibration")
    out = tmp_path / "out.json"
    assert calibration.main([str(tmp_path / "run" / "best.pt"), "--trials", "15", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result == json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    plain = run_experiment(to_experiment_config(OmegaConf.from_dotlist(dotlist)), tmp_path / "plain")
    # best.pt of so short a run has no fitted MLP yet (NaN); the calibration fits one.
    assert result["before"]["textures"] == pytest.approx(plain["evaluation"]["depth_mae_m"], nan_ok=True)
    assert result["after"]["textures"] == pytest.approx(calibrated["evaluation"]["depth_mae_m"])
    assert math.isfinite(result["after"]["textures"])
    with pytest.raises(SystemExit):
        calibration.main([str(tmp_path / "run" / "best.pt"), "--trials", "5"])


def test_depth_readout_compares_read_outs_of_the_same_trials(tmp_path, capsys, script):
    """scripts/depth_readout.py: its calibrated read-out is train.py's; the cache gives the same."""
    from omegaconf import OmegaConf

    from aectorch.runtime.config import to_experiment_config
    from aectorch.runtime import run_experiment

    dotlist = _tiny_dotlist(tmp_path) + ["train.iterations=20"]
    calibrated = run_experiment(to_experiment_config(OmegaConf.from_dotlist(dotlist + ["train.depth_calibration_trials=15"])),
                                tmp_path / "run")
    capsys.readouterr()
    readout = script("depth_readout")
    args = [str(tmp_path / "run" / "best.pt"), "--calibration", "12", "15", "--cache", str(tmp_path / "t.pt")]
    assert readout.main([*args, "--json", str(tmp_path / "a.json")]) == 0
    out = capsys.readouterr().out
    assert "| distance_m | MLP | calibrated 12 | calibrated 12 + training | calibrated 15 |" in out
    result = json.loads((tmp_path / "a.json").read_text())
    maes = result["textures"]["depth_mae_m"]
    assert maes["calibrated 15"] == pytest.approx(calibrated["evaluation"]["depth_mae_m"])
    assert maes["calibrated 12"] != maes["calibrated 15"]
    assert all(math.isfinite(maes[k]) for k in ("vergence", "pursuit", "all four", "calibrated 15 + training"))
    assert 0 < maes["Gaussian floor"] < math.inf
    assert result["textures"]["trials"] == 3 and [r["distance_m"] for r in result["textures"]["per_distance"]] == [1.0]
    tolerance = result["tolerance_deg_for_0.05_m"][0]  # 1.0 m: vergence 0.05 m is about 0.17 deg
    assert 0.1 < tolerance["q2"] < 0.25 and tolerance["all four alike"] > tolerance["q1"]
    # The cache: the same trials, so the same numbers, without running them again.
    assert readout.main([*args, "--json", str(tmp_path / "b.json")]) == 0
    assert (tmp_path / "b.json").read_text() == (tmp_path / "a.json").read_text()
    with pytest.raises(SystemExit):
        readout.main([str(tmp_path / "run" / "best.pt"), "--calibration", "5"])
