"""Tests of aectorch.figures (and the report's plot_code_comparison, on its panels): the figures, from
plain data to a PNG."""

from __future__ import annotations

import json
import math

import matplotlib.image
import pytest
import torch

from aectorch.figures import (
    DPI,
    plot_code,
    plot_dictionaries,
    plot_evaluation,
    plot_perturbation,
    plot_training,
)
from aectorch.report.code import plot_code_comparison

torch.set_num_threads(1)
KEYS = ("parallax/coarse", "parallax/fine", "stereo/coarse", "stereo/fine")


def read_png(path):
    assert path.exists() and path.stat().st_size > 1000
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    assert image.ndim == 3 and image.shape[2] in (3, 4)
    return image


def records_run(n=60, event=None):
    """A training run: errors decay; depth NaN before iteration 20; optional jump at ``event``."""
    out = []
    for i in range(n):
        it = 100 * i
        bump = 4.0 if event is not None and it >= event else 0.0
        out.append({
            "iteration": it,
            "pursuit_mae_deg": 2.0 / (1 + i) + 0.1,
            "vergence_mae_deg": 3.0 / (1 + i) + 0.1 + bump,
            "depth_mae_m": math.nan if i < 20 else 0.5 / (1 + i),
        })
    return out


# ---------------------------------------------------------------------------------------------
# plot_dictionaries


def test_plot_dictionaries_writes_png(tmp_path):
    gen = torch.Generator().manual_seed(4)
    keys = KEYS[::3]  # any subset of the four dictionaries (two rows keep the test fast)
    initial = {k: torch.randn(200, 48, generator=gen) for k in keys}
    trained = {k: torch.nn.functional.normalize(torch.randn(200, 48, generator=gen, dtype=torch.float64), dim=0)
               for k in keys}  # dtypes may differ between the two
    out = plot_dictionaries(initial, trained, tmp_path / "nested" / "fig2.png")
    assert out == tmp_path / "nested" / "fig2.png"
    image = read_png(out)
    h, w = image.shape[:2]
    assert 800 <= w <= 1100 and 2 * 380 <= h <= 2 * 500  # 2 panels wide, one row per key


def test_plot_dictionaries_bad_input(tmp_path):
    d = {"stereo/fine": torch.randn(20, 30)}
    with pytest.raises(ValueError, match=r"trained is missing key 'stereo/coarse'"):
        plot_dictionaries({**d, "stereo/coarse": torch.randn(20, 30)}, d, tmp_path / "b.png")
    with pytest.raises(ValueError, match=r"initial is missing key 'stereo/coarse'"):
        plot_dictionaries(d, {**d, "stereo/coarse": torch.randn(20, 30)}, tmp_path / "b.png")
    with pytest.raises(ValueError, match=r"trained\['stereo/fine'\]"):
        plot_dictionaries(d, {"stereo/fine": torch.randn(20)}, tmp_path / "b.png")
    with pytest.raises(ValueError, match="initial"):
        plot_dictionaries({}, {}, tmp_path / "b.png")
    assert not (tmp_path / "b.png").exists()


# ---------------------------------------------------------------------------------------------
# plot_training / plot_perturbation


def test_the_eye_axis_names_the_velocitys_unit():
    """The slip cue's pursuit velocity is in degrees per iteration, beside the angles in degrees."""
    from aectorch.figures import _eye_ylabel
    assert _eye_ylabel(["pursuit", "vergence"]) == "eye movement MAE (deg)"
    assert _eye_ylabel(["pursuit", "vergence", "pursuit_velocity"]) == \
        "eye movement MAE (deg; velocity: deg per iteration)"


def test_plot_training_two_panels_with_gaps_and_events(tmp_path):
    records = records_run()
    records[30]["pursuit_mae_deg"] = None  # a gap
    del records[31]["vergence_mae_deg"]    # a missing key is a gap too
    out = plot_training(records, tmp_path / "fig3.png", events=[(2000, "depth fit"), (4000, "")])
    h, w = read_png(out).shape[:2]
    assert 900 <= w <= 1000 and 600 <= h <= 800


def test_plot_training_four_panels_when_policy_metrics_exist(tmp_path):
    records = records_run()
    for i, r in enumerate(records):
        r.update({"parallax/reward": -1 + i / 100, "stereo/reward": -2 + i / 50,
                  "parallax/entropy": 2 - i / 60, "stereo/entropy": math.nan})
    h, w = read_png(plot_training(records, tmp_path / "four.png")).shape[:2]
    assert 900 <= w <= 1000 and 1200 <= h <= 1500  # twice the height of the two-panel figure


def test_plot_training_all_nan_and_bad_input(tmp_path):
    records = [{"iteration": i, "depth_mae_m": None} for i in range(5)]
    read_png(plot_training(records, tmp_path / "empty.png"))
    with pytest.raises(ValueError, match=r"records\[1\] has no 'iteration'"):
        plot_training([{"iteration": 0}, {"pursuit_mae_deg": 1.0}], tmp_path / "x.png")
    with pytest.raises(ValueError, match="records must not be empty"):
        plot_training([], tmp_path / "x.png")
    with pytest.raises(ValueError, match=r"events\[0\]"):
        plot_training(records, tmp_path / "x.png", events=[(None, "bad")])
    with pytest.raises(ValueError, match="path"):
        plot_training(records, tmp_path / "no_suffix")


def test_plot_perturbation(tmp_path):
    records = records_run(100, event=5000)
    out = plot_perturbation(records, tmp_path / "fig4.png", events=[(5000, "left roll")])
    read_png(out)
    read_png(plot_perturbation(records, tmp_path / "fig4b.png", events=[(4000, "left"), (6000, "right")], margin=500))
    with pytest.raises(ValueError, match="events must hold at least one"):
        plot_perturbation(records, tmp_path / "x.png", events=[])
    with pytest.raises(ValueError, match="margin"):
        plot_perturbation(records, tmp_path / "x.png", events=[(5000, "e")], margin=-1)
    with pytest.raises(ValueError, match="records has no record with iteration in"):
        plot_perturbation(records, tmp_path / "x.png", events=[(10 ** 6, "late")], margin=10)


# ---------------------------------------------------------------------------------------------
# plot_evaluation


def evaluation_result():
    per = [{"distance_m": d, "pursuit_mae_deg": 0.1 * d, "vergence_mae_deg": 0.2 / d,
            "depth_mae_m": 0.05 * d} for d in (2.0, 0.5, 1.0, 1.5)]
    per[0]["depth_mae_m"] = math.nan
    return {"pursuit_mae_deg": 0.1, "vergence_mae_deg": 0.2, "depth_mae_m": 0.05, "trials": 40,
            "per_distance": per}


def test_plot_evaluation(tmp_path):
    out = plot_evaluation(evaluation_result(), tmp_path / "eval" / "per_distance.png")
    h, w = read_png(out).shape[:2]
    assert 1000 <= w <= 1150 and 400 <= h <= 500
    bad = evaluation_result()
    del bad["trials"]
    with pytest.raises(ValueError, match="result is missing key 'trials'"):
        plot_evaluation(bad, tmp_path / "x.png")
    bad = evaluation_result()
    bad["per_distance"] = []
    with pytest.raises(ValueError, match=r"result\['per_distance'\]"):
        plot_evaluation(bad, tmp_path / "x.png")
    bad = evaluation_result()
    del bad["per_distance"][2]["distance_m"]
    with pytest.raises(ValueError, match=r"result\['per_distance'\]\[2\]"):
        plot_evaluation(bad, tmp_path / "x.png")


def test_dpi_is_about_120():
    assert 100 <= DPI <= 150


# ---------------------------------------------------------------------------------------------
# the learned code's read-outs


def _code(seed, names=("stereo/coarse", "stereo/fine"), atoms=32):
    from aectorch.coding.readouts import code_summary

    generator = torch.Generator().manual_seed(seed)
    return {name: code_summary(torch.randn(200, atoms, generator=generator)) for name in names}


def test_plot_code_writes_one_row_per_dictionary_with_the_initial_outline(tmp_path):
    one = read_png(plot_code(_code(0, names=("stereo/fine",)), tmp_path / "one.png"))
    two = read_png(plot_code(_code(1), tmp_path / "two.png", initial=_code(2)))
    assert two.shape[0] > 1.6 * one.shape[0]  # a second row


def test_plot_code_bad_input_names_the_argument(tmp_path):
    with pytest.raises(ValueError, match="code must be a non-empty mapping"):
        plot_code({}, tmp_path / "x.png")
    broken = _code(0)
    del broken["stereo/fine"]["disparity"]
    with pytest.raises(ValueError, match=r"code\['stereo/fine'\] must be a code_summary result with 'disparity'"):
        plot_code(broken, tmp_path / "x.png")
    with pytest.raises(ValueError, match="initial"):
        plot_code(_code(0), tmp_path / "x.png", initial={"stereo/fine": {}})


def test_run_code_and_the_comparison_of_groups_of_runs(tmp_path):
    from aectorch.runs import Run

    folders = []
    for seed in range(3):
        folder = tmp_path / f"run{seed}"
        folder.mkdir()
        (folder / "summary.json").write_text(json.dumps({"code": _code(seed), "code_initial": _code(10 + seed)}))
        folders.append(folder)
    code = Run(folders[0]).code
    assert set(code) == {"stereo/coarse", "stereo/fine", "initial"} and code["stereo/fine"] == _code(0)["stereo/fine"]
    groups = {"normal": [Run(f).code for f in folders[:2]], "strabismus": [Run(folders[2]).code]}
    read_png(plot_code_comparison(groups, tmp_path / "binocularity.png"))
    read_png(plot_code_comparison(groups, tmp_path / "disparity.png", readout="disparity",
                                  dictionaries=["stereo/fine"]))
    # Runs with equal histograms (shares of 0.1: their float mean lies a rounding error above them)
    same = _code(0)
    for summary in same.values():
        summary["binocularity"]["counts"] = [1, 1, 1, 1, 1, 1, 4]
    read_png(plot_code_comparison({"equal": [same, same, same]}, tmp_path / "equal.png"))
    with pytest.raises(ValueError, match="readout must be one of"):
        plot_code_comparison(groups, tmp_path / "x.png", readout="colour")
    with pytest.raises(ValueError, match=r"has no read-outs of \['stereo/full'\]"):
        plot_code_comparison(groups, tmp_path / "x.png", dictionaries=["stereo/full"])
    with pytest.raises(ValueError, match="non-empty list"):
        plot_code_comparison({"normal": []}, tmp_path / "x.png")
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"final": {}}))
    with pytest.raises(KeyError, match="no 'code' entry"):
        Run(tmp_path / "old").code
    with pytest.raises(FileNotFoundError, match="no such folder"):
        Run(tmp_path / "missing").code
