"""aectorch.runs (the run-folder reader) and python -m aectorch.report, whose tables docs/results.md shows."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from aectorch.evaluation.summary import BEYOND_DEG, WITHIN_DEG
from aectorch.report.__main__ import main
from aectorch.report.tables import band
from aectorch.runs import Run, read_json, read_metrics

ROOT = Path(__file__).resolve().parents[2]


def _run(folder: Path, lines: list[dict], events=None) -> Path:
    folder.mkdir()
    (folder / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    if events is not None:
        (folder / "summary.json").write_text(json.dumps({"perturbation": {"events": events}}))
    return folder


def _rows(trials: list[tuple[str, float, list[float], list[float]]]) -> list[dict]:
    return [{"texture": t, "distance_m": d, "pursuit_error_deg": p[-1], "vergence_error_deg": v[-1],
             "depth_error_m": 0.01, "pursuit_errors_deg": p, "vergence_errors_deg": v} for t, d, p, v in trials]


def _evaluation(path: Path, spec, **extra) -> Path:
    path.write_text(json.dumps({"per_trial": _rows(spec), **extra}))
    return path


def _finished(folder: Path, seed: int, mae: float, train_s: float = 60.0) -> Path:
    """A run folder as train.py and two `python -m aectorch.evaluate` calls leave it."""
    folder.mkdir()
    (folder / "config.yaml").write_text(f"seed: {seed}\nenv:\n  num_envs: 4\n")
    (folder / "metrics.jsonl").write_text("".join(
        json.dumps({"iteration": i, "pursuit_mae_deg": mae * i, "vergence_mae_deg": mae}) + "\n" for i in (10, 20)))
    (folder / "summary.json").write_text(json.dumps({
        "iterations": 20, "train_seconds": train_s, "best": None,
        "final": {"pursuit_mae_deg": 0.1, "vergence_mae_deg": 0.2, "depth_mae_m": 0.3}}))
    result = {"pursuit_mae_deg": mae, "vergence_mae_deg": mae / 2, "depth_mae_m": 0.05, "trials": 3,
              "pursuit": {"median_abs": 0.2}, "vergence": {"median_abs": 0.0}, "depth": {"median_abs": 0.01},
              "fractions": {"both": {"within": 0.5, "beyond": 0.25}, "vergence": {"within": 0.75, "beyond": 0.0}},
              "last5": {"pursuit_mae_deg": mae / 3, "vergence_mae_deg": mae / 4,
                        "fractions": {"both": {"within": 0.6, "beyond": 0.0}}}}
    spec = [("x", 1.0, [0.1, -0.3], [0.0, 0.0]), ("x", 1.5, [0.2, 0.2], [0.1, 0.1]), ("x", 3.0, [5.0, 5.0], [0, 0])]
    for name in ("evaluation.json", "final_textures.json", "final_choose.json"):
        _evaluation(folder / name, spec, **result)
    return folder


def test_the_reader_reads_each_file_of_a_run_and_names_what_is_missing(tmp_path):
    run = Run(_finished(tmp_path / "run", seed=3, mae=1.0))
    assert run.config["seed"] == 3 and run.config["env"]["num_envs"] == 4
    assert [line["iteration"] for line in run.metrics] == [10, 20] and run.metrics_at[20]["pursuit_mae_deg"] == 20.0
    assert run.summary["iterations"] == 20 and len(run.per_trial("final_choose.json")) == 3
    with pytest.raises(FileNotFoundError, match="provenance.json: no such file"):
        run.provenance
    with pytest.raises(FileNotFoundError, match="no such folder"):
        Run(tmp_path / "nowhere")
    (tmp_path / "old.json").write_text(json.dumps({"pursuit_mae_deg": 1.0}))
    with pytest.raises(KeyError, match="no per_trial rows"):
        Run(tmp_path).per_trial("old.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="must hold a JSON object"):
        read_json(tmp_path / "list.json")


def test_read_metrics_round_trip_and_truncated_last_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    records = [{"iteration": i, "pursuit_mae_deg": 1.0 / i, "depth_mae_m": math.nan if i < 3 else 0.5}
               for i in range(1, 6)]
    path.write_text("\n".join(json.dumps(r) for r in records) + "\n\n")  # (NaN as train.py writes it)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_metrics(path)
    assert [r["iteration"] for r in back] == [1, 2, 3, 4, 5] and math.isnan(back[0]["depth_mae_m"])
    assert back[4] == records[4]
    path.write_text(path.read_text() + '{"iteration": 6, "pur')
    with pytest.warns(UserWarning, match="skipping truncated last line"):
        assert len(read_metrics(path)) == 5
    path.write_text(json.dumps(records[0]) + "\nnot json\n" + json.dumps(records[1]) + "\n")
    with pytest.raises(ValueError, match="line 2 is not valid JSON"):
        read_metrics(path)


def test_curves_prints_the_runs_side_by_side(tmp_path, capsys):
    a = _run(tmp_path / "a", [{"iteration": i, "pursuit_mae_deg": i / 100, "vergence_mae_deg": None}
                              for i in (25, 50, 75, 100)], events=[{"iteration": 60, "label": "rolled"}])
    b = _run(tmp_path / "b", [{"iteration": i, "pursuit_mae_deg": 2.0, "vergence_mae_deg": 0.5} for i in (50, 100)])
    plot = tmp_path / "out" / "cmp.png"
    assert main(["curves", str(a), str(b), "--names", "x", "y", "--every", "25", "--from", "50",
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
def test_curves_rejects_bad_arguments(tmp_path, capsys, args, message):
    a = _run(tmp_path / "a", [{"iteration": 1}])
    b = _run(tmp_path / "b", [{"iteration": 1}])
    assert main(["curves", str(a), str(b), *args]) == 2
    assert message in capsys.readouterr().err


def test_a_folder_without_the_file_asked_for_is_one_error_line(tmp_path, capsys):
    assert main(["curves", str(tmp_path)]) == 2
    assert "has no metrics.jsonl" in capsys.readouterr().err
    assert main(["table", str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.startswith("error: run folder")


def test_trials_counts_the_fixation_ends_that_agree(tmp_path, capsys):
    a = _evaluation(tmp_path / "a.json", [("x", 1.0, [0.1, 0.0], [0.0, 0.0]), ("y", 2.0, [0.0, 0.0], [0.5, 0.0])])
    b = _evaluation(tmp_path / "b.json", [("y", 2.0, [0.04, 0.0], [0.0, 0.0]), ("x", 1.0, [0.1, 0.0], [0.0, 0.2])])
    assert main(["trials", str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    result = json.loads((tmp_path / "c.json").read_text())
    assert result["pursuit"]["agree"] == 1.0  # 0.04 deg apart is within 0.05
    assert result["vergence"]["agree"] == 0.5 and result["vergence"]["max_difference_deg"] == 0.5
    assert result["vergence"]["worst"][0]["texture"] == "y" and result["both_agree_trials"] == 0.0
    assert "pursuit" in capsys.readouterr().out
    c = _evaluation(tmp_path / "d.json", [("x", 1.0, [0.1, 0.0], [0.0, 0.0])])
    assert main(["trials", str(a), str(c)]) == 2
    assert "different trials" in capsys.readouterr().err


def test_table_reports_the_near_trials_the_fractions_and_the_spread_of_the_runs(tmp_path, capsys):
    runs = [_finished(tmp_path / f"s{seed}", seed=seed, mae=seed - 2.0) for seed in (3, 4)]
    assert main(["table", *map(str, runs)]) == 0
    header, _, row, _, spread = capsys.readouterr().out.splitlines()
    cells = dict(zip(header.strip("| ").split(" | "), row.strip("| ").split(" | ")))
    assert cells["seed"] == "3" and cells["pursuit MAE (deg)"] == "1.000"
    assert cells["1.0-1.5 m pursuit MAE (deg)"] == "0.200" and cells["1.0-1.5 m vergence MAE (deg)"] == "0.050"
    assert cells[f"both within {WITHIN_DEG} deg"] == "0.500" and cells["evaluated (best.pt: iteration)"] == "last"
    assert dict(zip(header.strip("| ").split(" | "), spread.strip("| ").split(" | ")))["pursuit MAE (deg)"] \
        == "1.500 +- 0.707"


def test_band_counts_fixation_ends_by_the_evaluations_thresholds():
    # Both ends of each trial: on target is |error| <= WITHIN_DEG in every movement, failed is
    # |error| > BEYOND_DEG in any: the thresholds and the rule of aectorch.evaluation.summary.
    rows = _rows([("a", 1.0, [WITHIN_DEG, -WITHIN_DEG], [0.0, 0.0]),  # both ends on target
                  ("b", 1.2, [WITHIN_DEG + 0.01, 0.0], [0.0, -BEYOND_DEG]),  # neither, and not failed
                  ("c", 1.4, [0.0, 0.0], [0.0, BEYOND_DEG + 0.01]),  # on target, then failed
                  ("far", 3.0, [9.0, 9.0], [9.0, 9.0])])
    out = band(rows, 1.0, 1.5)
    assert out["trials"] == 3 and out["within"] == pytest.approx(3 / 6) and out["beyond"] == pytest.approx(1 / 6)
    assert out["pursuit_mae_deg"] == pytest.approx((3 * WITHIN_DEG + 0.01) / 6)
    with pytest.raises(ValueError, match="no trial at 2.0-2.5 m"):
        band(rows, 2.0, 2.5)


def test_band_and_ablation_read_the_evaluations_they_name(tmp_path, capsys):
    runs = [_finished(tmp_path / f"s{seed}", seed=seed, mae=1.0) for seed in (0, 1)]
    assert main(["band", *map(str, runs), "--eval", "final_choose.json", "--low", "1.0", "--high", "1.5"]) == 0
    assert capsys.readouterr().out.startswith("1.0-1.5 m, final_choose.json, mean of 2 runs: pursuit 0.200 deg, "
                                              "vergence 0.050 deg")
    assert main(["ablation", f"first={runs[0]}", f"second={runs[1]}:_missing", "--json", str(tmp_path / "a.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2] == "| first | 1.000 / 0.500 / 0.050 | 50.0% / 25.0% | 0.333 / 0.250 | 1.000 / 0.500 / 0.050 " \
                       "| 50.0% / 25.0% | 0.333 / 0.250 |"
    assert lines[3] == "| second | n/a | n/a | n/a | n/a | n/a | n/a |"
    assert json.loads((tmp_path / "a.json").read_text())["second"]["suffix"] == "_missing"
    assert main(["ablation", "no-label"]) == 2
    assert "label=run[:suffix]" in capsys.readouterr().err


def test_compare_gives_each_groups_mean_and_sd_and_plots_its_curves(tmp_path, capsys):
    runs = [_finished(tmp_path / f"s{seed}", seed=seed, mae=1.0 + seed, train_s=60.0 * (1 + seed)) for seed in (0, 1)]
    plot, out = tmp_path / "groups.png", tmp_path / "groups.json"
    assert main(["compare", f"both={runs[0]},{runs[1]}", f"one={runs[0]}", "--evals", "photos=final_choose.json",
                 "--json", str(out), "--plot", str(plot)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2].startswith("| photos | both | 1.500 (0.707) | 0.750 (0.354) | 0.050 (0.000) | 50.0% | 25.0% | "
                               "0.500 / 0.375, 60.0% | 0.100 / 0.200 | 90 (42) |")
    assert lines[3].startswith("| photos | one | 1.000 (0.000) |")
    table = json.loads(out.read_text())["table"]
    assert table["photos"]["both"]["pursuit_mae_deg"]["runs"] == [1.0, 2.0] and plot.stat().st_size > 0


@pytest.mark.integration
def test_the_command_line_lists_its_commands():
    done = subprocess.run([sys.executable, "-m", "aectorch.report", "--help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0
    for command in ("table", "compare", "curves", "band", "trials", "ablation", "matcher", "offsets",
                    "depth-readout", "depth-tolerance"):
        assert command in done.stdout


def _code_run(folder: Path, seed: int) -> Path:
    import torch

    from aectorch.coding.readouts import code_summary

    generator = torch.Generator().manual_seed(seed)
    code = {name: code_summary(torch.randn(200, 16, generator=generator)) for name in ("parallax/fine", "stereo/fine")}
    start = {name: code_summary(torch.randn(200, 16, generator=generator)) for name in code}
    folder.mkdir()
    (folder / "summary.json").write_text(json.dumps({"code": code, "code_initial": start}))
    return folder


def test_code_gives_each_groups_mean_and_range_beside_the_start(tmp_path, capsys):
    runs = [_code_run(tmp_path / f"s{seed}", seed) for seed in range(3)]
    plot = tmp_path / "out" / "binocularity.png"
    assert main(["code", f"normal={runs[0]},{runs[1]}", str(runs[2]), "--cue", "stereo", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 5 and out[2].startswith("| normal (2) | stereo/fine | ") and out[3].startswith("| s2 (1) | ")
    codes = [Run(run).code for run in runs[:2]]
    index = [c["stereo/fine"]["binocularity"]["mean_abs_index"] for c in codes]
    start = [c["initial"]["stereo/fine"]["binocularity"]["mean_abs_index"] for c in codes]
    expected = f"{sum(index) / 2:.3f} ({min(index):.3f}-{max(index):.3f}) [{sum(start) / 2:.3f}]"
    assert out[2].split(" | ")[2] == expected
    assert plot.stat().st_size > 0 and out[4] == f"wrote {plot}"


@pytest.mark.parametrize("args, message", [
    (["x=", "--cue", "stereo"], "a group must be"),
    (["a={one}", "a={two}"], "distinct"),
    (["nowhere"], "no such folder"),
])
def test_code_rejects_bad_groups(tmp_path, capsys, args, message):
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    args = [a.format(one=tmp_path / "one", two=tmp_path / "two") for a in args]
    assert main(["code", *[a if "=" in a or a.startswith("--") or a == "stereo" else str(tmp_path / a)
                           for a in args]]) == 2
    assert message in capsys.readouterr().err
