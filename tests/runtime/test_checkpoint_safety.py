"""Loading a checkpoint never runs code (docs/security.md).

A malicious checkpoint (a pickle that calls ``os.system`` when it is unpickled, as anyone handing
a user a file could write) is refused by every entry point with one ``error:`` line, status 2 and
no traceback, and the command it carries never runs. Real checkpoints of every format still
load (tests/runtime/test_migrations.py loads the stored ones; every test that resumes a run reads its
checkpoint through the same restricted loader).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from aectorch.runtime.checkpoint import load_checkpoint, load_learner

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = sorted((ROOT / "tests" / "fixtures" / "checkpoints").glob("*.pt"))


class _Payload:
    """Unpickled, this would run ``touch <marker>``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture
def malicious(tmp_path):
    """A run folder whose checkpoint.pt creates ``PWNED`` when unpickled with the full unpickler."""
    run = tmp_path / "run"
    run.mkdir()
    marker = tmp_path / "PWNED"
    torch.save({"format": 2, "config": {}, "iteration": 1, "learner": _Payload(marker)}, run / "checkpoint.pt")
    # the file is what it claims: the full unpickler runs the command
    torch.load(run / "checkpoint.pt", weights_only=False)
    assert marker.exists()
    marker.unlink()
    return run, marker


def test_the_library_refuses_a_malicious_checkpoint(malicious):
    run, marker = malicious
    for load in (load_checkpoint, load_learner):
        with pytest.raises(ValueError, match=r"refusing to load .*checkpoint.pt.*objects that are not data "
                                             r"\(GLOBAL posix.system\)"):
            load(run / "checkpoint.pt")
    assert not marker.exists()


@pytest.mark.integration
@pytest.mark.parametrize("command", ["evaluate", "visualize", "record", "resume"])
def test_every_entry_point_refuses_a_malicious_checkpoint_in_one_line(malicious, command, tmp_path):
    run, marker = malicious
    path = run / "checkpoint.pt"
    argv = {
        "evaluate": ["-m", "aectorch.evaluate", f"checkpoint={path}", f"out={tmp_path / 'e.json'}"],
        "visualize": ["-m", "aectorch.visualize", f"checkpoint={path}", f"out={tmp_path / 't.gif'}"],
        "record": ["-m", "aectorch.record", f"checkpoint={path}", f"out={tmp_path / 'dataset'}"],
        "resume": [str(ROOT / "train.py"), f"train.resume={run}"],
    }[command]
    env = {**os.environ, "PYOPENGL_PLATFORM": "osmesa"}
    env.pop("AECTORCH_DEBUG", None)
    done = subprocess.run([sys.executable, *argv], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "refusing to load" in lines[0], done.stderr
    assert str(path) in lines[0] and "Traceback" not in done.stderr
    assert not marker.exists()


def test_every_stored_checkpoint_is_data_only():
    assert len(FIXTURES) >= 10
    for path in FIXTURES:
        torch.load(path, map_location="cpu", weights_only=True)  # raises on any object that is not data
        assert load_checkpoint(path)["format"] >= 2  # and reads as today's


def test_a_file_that_is_no_checkpoint_is_named(tmp_path):
    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint")
    with pytest.raises(ValueError, match=r"cannot read the checkpoint .*notes.pt"):
        load_checkpoint(text)
    data = tmp_path / "dict.pt"
    torch.save({"weights": torch.zeros(2)}, data)
    with pytest.raises(ValueError, match=r"dict.pt' is not an aectorch checkpoint"):
        load_checkpoint(data)
