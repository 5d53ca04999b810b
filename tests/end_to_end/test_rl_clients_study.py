"""The RL clients study's report (experiments/rl_clients/report.py) on constructed result files,
and the README's commands at a tiny size: a client's run (the CleanRL-style example, 480 steps) and
the table of its result file. tests/envs/test_envs.py runs every client at that size."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.end_to_end import EXPERIMENTS, run_script, study_module

main = study_module("rl_clients", "report").main


def _finished(folder: Path, mae: float, train_s: float = 60.0) -> Path:
    """A run folder of the project's own learner: its summary and both final evaluations."""
    folder.mkdir()
    (folder / "summary.json").write_text(json.dumps({"train_seconds": train_s}))
    result = {"vergence_mae_deg": mae / 2, "fractions": {"vergence": {"within": 0.75, "beyond": 0.0}}}
    for name in ("final_textures.json", "final_choose.json"):
        (folder / name).write_text(json.dumps(result))
    return folder


def test_the_clients_are_put_beside_the_learner(tmp_path, capsys):
    folder = tmp_path / "rl"
    folder.mkdir()
    for seed, mae in ((0, 0.5), (1, 0.7)):
        (folder / f"sb3_error_s{seed}.json").write_text(json.dumps({"train_s": 100.0, "eval": {"photos": {
            "trained": {"vergence_mae_deg": mae, "within_0.22_deg": 0.5}, "random": {"vergence_mae_deg": 3.0}}}}))
    (folder / "notes.json").write_text("{}")  # not a client's file: skipped
    own = _finished(tmp_path / "own", mae=1.0)
    assert main([str(folder), "--own", str(own), "--default-set", "photos"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2] == "| SB3 PPO | error | photos | 2 | 0.600 (0.141) [0.50 / 0.70] | 50.0% | 3.00 | 100 |"
    assert lines[3] == "| aectorch NAC (vergence only) | coding (improvement) | photos | 1 | 0.500 [0.50] | 75.0% | - | 60 |"
    assert main([str(tmp_path / "missing")]) == 2
    assert "no such folder" in capsys.readouterr().err


def _result(mae, random_mae, **pursuit):
    row = lambda v, p: {"vergence_mae_deg": v, "within_0.22_deg": 0.5, "fixations": 8,  # noqa: E731
                        **({"pursuit_mae_deg": p} if p is not None else {})}
    return {"train_s": 10.0, "eval": {"test textures": {"trained": row(mae, pursuit.get("trained")),
                                                        "random": row(random_mae, pursuit.get("random"))}}}


def test_the_clients_and_active_depth_are_tabulated(tmp_path, capsys):
    for name, value in (("cleanrl_scaled_s0", 0.2), ("cleanrl_scaled_s1", 0.4), ("sb3_coding_s0", 1.0)):
        (tmp_path / f"{name}.json").write_text(json.dumps(_result(value, 2.5)))
    (tmp_path / "sb3-activedepth_scaled_s0.json").write_text(json.dumps(_result(0.5, 2.0, trained=1.0, random=3.0)))
    (tmp_path / "other_s0.json").write_text("{}")  # not a client's file: left alone
    assert main([str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "| CleanRL-style PPO | scaled | test textures | 2 | 0.300 (0.141) [0.20 / 0.40] | 50.0% | 2.50 | 10 |" in out
    assert "| SB3 PPO | coding | test textures | 1 | 1.000 [1.00] | 50.0% | 2.50 | 10 |" in out
    assert "| SB3 PPO, MultiDiscrete | scaled | test textures | 1 | 1.000 [1.00] | 3.000 | 0.500 [0.50] | 2.000 | 10 |" in out


@pytest.mark.integration
def test_a_tiny_client_run_is_tabulated_as_the_readme_runs_it(tmp_path):
    out = tmp_path / "rl" / "cleanrl_scaled_s0.json"
    out.parent.mkdir()
    done = run_script("examples/cleanrl_ppo_vergence.py", "--steps", "480", "--num-envs", "4", "--eval-episodes", "1",
                      "--out", str(out))
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    done = run_script(str(EXPERIMENTS / "rl_clients" / "report.py"), str(out.parent))
    assert done.returncode == 0, done.stdout + done.stderr
    rows = done.stdout.splitlines()
    assert len(rows) == 3 and rows[2].startswith("| CleanRL-style PPO | scaled | test textures | 1 | ")
