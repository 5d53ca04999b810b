"""Run the docstring examples of every module of aectorch.coding with the stdlib doctest."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest
import torch

import aectorch.coding

torch.set_num_threads(1)

# Every submodule of the package (the package's own __init__ only re-exports names and has no
# examples of its own; doctest does not collect objects defined in other modules).
MODULES = sorted(
    f"aectorch.coding.{m.name}" for m in pkgutil.iter_modules(aectorch.coding.__path__)
)


def test_module_discovery_finds_the_coding_modules():
    expected = {"dictionary", "encoder", "patches", "pursuit", "sparse_code"}
    assert expected <= {name.rsplit(".", 1)[1] for name in MODULES}


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(name)
    torch.manual_seed(0)  # the examples draw random tensors; make a failure reproducible
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(verbose=False)
    report: list[str] = []
    for test in finder.find(module, name, globs=vars(module).copy()):
        runner.run(test, out=report.append)
    failed, attempted = runner.summarize(verbose=False)
    assert attempted > 0, f"{name} has no doctest examples"
    assert failed == 0, "".join(report)
