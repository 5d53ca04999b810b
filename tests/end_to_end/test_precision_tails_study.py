"""The precision-and-tails study's report (experiments/precision_tails/report.py): the tails of
groups of runs on constructed evaluations, and at a tiny size on a tiny run's evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.end_to_end import EXPERIMENTS, TINY, noise_images, run_script, study_module
from tests.report.test_report import _rows

report = study_module("precision_tails", "report")
main = report.main


def test_the_tails_count_the_far_ends_compare_near_and_far_and_list_the_worst_with_their_views(tmp_path, capsys):
    def folder(name: str, trials) -> Path:
        run = tmp_path / name
        run.mkdir()
        rows = _rows(trials)
        for i, row in enumerate(rows):  # the flat view is the failing one
            row.update(view_contrast=0.001 if row["texture"] == "flat" else 0.3, view_energy_full=1e-6 * (i + 1))
        (run / "final_choose.json").write_text(json.dumps({"per_trial": rows}))
        return run

    a = folder("a", [("flat", 1.0, [0.1, 0.0], [-12.0, 1.5]),  # ends beyond 2 and beyond 1 deg
                     ("texture", 2.0, [0.1, 0.1], [0.1, 0.1])])
    b = folder("b", [("texture", 1.2, [0.3, 0.0], [0.0, 0.0]), ("texture", 3.0, [0.0, 0.0], [0.0, 0.2])])
    assert main([f"g={a},{b}", "--eval", "final_choose.json", "--worst", "2",
                 "--json", str(tmp_path / "t.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    # 8 fixation ends; within 0.22 deg: a 2 of 4, b 3 of 4; MAEs are the means of the runs' (vergence:
    # a 13.7 / 4, b 0.2 / 4; near: a 6.75, b 0; far: 0.1 each)
    assert lines[2] == ("| g | 8 | 62.5% | 2 (25.0%) | 1 (12.5%) | 0.075 / 1.737 | 0.100 / 3.375 | 0.050 / 0.100 "
                        "| 33.75x |")
    result = json.loads((tmp_path / "t.json").read_text())["g"]
    assert [w["errors_deg"]["vergence"] for w in result["worst"]] == [-12.0, 1.5]
    # the one end beyond 2 deg is a vergence short of its optimum (diverged): counted by its kind
    assert result["all"]["beyond_2_vergence-"] == 1 and result["all"]["beyond_2_vergence+"] == 0
    assert result["all"]["beyond_2_pursuit+"] == result["all"]["beyond_2_pursuit-"] == 0
    assert lines[3:5] == ["", "g: the ends beyond 2 deg by the movement of the largest error and its sign (vergence + "
                        "past the optimum, - short of it): vergence- 1"]
    # without the ends beyond 1 deg: run a's vergence is its two 0.1 deg ends
    assert [r["inside_vergence_mae_deg"] for r in result["runs"]] == pytest.approx([0.1, 0.05])
    assert "| g 0 | 3.425 | 0.100 | 2 |" in lines
    assert result["worst"][0]["texture"] == "flat" and result["worst"][0]["view_contrast"] == 0.001
    assert result["views"]["beyond_1"] == {"trials": 1, "view_contrast": 0.001, "view_energy_full": 1e-6}
    assert result["views"]["all"]["trials"] == 4 and result["views"]["all"]["view_contrast"] == pytest.approx(0.3)
    assert any(line.startswith("| g, with an end beyond 1 deg | 1 | 0.001 | 1e-06 |") for line in lines)
    assert main(["no-runs"]) == 2
    assert "name=run,run" in capsys.readouterr().err


@pytest.mark.integration
def test_a_tiny_runs_tails_are_counted_as_the_readme_counts_them(tmp_path):
    photos = noise_images(tmp_path / "textures", 2, 64, seed=0)
    run = tmp_path / "range_s0"
    done = run_script("train.py", f"env.textures={photos}", *TINY, "train.iterations=4", f"eval.textures={photos}",
                      "eval.distances_m=[1.0,2.0]", f"hydra.run.dir={run}")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    out = tmp_path / "tails.json"
    done = run_script(str(EXPERIMENTS / "precision_tails" / "report.py"), f"range={run}", "--worst", "3",
                      "--json", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines()[2].startswith("| range | 8 | ")  # 2 textures x 2 distances, two ends each
    result = json.loads(out.read_text())["range"]
    assert len(result["worst"]) == 3 and set(result["views"]) == {"all", "beyond_1"}
    assert any(key.startswith("view_") for key in result["worst"][0])


def test_the_report_s_examples_hold():
    import doctest

    assert doctest.testmod(report).failed == 0
