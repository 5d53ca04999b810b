"""No behaviour change: a fixed-seed short run matches the fixture recorded before issue 22's
restructure (tests/fixtures/short_run/record.py, from commit 8680a64).

The run is float64, so its numbers agree across CPUs to far better than the tolerance; on the
machine that recorded the fixture every tensor's sha256 is equal too (reported, not asserted:
another CPU's BLAS may round the last bit differently).
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent / "fixtures" / "short_run"
_spec = importlib.util.spec_from_file_location("short_run_record", HERE / "record.py")
record = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(record)

RTOL, ATOL = 1e-9, 1e-12


def _close(a, b, where: str) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), f"{where}: keys differ: {sorted(set(a) ^ set(b))}"
        for key in a:
            _close(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), f"{where}: lengths differ ({len(a)} vs {len(b)})"
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, (int, float)) and not isinstance(b, bool):
        if math.isnan(a):
            assert math.isnan(b), f"{where}: {b} is not NaN"
        else:
            assert b == pytest.approx(a, rel=RTOL, abs=ATOL), f"{where}: {b!r} != {a!r}"
    else:
        assert a == b, f"{where}: {b!r} != {a!r}"


@pytest.fixture(scope="module")
def fingerprint(tmp_path_factory):
    folder = tmp_path_factory.mktemp("short_run") / "run"
    done = record.run(folder)
    assert done.returncode == 0, done.stderr[-3000:]
    return record.fingerprint(folder)


def _numbers(tensors: dict) -> dict:
    return {k: {f: v for f, v in t.items() if f != "sha256"} if isinstance(t, dict) and "sha256" in t else t
            for k, t in tensors.items()}


@pytest.mark.parametrize("part", ["metrics", "evaluation", "summary"])
def test_the_logs_and_results_are_those_of_the_fixture(fingerprint, part):
    expected = json.loads(record.FIXTURE.read_text())
    _close(expected[part], fingerprint[part], part)


@pytest.mark.parametrize("name", record.CHECKPOINTS)
def test_the_checkpoints_hold_the_fixtures_tensors(fingerprint, name):
    expected = json.loads(record.FIXTURE.read_text())["checkpoints"][name]
    got = fingerprint["checkpoints"][name]
    _close(_numbers(expected), _numbers(got), name)
    same = sum(expected[k]["sha256"] == got[k]["sha256"] for k in expected if isinstance(expected[k], dict))
    print(f"{name}: {same} of {sum(isinstance(v, dict) for v in expected.values())} tensors bit-identical")
