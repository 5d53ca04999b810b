"""The analysis scripts under scripts/ (the tables of runs are python -m aectorch.report's:
tests/report/test_report.py)."""

from __future__ import annotations

import json

import pytest


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


def test_soak_expands_a_config_groups_option_before_the_other_overrides(script):
    soak = script("soak")
    keys = soak.group_keys(["+experiment=lifelong", "env.num_envs=8", "preset=paper"])
    assert "learner.cues.parallax.learn_until=2400" in keys and "env.pursuit_start_error_deg=8.0" in keys
    assert keys.index("train.iterations=24000") < keys.index("train.iterations=6000")  # the groups in the order given
    assert not soak.is_group("env.num_envs=8") and soak.is_group("+experiment=lifelong")
    with pytest.raises(SystemExit, match="experiment has the options"):
        soak.group_keys(["+experiment=nonsense"])
