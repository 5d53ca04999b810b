"""experiments/roll_adaptation/report.py: the recovery read-out of perturbed runs, on constructed run folders."""

from __future__ import annotations

import json

from tests.end_to_end import study_module

report = study_module("roll_adaptation", "report")
main = report.main


def test_adaptation_tabulates_the_recovery_of_each_error(tmp_path, capsys):
    run = tmp_path / "rolled"
    run.mkdir()
    (run / "config.yaml").write_text("train:\n  recent_window: 128\n")
    values = [0.1, 0.1, 0.5, 0.3, 0.11, 0.1, 0.4, 0.4]
    within = [1.0, 0.96, 0.2, 0.6, 0.97, 0.99, 0.5, 0.5]
    lines = [{"iteration": 10 * i, "vergence_recent_deg": v, "vergence_recent_1px": w, "pursuit_recent_deg": 0.1,
              "pursuit_recent_1px": 1.0, "depth_recent_m": 0.05} for i, (v, w) in enumerate(zip(values, within))]
    (run / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    assert main([str(run), "--change", "10"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 5 and out[2].startswith("| rolled | vergence | 0.100 | 0.500 (5.0x, 20) | 30 | 0.400 |")
    assert main([str(tmp_path / "missing"), "--change", "10"]) == 2
    assert "no such folder" in capsys.readouterr().err
