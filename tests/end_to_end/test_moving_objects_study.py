"""The moving-object study's commands (experiments/moving_objects) at a tiny size: a run trained
with the object moving, its tracking test (``python -m aectorch.evaluate ... tracking=[...]``) and
the study's table and figure. tests/test_evaluate_cli.py checks the table's numbers against the
per-trial rows."""

from __future__ import annotations

import pytest

from tests.end_to_end import EXPERIMENTS, TINY, noise_images, run_script, study_module

STUDY = EXPERIMENTS / "moving_objects"
main = study_module("moving_objects", "report").main


@pytest.mark.integration
def test_a_tiny_moving_object_run_is_tracked_and_tabulated(tmp_path):
    photos = noise_images(tmp_path / "textures", 2, 64, seed=0)
    run = tmp_path / "slip_s0"
    done = run_script("train.py", "+experiment=slip", f"env.textures={photos}", *TINY, "train.iterations=4",
                      "eval.enabled=false", "env.object_speed_deg=[-1.25,1.25]", f"hydra.run.dir={run}")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    done = run_script("-m", "aectorch.evaluate", f"checkpoint={run / 'checkpoint.pt'}", f"textures={photos}",
                      "depths=[1.0]", "tracking=[0,1]", "skip=1", "progress=false",
                      f"out={run / 'tracking_report.json'}")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    plot = tmp_path / "tracking.png"
    done = run_script(str(STUDY / "report.py"), str(run), "--eval", "tracking_report.json", "--within", "0.5",
                      "--plot", str(plot), "--target", "0.2")
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("1 runs, mean |error| (deg) after each fixation's first 1 iterations")
    assert "pursuit within 0.5 (%)" in lines[1] and [line.split(" | ")[0] for line in lines[3:5]] == ["| 0", "| 1"]
    assert lines[-1] == f"wrote {plot}" and plot.stat().st_size > 10_000
    done = run_script(str(STUDY / "report.py"), str(tmp_path / "textures"))
    assert done.returncode == 2 and done.stderr.startswith("error: ")
