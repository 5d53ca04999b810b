"""The accommodation study's scripts (experiments/accommodation): the table of groups of runs on
constructed run folders, and every script at a tiny size (a tiny accommodation run, its table, its
policy against defocus and the rewards against defocus)."""

from __future__ import annotations

import json

import pytest

from aectorch.sim import PinholeCamera

from tests.end_to_end import EXPERIMENTS, TINY, noise_images, run_script, study_module

STUDY = EXPERIMENTS / "accommodation"
main = study_module("accommodation", "report").main


def test_the_table_gives_each_groups_mean_and_sd(tmp_path, capsys):
    def run(name, vergence, mae_D=None):
        folder = tmp_path / name
        folder.mkdir()
        result = {"vergence_mae_deg": vergence, "pursuit_mae_deg": 0.03, "depth_mae_m": 0.05}
        if mae_D is not None:
            result["accommodation_focus"] = {"mae_D": mae_D, "mae_px": 4 * mae_D, "within_0.25px": 0.1,
                                             "within_0.5px": 0.2}
            px = PinholeCamera().degrees_per_pixel  # two fixation ends per trial, in blur-disc degrees
            result["per_trial"] = [{"distance_m": 1.0, "accommodation_errors_deg": [-mae_D * px, -0.5 * px]},
                                   {"distance_m": 3.0, "accommodation_errors_deg": [0.25 * px, 0.25 * px]}]
        (folder / "evaluation.json").write_text(json.dumps(result))
        return str(folder)

    acc = ",".join(run(f"a{i}", v, d) for i, (v, d) in enumerate([(0.02, 0.4), (0.04, 0.6)]))
    plain = ",".join(run(f"p{i}", v) for i, v in enumerate([0.05, 0.05]))
    assert main([f"with={acc}", f"plain={plain}"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| | with (2 seeds) | plain (2 seeds) |"
    assert "| vergence MAE (deg) | 0.030 +- 0.014 | 0.050 +- 0.000 |" in lines
    assert "| accommodation MAE (D) | 0.500 +- 0.141 | - |" in lines
    assert main([f"with={acc}", f"plain={plain}", "--per-distance"]) == 0
    lines = capsys.readouterr().out.splitlines()
    at = lines.index("| distance (m) | with: px, mean abs. / signed | plain: px, mean abs. / signed |")
    assert lines[at + 2:] == ["| 1 | 0.50 / -0.50 | - |", "| 3 | 0.25 / +0.25 | - |"]  # (0.4 + 0.5 + 0.6 + 0.5) / 4
    assert main([f"plain={plain}", "--per-distance"]) == 2
    assert "no per-trial accommodation errors" in capsys.readouterr().err
    assert main(["nogroup"]) == 2
    assert "groups are name=run,run,..." in capsys.readouterr().err


@pytest.mark.integration
def test_a_tiny_accommodation_run_is_tabulated_and_its_policy_read(tmp_path):
    photos = noise_images(tmp_path / "textures", 2, 64, seed=0)
    run = tmp_path / "acc_s0"
    done = run_script("train.py", "+experiment=accommodation", f"env.textures={photos}", *TINY,
                      "learner.cues.accommodation.encoder.num_atoms=16", "train.iterations=4",
                      f"eval.textures={photos}", "eval.distances_m=[1.0]", f"hydra.run.dir={run}")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    done = run_script(str(STUDY / "report.py"), f"accommodation={run}", "--per-distance")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "| accommodation (1 seeds) |" in done.stdout and "| distance (m) | accommodation: px" in done.stdout
    done = run_script(str(STUDY / "policy.py"), str(run / "checkpoint.pt"), "--textures", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    rows = done.stdout.splitlines()
    assert rows[0].startswith("distance | -0.8 D: increment (deg), reward") and [r[:5] for r in rows[1:]] == [
        "1.0 m", "2.0 m", "3.0 m"]


@pytest.mark.integration
def test_the_focus_curve_draws_the_rewards_against_defocus(tmp_path):
    photos = noise_images(tmp_path / "photos", 2, 64, seed=1)
    out = tmp_path / "curve" / "focus.png"
    done = run_script(str(STUDY / "focus_curve.py"), "--photos", str(photos), "--out", str(out), "--steps", "1",
                      "--batch", "2", "--textures", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines()[-1] == f"wrote {out}" and out.stat().st_size > 10_000
    result = json.loads(out.with_suffix(".json").read_text())
    assert len(result["textures"]["defocus_D"]) == 21 and set(result) >= {"textures", "photographs"}


def test_the_focus_curve_s_examples_hold():
    import doctest

    assert doctest.testmod(study_module("accommodation", "focus_curve")).failed == 0
