"""The analysis scripts under scripts/ that docs/results.md's tables come from."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(folder: Path, lines: list[dict], events=None) -> Path:
    folder.mkdir()
    (folder / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    if events is not None:
        (folder / "summary.json").write_text(json.dumps({"perturbation": {"events": events}}))
    return folder


def test_compare_runs_prints_the_runs_side_by_side(tmp_path, capsys):
    compare = _script("compare_runs")
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
def test_compare_runs_rejects_bad_arguments(tmp_path, capsys, args, message):
    compare = _script("compare_runs")
    a = _run(tmp_path / "a", [{"iteration": 1}])
    b = _run(tmp_path / "b", [{"iteration": 1}])
    assert compare.main([str(a), str(b), *args]) == 2
    assert message in capsys.readouterr().err


def test_compare_runs_names_a_folder_without_metrics(tmp_path, capsys):
    compare = _script("compare_runs")
    assert compare.main([str(tmp_path)]) == 2
    assert "has no metrics.jsonl" in capsys.readouterr().err
