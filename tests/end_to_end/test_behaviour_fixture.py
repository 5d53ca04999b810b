"""No behaviour change: a fixed-seed short run matches the fixture recorded before the restructure
into layers (tests/fixtures/short_run/record.py, from commit 8680a64).

The fixture holds format 1 checkpoints (the cues written out); the test reads it through
`aectorch.runtime.migrations.migrate`, as an old checkpoint is read, so the comparison is of the
same state under today's names.

The run is float64, so its numbers agree across CPUs to far better than the tolerance; on the
machine that recorded the fixture every tensor's sha256 is equal too (reported, not asserted:
another CPU's BLAS may round the last bit differently).
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
from pathlib import Path

import pytest

from aectorch.runtime.config import to_container, to_experiment_config
from aectorch.runtime.migrations import migrate

pytestmark = pytest.mark.integration  # every test here runs training or a subprocess

HERE = Path(__file__).resolve().parents[1] / "fixtures" / "short_run"
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


def _without_last5(value):
    """The logs and results without what they have reported since the fixture was recorded: the
    means of each fixation's last 5 iterations (``last5``, ``*_last5_deg``); with perturbations
    (perturbations as data; the fixture's run rolls the eyes) the events acting (``perturbations``), the short
    window (``*_recent_*``), each event's start, end, kind and eyes, the plasticity and the
    recovery read-out (with the figures off the fixture's was empty); the texture statistics
    of each trial's first view in its row (``view_*``); the checkpoint an evaluation
    was made from (``source``: its file, iteration and hash); and the vergence test's largest end
    and fraction of ends beyond 1 deg (``max_abs_deg``, ``beyond_1deg``)."""
    if isinstance(value, dict):
        new = ("perturbations", "start", "end", "kind", "eyes", "plasticity", "recovery", "source", "max_abs_deg",
               "beyond_1deg")
        return {k: _without_last5(v) for k, v in value.items() if "last5" not in k and "_recent_" not in k
                and k not in new and not k.startswith("view_")}
    if isinstance(value, list):
        return [_without_last5(v) for v in value]
    return value


#: What ``summary.json`` has reported since the fixture was recorded, beside the results: the
#: read-outs of the learned code, computed from the final and initial dictionaries, whose
#: tensors `test_the_checkpoints_hold_the_fixtures_tensors` compares.
NEW_IN_SUMMARY = ("code", "code_initial")


@pytest.mark.parametrize("part", ["metrics", "evaluation", "summary"])
def test_the_logs_and_results_are_those_of_the_fixture(fingerprint, part):
    expected = json.loads(record.FIXTURE.read_text())
    found = _without_last5(fingerprint[part])
    if part == "summary":
        assert set(NEW_IN_SUMMARY) <= set(found), f"summary: missing {set(NEW_IN_SUMMARY) - set(found)}"
        found = {k: v for k, v in found.items() if k not in NEW_IN_SUMMARY}
        expected[part]["perturbation"].pop("recovery")
    _close(expected[part], found, part)


class _Leaf(dict):
    """A tensor's fingerprint: a leaf of the payload, not a dict to walk into."""


def _unflatten(flat: dict) -> dict:
    """The nested payload of a flat fingerprint (``/a/b[0]`` paths); tensors' prints as `_Leaf`."""
    root: dict = {}
    for path, value in flat.items():
        parts = [p for p in re.split(r"/|(\[\d+\])", path) if p]
        node = root
        for here, ahead in zip(parts, parts[1:] + [None]):
            key = int(here[1:-1]) if here.startswith("[") else here
            if ahead is None:
                leaf = _Leaf(value) if isinstance(value, dict) else value
                if isinstance(node, list):
                    node.append(leaf)
                else:
                    node[key] = leaf
                break
            child = [] if ahead.startswith("[") else {}
            if isinstance(node, list):
                if key >= len(node):
                    node.append(child)
                node = node[key]
            else:
                node = node.setdefault(key, child)
    return root


def _flatten(value, path: str = "") -> dict:
    if isinstance(value, dict) and not isinstance(value, _Leaf):
        return {k: v for key, item in value.items() for k, v in _flatten(item, f"{path}/{key}").items()}
    if isinstance(value, (list, tuple)):
        return {k: v for i, item in enumerate(value) for k, v in _flatten(item, f"{path}[{i}]").items()}
    return {path: dict(value) if isinstance(value, _Leaf) else value}


def _config(payload: dict) -> dict:
    stored = {k: v for k, v in payload["config"].items() if k not in ("watchdog", "record")}
    return to_container(to_experiment_config(stored))


@pytest.mark.parametrize("name", record.CHECKPOINTS)
def test_the_checkpoints_hold_the_fixtures_tensors(fingerprint, name):
    # The fixture's format 1 checkpoint read as today's (the migration's renames), against the new
    # run's: the same tensors under today's names, the same config once validated.
    old = _unflatten(json.loads(record.FIXTURE.read_text())["checkpoints"][name])
    # The environment's running sum of q (env.q_iterations, format 3) and its optics
    # (perturbations as data: the roll is the state's roll_deg, as before) are newer than the fixture.
    new = _unflatten({k: v for k, v in fingerprint["checkpoints"][name].items() if k != "/env/q_sum_deg"
                      and not k.startswith(("/env/optics/", "/env/first_optics"))})
    migrated = migrate(old)
    for key in ("optics", "first_optics"):  # what the migration gives a state without them: None
        assert migrated["env"].pop(key) is None
    assert _config(migrated) == _config(new)
    expected = {k: v for k, v in _flatten({**migrated, "config": None}).items()}
    got = {k: v for k, v in _flatten({**new, "config": None}).items()}
    _close(_numbers(expected), _numbers(got), name)
    same = sum(expected[k]["sha256"] == got[k]["sha256"] for k in expected if isinstance(expected[k], dict))
    print(f"{name}: {same} of {sum(isinstance(v, dict) for v in expected.values())} tensors bit-identical")
