"""The benchmark suite's harness and results: one schema, the current snapshot per suite and
machine, and docs/performance.md's tables generated from them (``python -m benchmarks.report``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import harness, report

ROOT = Path(__file__).resolve().parents[2]


def test_every_result_follows_the_schema_under_the_name_of_its_suite_and_machine():
    paths = sorted(harness.RESULTS.iterdir())
    assert {json.loads(p.read_text())["suite"] for p in paths} == set(harness.SUITES)
    for path in paths:
        harness.check(json.loads(path.read_text()), path.name)


@pytest.mark.parametrize(("change", "named"), [
    ({"schema": "other/1"}, "schema"), ({"suite": "stages"}, "suite"), ({"machine": {"cpu": "x"}}, "machine"),
    ({"rows": []}, "rows"), ({"rows": [{"variant": "a", "note": "no number"}]}, "holds no number")])
def test_the_schema_check_names_what_is_wrong(change, named):
    document = {"schema": harness.SCHEMA, "suite": "coding", "rows": [{"variant": "a", "x": 1.0}],
                "machine": {"cpu": "AMD EPYC", "cores": 2, "torch": "2"}}
    harness.check(document, "coding.amd-epyc-2c.json")
    with pytest.raises(ValueError, match=named):
        harness.check({**document, **change})
    with pytest.raises(ValueError, match="coding.amd-epyc-2c.json"):
        harness.check(document, "coding.json")


def test_the_performance_page_shows_the_generated_tables_and_stays_short():
    page = ROOT / "docs" / "performance.md"
    text = page.read_text()
    assert text.count("<!-- table: ") == len(report.TABLES)
    assert report.write(page) == text, "python -m benchmarks.report --write docs/performance.md"
    # 250 lines when its prose ran to 120 columns; wrapped at 100 (test_docs.py) the same text took 257
    assert len(text.splitlines()) <= 260


def test_interleaved_rounds_run_every_workload_in_turn():
    calls = []
    times = harness.interleaved({"a": lambda: calls.append("a"), "b": lambda: calls.append("b")}, rounds=2,
                                calls=2, warmup=1)
    assert calls == ["a", "b"] + ["a", "a", "b", "b"] * 2
    assert [len(t) for t in times.values()] == [4, 4]
    with pytest.raises(ValueError, match="rounds"):
        harness.interleaved({"a": lambda: None}, rounds=0)


def test_a_run_saves_its_rows_per_suite_and_machine_with_provenance(tmp_path, monkeypatch):
    monkeypatch.setattr(harness, "_rows", {})
    harness.record("coding", [{"variant": "omp", "patches_per_s": 1.0}])
    harness.record("coding", [{"variant": "mp", "patches_per_s": 2.0}])
    [path] = harness.save(tmp_path, "pytest benchmarks")
    document = json.loads(path.read_text())
    harness.check(document, path.name)
    assert [r["variant"] for r in document["rows"]] == ["omp", "mp"]
    assert document["provenance"]["git"] is None or len(document["provenance"]["git"]["commit"]) == 40
    # a later run (another ISA, say) replaces its own variants and keeps the others
    monkeypatch.setattr(harness, "_rows", {})
    harness.record("coding", [{"variant": "mp", "patches_per_s": 3.0}])
    harness.save(tmp_path, "pytest benchmarks -k mp")
    rows = json.loads(path.read_text())["rows"]
    assert [(r["variant"], r["patches_per_s"]) for r in rows] == [("omp", 1.0), ("mp", 3.0)]
