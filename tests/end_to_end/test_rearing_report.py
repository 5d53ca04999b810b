"""experiments/rearing/report.py: the rearing suite's table and figure, on constructed run folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from aectorch.coding.readouts import code_summary
from aectorch.runtime.presets import REARING

from tests.end_to_end import study_module

report = study_module("rearing", "report")
main, code_numbers, rearing_condition, rearing_runs = (report.main, report.code_numbers, report.rearing_condition,
                                                       report.rearing_runs)


def _atoms(seed: int, eye: str | None) -> torch.Tensor:
    """16 atoms of 4 x 4 halves: binocular (both halves noise) or of one eye only."""
    atoms = torch.randn(32, 16, generator=torch.Generator().manual_seed(seed))
    if eye == "left":
        atoms[16:] = 0
    elif eye == "right":
        atoms[:16] = 0
    elif eye == "split":  # half the atoms of each eye only
        atoms[16:, :8] = 0
        atoms[:16, 8:] = 0
    return atoms


def _run(folder: Path, condition: str, seed: int, eye: str | None, seconds: float, correction=None,
         eye_at_correction: str | None = "none") -> Path:
    folder.mkdir(parents=True)
    OmegaConf.save(OmegaConf.create({"seed": seed, "perturbations": REARING[condition]}), folder / "config.yaml")
    summary = {"train_seconds": seconds, "final": {"vergence_mae_deg": 0.5 + seed},
               "evaluation": {"vergence_mae_deg": 0.1 * (seed + 1)},
               "code": {f"{cue}/fine": code_summary(_atoms(seed, eye)) for cue in ("parallax", "stereo")},
               "code_initial": {"stereo/fine": code_summary(_atoms(seed + 10, None))}}
    if correction is not None:
        vergence = {"before": correction[0], "final": correction[1], "iterations_to_recover": 40}
        summary["perturbation"] = {"recovery": {"right eye blurred, corrected early ends": {
            "iteration": 600, "vergence": vergence}}}
    if eye_at_correction != "none":  # the code as the perturbation left it
        summary["perturbation"]["code"] = {"right eye 2 D myopic, corrected early ends": {
            "iteration": 600, "code": {"stereo/fine": code_summary(_atoms(seed, eye_at_correction))}}}
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def test_the_table_reads_each_condition_from_its_runs(tmp_path, capsys):
    _run(tmp_path / "normal_s0", "normal", 0, None, 100.0)
    _run(tmp_path / "normal_s1", "normal", 1, None, 110.0)
    _run(tmp_path / "monocular_s0", "monocular", 0, "left", 120.0)
    _run(tmp_path / "anisometropia_early_s0", "anisometropia_early", 0, None, 130.0, correction=(2.0, 0.3))
    (tmp_path / "unfinished").mkdir()  # no summary.json: not a run of the suite
    plot = tmp_path / "out" / "rearing.png"
    assert main([str(tmp_path), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out.splitlines()
    # Conditions in REARING's order, one row per stereo dictionary; the left-eye atoms are all
    # left-dominated, with index exactly -1.
    assert out[2].startswith("| normal (2) | stereo/fine | ") and "| 0 (0-0) | 0 (0-0) |" in out[2]
    assert out[3].startswith("| monocular (1) | stereo/fine | 1.000 [") and "| -0.86 | 100 | 0 |" in out[3]
    assert out[4].startswith("| anisometropia_early (1) | stereo/fine |")
    assert out[8] == "| normal (2) | 0.150 (0.100-0.200) | 1.000 (0.500-1.500) | - | 105 (100-110) |"
    assert out[10] == "| anisometropia_early (1) | 0.100 | 0.500 | 2.000 -> 0.300 | 130 |"
    suite = out.index("suite: 4 runs, training 7.7 min in all (460 s; summary.json's train_seconds summed)")
    assert out[suite + 1] == f"wrote {plot}" and plot.stat().st_size > 10_000
    verdicts = out[out.index("| the lineage's result | source | here (means over the seeds) | agrees |") + 2:suite - 1]
    assert len(verdicts) == 7 and verdicts[0].startswith("| normal rearing: mostly binocular atoms |")
    assert verdicts[0].endswith("| yes |") and verdicts[1].endswith("| yes |")  # binocular; the open eye's
    assert verdicts[2].endswith("| not run | - |")  # no strabismus run


def test_the_verdicts_test_each_lineage_result_against_its_numbers(tmp_path):
    lineage_verdicts = report.lineage_verdicts

    _run(tmp_path / "normal_s0", "normal", 0, None, 1.0)
    _run(tmp_path / "strabismus_s0", "strabismus", 0, "split", 1.0)
    _run(tmp_path / "monocular_s0", "monocular", 0, "right", 1.0)  # dominated by the closed eye
    _run(tmp_path / "strabismus_3deg_s0", "strabismus_3deg", 0, None, 1.0)
    verdicts = {v["result"].split(":")[0]: v for v in lineage_verdicts(rearing_runs(tmp_path))}
    assert verdicts["normal rearing"]["agrees"] is True
    assert verdicts["strabismus (10 deg)"]["agrees"] is True
    assert verdicts["strabismus (10 deg)"]["numbers"] == "fine: 100 % dominated (50 % left, 50 % right)"
    assert verdicts["monocular deprivation"]["agrees"] is False
    # The 3 deg squint's atoms are the normal run's: no shift of the disparity preference.
    assert verdicts["strabismus (3 deg)"]["agrees"] is False and "fine +0.00" in verdicts["strabismus (3 deg)"]["numbers"]
    assert verdicts["orientation rearing"]["agrees"] is None


def test_the_code_at_the_correction_is_read_beside_the_code_at_the_end(tmp_path, capsys):
    _run(tmp_path / "anisometropia_early_s0", "anisometropia_early", 0, None, 130.0, correction=(2.0, 0.3))
    for seed in (0, 1):  # the left eye's atoms at the correction, binocular ones at the end
        _run(tmp_path / f"refractive_early_s{seed}", "refractive_early", seed, None, 100.0, correction=(1.0, 0.2),
             eye_at_correction="left")
    plot = tmp_path / "rearing.png"
    _run(tmp_path / "later" / "refractive_early_s2", "refractive_early", 2, None, 100.0, correction=(1.0, 0.2))
    assert main([str(tmp_path), str(tmp_path / "later"), "--plot", str(plot)]) == 0  # two sweeps
    out = capsys.readouterr().out.splitlines()
    at = out.index("| condition (runs) | dictionary | at the correction -> at the end: mean abs. binocularity index "
                   "| mean index | left-dominated % | right-dominated % |")
    # Only the runs that read the code at their correction (not the older anisometropia run).
    assert len(out[at + 2:out.index("", at)]) == 1
    row = out[at + 2].split(" | ")
    assert out[3].startswith("| refractive_early (3) | stereo/fine |")  # the later sweep's run too
    assert row[:2] == ["| refractive_early (2)", "stereo/fine"]
    assert row[2].startswith("1.000 (1.000-1.000) -> 0.") and row[4] == "100 (100-100) -> 0 (0-0)"
    assert row[3].startswith("-0.86 (-0.86--0.86) -> ") and plot.stat().st_size > 10_000


def test_a_run_of_no_condition_is_named(tmp_path, capsys):
    folder = _run(tmp_path / "odd", "normal", 0, None, 1.0)
    OmegaConf.save(OmegaConf.create({"perturbations": [{"kind": "roll", "start": 0, "eye": "right",
                                                        "params": {"deg": 3.0}}]}), folder / "config.yaml")
    assert main([str(tmp_path)]) == 2
    assert "are those of no rearing condition" in capsys.readouterr().err
    assert main([str(tmp_path / "missing")]) == 2
    _run(tmp_path / "again" / "normal_s0", "normal", 0, None, 1.0)
    with pytest.raises(ValueError, match="runs of the same condition and seed"):
        rearing_runs(tmp_path / "again", tmp_path / "again")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="holds no finished run"):
        rearing_runs(tmp_path / "empty")


def test_every_condition_is_recognised_and_the_shares_count_the_bins():
    for name, events in REARING.items():
        assert rearing_condition({"perturbations": [{**e, "label": "ignored"} for e in events]}) == name
    numbers = code_numbers(code_summary(_atoms(0, "right")))
    assert (numbers["mean_abs_index"], numbers["left"], numbers["right"]) == (1.0, 0.0, 1.0)
    assert numbers["mean_index"] == pytest.approx(6 / 7)  # the last bin's centre
    balanced = code_numbers(code_summary(torch.cat([_atoms(1, "left")[:16]] * 2)))
    assert (balanced["mean_abs_index"], balanced["left"], balanced["right"]) == (0.0, 0.0, 0.0)


def test_scales_keep_only_those_dictionaries(tmp_path, capsys):
    folder = _run(tmp_path / "monocular_s0", "monocular", 0, "left", 120.0)
    summary = json.loads((folder / "summary.json").read_text())
    summary["code"]["stereo/full"] = code_summary(_atoms(5, None))
    (folder / "summary.json").write_text(json.dumps(summary))
    assert main([str(tmp_path)]) == 0
    every = capsys.readouterr().out.splitlines()
    assert [line.split(" | ")[1] for line in every[2:4]] == ["stereo/fine", "stereo/full"]
    assert main([str(tmp_path), "--scales", "full"]) == 0
    only = capsys.readouterr().out.splitlines()
    assert only[2] == every[3] and only[3] == "" and only[5:] == every[6:]  # the other tables unchanged
    assert main([str(tmp_path), "--scales", "coarse"]) == 2
    assert "scales: ['coarse'] are not among the 'stereo' cue's dictionaries ['fine', 'full']" in capsys.readouterr().err


def test_the_report_s_examples_hold():
    import doctest

    assert doctest.testmod(report).failed == 0
