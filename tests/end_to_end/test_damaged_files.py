"""Damaged run files: every corruption is named, never a traceback, never a wrong table.

Random corruptions (truncation, bit flips, values of another type, missing entries) of a tiny
run's ``checkpoint.pt``, ``metrics.jsonl``, ``summary.json``, ``evaluation.json`` and an
evaluation of ``python -m aectorch.evaluate`` (``tracking.json``), read by ``python -m
aectorch.report`` (``tracking.json`` by experiments/moving_objects/report.py) and by the
checkpoint reader of ``python -m aectorch.evaluate``. Each gives status 2 and one ``error:`` line
naming the file, or the table of the undamaged files (a flip that leaves the file's bytes meaning
the same, a cut after the last line), or that table with cells of the missing values shown as
missing. A bit flip that turns a number of a JSON file into
another valid number is not a corruption any reader can see (no checksum): those flips are left
out; a checkpoint's entries carry CRC-32s, so every flip in one is seen.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from aectorch.evaluate import main as evaluate
from aectorch.report.__main__ import main as report
from aectorch.runtime import load_checkpoint, load_learner, run_experiment
from tests.end_to_end import study_module
from tests.runtime.test_train import _cfg, textures  # noqa: F401  (the fixture)

pytestmark = pytest.mark.integration  # every test here runs training or a subprocess

EXAMPLES = settings(max_examples=20, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

#: The report command that reads each file (``None``: the moving-object study's report).
COMMANDS = {"summary.json": ["table"], "evaluation.json": ["table"], "metrics.jsonl": ["curves", "--every", "2"],
            "tracking.json": [None]}

#: How a missing value shows in the tables.
MISSING = {"n/a", "nan", "None", "-", ""}


@pytest.fixture(scope="module")
def run(tmp_path_factory, textures) -> Path:
    folder = tmp_path_factory.mktemp("damaged") / "run"
    run_experiment(_cfg(textures, "train.iterations=4", "eval.enabled=true"), folder)
    assert evaluate([f"checkpoint={folder / 'checkpoint.pt'}", f"textures={textures}", f"out={folder / 'tracking.json'}",
                     "depths=[1.0]", "tracking=[0]", "skip=1", "progress=false"]) == 0
    return folder


def _report(name: str, folder: Path, capsys) -> tuple[int, list[str], list[str]]:
    capsys.readouterr()
    args = COMMANDS[name]
    if args[0] is None:
        code = study_module("moving_objects", "report").main([str(folder), *args[1:]])
    else:
        code = report([args[0], str(folder), *args[1:]])
    out, err = capsys.readouterr()
    return code, out.splitlines(), [line for line in err.splitlines() if line.strip()]


def _paths(node, path=()):
    """Every entry of a JSON document, as key paths."""
    if isinstance(node, dict):
        items = node.items()
    elif isinstance(node, list):
        items = enumerate(node)
    else:
        return
    for key, value in items:
        yield path + (key,)
        yield from _paths(value, path + (key,))


def _at(node, path):
    for key in path[:-1]:
        node = node[key]
    return node


def _another_type(value):
    """A value of a JSON type that never stands for ``value``'s (null is NaN's spelling: left out)."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, (dict, list)):
        return "x"
    return "x" if not isinstance(value, bool) else [value]


def _shape(node):
    if isinstance(node, dict):
        return {k: _shape(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_shape(v) for v in node]
    return "number" if isinstance(node, (int, float)) and not isinstance(node, bool) else type(node).__name__


def _documents(text: str, lines: bool):
    return [json.loads(line) for line in text.splitlines() if line.strip()] if lines else json.loads(text)


def _corrupt(data, original: bytes, lines: bool) -> tuple[bytes, str]:
    """A corruption drawn by hypothesis: (the new bytes, its kind)."""
    kind = data.draw(st.sampled_from(["truncate", "flip", "wrong type", "missing entry"]))
    if kind == "truncate":
        return original[: data.draw(st.integers(0, len(original) - 1))], kind
    if kind == "flip":
        at = data.draw(st.integers(0, len(original) - 1))
        return original[:at] + bytes([original[at] ^ (1 << data.draw(st.integers(0, 7)))]) + original[at + 1:], kind
    document = _documents(original.decode(), lines)
    # (in metrics.jsonl, an entry of a line: a whole line missing is a log with a gap, which the
    # tables show as one: no row for its iteration)
    paths = [p for p in _paths(document) if not lines or len(p) > 1]
    path = paths[data.draw(st.integers(0, len(paths) - 1))]
    node = _at(document, path)
    if kind == "wrong type":
        node[path[-1]] = _another_type(node[path[-1]])
    else:
        del node[path[-1]]
    text = "".join(json.dumps(d) + "\n" for d in document) if lines else json.dumps(document)
    return text.encode(), kind


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.split("|")]


def _only_missing_cells(found: list[str], expected: list[str]) -> bool:
    """The same table but for cells that now show a value as missing."""
    if len(found) != len(expected):
        return False
    for a, b in zip(found, expected):
        if a != b and not (len(_cells(a)) == len(_cells(b))
                           and all(x == y or x in MISSING for x, y in zip(_cells(a), _cells(b)))):
            return False
    return True


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_damaged_run_file_is_named_or_changes_nothing_the_table_shows(run, tmp_path, capsys, name):
    folder = tmp_path / "run"
    shutil.copytree(run, folder)
    original = (folder / name).read_bytes()
    code, expected, _ = _report(name, folder, capsys)
    assert code == 0 and expected
    lines = name.endswith(".jsonl")

    @EXAMPLES
    @given(st.data())
    def check(data):
        damaged, kind = _corrupt(data, original, lines)
        try:
            document = _documents(damaged.decode(), lines)
        except (UnicodeDecodeError, json.JSONDecodeError):
            document = None
        if kind == "flip" and document is not None and _shape(document) == _shape(_documents(original.decode(), lines)):
            return  # another valid number in the same place: no reader can tell (see the module's docstring)
        (folder / name).write_bytes(damaged)
        try:
            code, out, err = _report(name, folder, capsys)
        finally:
            (folder / name).write_bytes(original)
        if code == 2:
            assert len(err) == 1 and err[0].startswith("error: ") and str(folder / name) in err[0], (kind, err)
            assert "Traceback" not in err[0] and not out
            return
        assert code == 0, (kind, code, err)
        if lines and kind == "truncate":  # a torn last line is dropped, as a kill -9 leaves it
            whole = damaged[: damaged.rfind(b"\n") + 1]
            (folder / name).write_bytes(whole)
            try:
                expected_here = _report(name, folder, capsys)[1]  # (no whole line: the table's header alone)
            finally:
                (folder / name).write_bytes(original)
            assert out == expected_here, (kind, out)
            return
        assert out == expected or kind == "missing entry" and _only_missing_cells(out, expected), (kind, out)

    check()


def _same(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b or a != a and b != b  # (NaN)


def test_a_damaged_checkpoint_is_named_or_reads_as_the_same_payload(run, tmp_path):
    original = (run / "checkpoint.pt").read_bytes()
    payload = load_checkpoint(run / "checkpoint.pt")
    path = tmp_path / "checkpoint.pt"

    @EXAMPLES
    @given(st.data())
    def check(data):
        kind = data.draw(st.sampled_from(["truncate", "flip"]))
        if kind == "truncate":
            damaged = original[: data.draw(st.integers(0, len(original) - 1))]
        else:
            at = data.draw(st.integers(0, len(original) - 1))
            damaged = original[:at] + bytes([original[at] ^ (1 << data.draw(st.integers(0, 7)))]) + original[at + 1:]
        path.write_bytes(damaged)
        try:
            found = load_checkpoint(path)
        except ValueError as err:
            assert str(path) in str(err) and "\n" not in str(err).strip(), str(err)
            return
        assert _same(found, payload), kind  # a flip in bytes nothing reads (a zip header's padding)

    check()


@pytest.mark.parametrize("entry", [("learner",), ("iteration",), ("config",), ("config", "learner"),
                                   ("learner", "cues.stereo.encoder.dictionary.scale_dicts.fine")])
@pytest.mark.parametrize("change", ["missing", "wrong type"])
def test_a_checkpoint_with_an_entry_missing_or_of_another_type_is_named(run, tmp_path, capsys, entry, change):
    payload = copy.deepcopy(torch.load(run / "checkpoint.pt", weights_only=True))
    node = payload
    for key in entry[:-1]:
        node = node[key]
    key = entry[-1]
    if key not in node:  # a state dict's key: the first that holds the entry's name
        key = next(k for k in node if entry[-1].split(".")[-1] in k)
    if change == "missing":
        del node[key]
    else:
        node[key] = "x"
    path = tmp_path / "checkpoint.pt"
    torch.save(payload, path)
    with pytest.raises(ValueError, match=str(path).replace(".", r"\.")):
        load_learner(path)
    capsys.readouterr()
    assert evaluate([f"checkpoint={path}", f"out={tmp_path / 'e.json'}", "progress=false"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and str(path) in err[0], err


@pytest.mark.parametrize("change", ["missing", "wrong type"])
def test_a_resume_from_a_checkpoint_without_its_environments_names_it(run, tmp_path, change):
    """The environments' state is a resume's alone (an evaluation does not read it)."""
    from aectorch.runtime import prepare_run

    folder = tmp_path / "run"
    folder.mkdir()
    payload = torch.load(run / "checkpoint.pt", weights_only=True)
    if change == "missing":
        del payload["env"]
    else:
        payload["env"] = "x"
    torch.save(payload, folder / "checkpoint.pt")
    cfg = copy.deepcopy(load_learner(run / "checkpoint.pt")[0])
    cfg.train.resume = str(folder)
    with pytest.raises(ValueError, match=r"checkpoint\.pt' is not an aectorch checkpoint this version reads: its 'env'"):
        prepare_run(cfg, {"train.resume"})
