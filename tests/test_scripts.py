"""The analysis scripts under scripts/ that docs/results.md's tables come from."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

def _run(folder: Path, lines: list[dict], events=None) -> Path:
    folder.mkdir()
    (folder / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    if events is not None:
        (folder / "summary.json").write_text(json.dumps({"perturbation": {"events": events}}))
    return folder


def test_compare_runs_prints_the_runs_side_by_side(tmp_path, capsys, script):
    compare = script("compare_runs")
    a = _run(tmp_path / "a", [{"iteration": i, "pursuit_mae_deg": i / 100, "vergence_mae_deg": None}
                              for i in (25, 50, 75, 100)], events=[{"iteration": 60, "label": "rolled"}])
    b = _run(tmp_path / "b", [{"iteration": i, "pursuit_mae_deg": 2.0, "vergence_mae_deg": 0.5} for i in (50, 100)])
    plot = tmp_path / "out" / "cmp.png"
    assert compare.main([str(a), str(b), "--names", "x", "y", "--every", "25", "--from", "50",
                         "--keys", "pursuit_mae_deg", "vergence_mae_deg", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "| iteration | pursuit_mae_deg x | pursuit_mae_deg y | vergence_mae_deg x | vergence_mae_deg y |"
    assert out[2] == "| 50 | 0.500 | 2.000 | - | 0.500 |"
    assert out[3] == "| 75 | 0.750 | - | - | - |"  # b has no line at 75
    assert out[4].startswith("| 100 | 1.000 |") and len(out) == 6 and plot.stat().st_size > 0


@pytest.mark.parametrize("args, message", [
    (["--names", "only-one"], "one name per run"),
    (["--names", "same", "same"], "distinct"),
    (["--every", "0"], "--every"),
])
def test_compare_runs_rejects_bad_arguments(tmp_path, capsys, args, message, script):
    compare = script("compare_runs")
    a = _run(tmp_path / "a", [{"iteration": 1}])
    b = _run(tmp_path / "b", [{"iteration": 1}])
    assert compare.main([str(a), str(b), *args]) == 2
    assert message in capsys.readouterr().err


def test_compare_runs_names_a_folder_without_metrics(tmp_path, capsys, script):
    compare = script("compare_runs")
    assert compare.main([str(tmp_path)]) == 2
    assert "has no metrics.jsonl" in capsys.readouterr().err


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


def _evaluation(path: Path, trials: list[tuple[str, float, list[float], list[float]]]) -> Path:
    rows = [{"texture": t, "distance_m": d, "pursuit_error_deg": p[-1], "vergence_error_deg": v[-1],
             "depth_error_m": 0.01, "pursuit_errors_deg": p, "vergence_errors_deg": v} for t, d, p, v in trials]
    path.write_text(json.dumps({"per_trial": rows}))
    return path


def test_compare_trials_counts_the_fixation_ends_that_agree(tmp_path, capsys, script):
    compare = script("compare_trials")
    a = _evaluation(tmp_path / "a.json", [("x", 1.0, [0.1, 0.0], [0.0, 0.0]), ("y", 2.0, [0.0, 0.0], [0.5, 0.0])])
    b = _evaluation(tmp_path / "b.json", [("y", 2.0, [0.04, 0.0], [0.0, 0.0]), ("x", 1.0, [0.1, 0.0], [0.0, 0.2])])
    assert compare.main([str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    result = json.loads((tmp_path / "c.json").read_text())
    assert result["pursuit"]["agree"] == 1.0  # 0.04 deg apart is within 0.05
    assert result["vergence"]["agree"] == 0.5 and result["vergence"]["max_difference_deg"] == 0.5
    assert result["vergence"]["worst"][0]["texture"] == "y" and result["both_agree_trials"] == 0.0
    assert "pursuit" in capsys.readouterr().out
    c = _evaluation(tmp_path / "d.json", [("x", 1.0, [0.1, 0.0], [0.0, 0.0])])
    assert compare.main([str(a), str(c)]) == 2
    assert "different trials" in capsys.readouterr().err


def test_results_table_reports_the_near_trials_and_the_fractions(tmp_path, capsys, script):
    table = script("results_table")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("seed: 3\n")
    (run / "summary.json").write_text(json.dumps({
        "iterations": 10, "train_seconds": 60.0, "best": None,
        "final": {"pursuit_mae_deg": 0.1, "vergence_mae_deg": 0.2, "depth_mae_m": 0.3}}))
    evaluation = json.loads(_evaluation(tmp_path / "e.json", [
        ("x", 1.0, [0.1, -0.3], [0.0, 0.0]), ("x", 1.5, [0.2, 0.2], [0.1, 0.1]), ("x", 3.0, [5.0, 5.0], [0, 0])]).read_text())
    evaluation.update(pursuit_mae_deg=1.0, vergence_mae_deg=0.0, depth_mae_m=0.01, trials=3,
                      pursuit={"median_abs": 0.2}, vergence={"median_abs": 0.0}, depth={"median_abs": 0.01},
                      fractions={"both": {"within": 0.5, "beyond": 0.25}})
    (run / "evaluation.json").write_text(json.dumps(evaluation))
    assert table.main([str(run)]) == 0
    header, _, row = capsys.readouterr().out.splitlines()
    cells = dict(zip(header.strip("| ").split(" | "), row.strip("| ").split(" | ")))
    assert cells["1.0-1.5 m pursuit MAE (deg)"] == "0.200" and cells["1.0-1.5 m vergence MAE (deg)"] == "0.050"
    assert cells["both within 0.22 deg"] == "0.500" and cells["evaluated (best.pt: iteration)"] == "last"


def test_rl_table_tabulates_the_clients_and_active_depth(tmp_path, capsys, script):
    table = script("rl_table")

    def result(mae, random_mae, **pursuit):
        row = lambda v, p: {"vergence_mae_deg": v, "within_0.22_deg": 0.5, "fixations": 8,  # noqa: E731
                            **({"pursuit_mae_deg": p} if p is not None else {})}
        return {"train_s": 10.0, "eval": {"test textures": {"trained": row(mae, pursuit.get("trained")),
                                                            "random": row(random_mae, pursuit.get("random"))}}}

    for name, value in (("cleanrl_scaled_s0", 0.2), ("cleanrl_scaled_s1", 0.4), ("sb3_coding_s0", 1.0)):
        (tmp_path / f"{name}.json").write_text(json.dumps(result(value, 2.5)))
    (tmp_path / "sb3-activedepth_scaled_s0.json").write_text(json.dumps(result(0.5, 2.0, trained=1.0, random=3.0)))
    (tmp_path / "other_s0.json").write_text("{}")  # not a client's file: left alone
    assert table.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "| CleanRL-style PPO | scaled | test textures | 2 | 0.300 (0.141) [0.20 / 0.40] | 50.0% | 2.50 | 10 |" in out
    assert "| SB3 PPO | coding | test textures | 1 | 1.000 [1.00] | 50.0% | 2.50 | 10 |" in out
    assert "| SB3 PPO, MultiDiscrete | scaled | test textures | 1 | 1.000 [1.00] | 3.000 | 0.500 [0.50] | 2.000 | 10 |" in out
