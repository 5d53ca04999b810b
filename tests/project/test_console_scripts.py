"""The console scripts of pyproject.toml's ``[project.scripts]`` (``aectorch/cli/``): each resolves to a
callable whose help runs (in this process: no subprocess, so the test is fast), the documentation names
each, and ``aectorch/cli/`` holds one module per script."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _scripts() -> dict[str, str]:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        tomllib = pytest.importorskip("tomli")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


SCRIPTS = _scripts()


def test_the_scripts_are_the_commands():
    assert set(SCRIPTS) == {"aectorch-train", "aectorch-evaluate", "aectorch-report", "aectorch-record",
                            "aectorch-view"}
    modules = {target.partition(":")[0] for target in SCRIPTS.values()}
    files = {f"aectorch.cli.{path.stem}" for path in (ROOT / "aectorch" / "cli").glob("*.py")
             if path.stem != "__init__"}
    assert modules == files, "one module of aectorch/cli/ per script"


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_a_script_resolves_to_a_callable_whose_help_runs(name, capsys):
    from hydra.core.global_hydra import GlobalHydra

    module, _, attribute = SCRIPTS[name].partition(":")
    main = getattr(importlib.import_module(module), attribute)
    assert callable(main)
    try:
        status = main(["--help"])
    finally:
        GlobalHydra.instance().clear()  # Hydra's help leaves its global state set
    out = capsys.readouterr().out
    assert status == 0
    if name == "aectorch-train":
        assert "== Configuration groups ==" in out and "num_envs: 32" in out, out[:2000]
    else:
        assert out.startswith("usage:"), out[:2000]


def test_the_documentation_names_every_script():
    text = (ROOT / "README.md").read_text() + (ROOT / "docs" / "training.md").read_text()
    assert [name for name in SCRIPTS if f"`{name}`" not in text] == []


def test_train_py_runs_the_scripts_code():
    shim = (ROOT / "train.py").read_text()
    assert "from aectorch.cli.train import main" in shim and len(shim.splitlines()) < 15
