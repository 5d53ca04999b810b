"""Run the docstring examples of every module of the aectorch subpackages with the stdlib doctest."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest
import torch

import aectorch.coding
import aectorch.control
import aectorch.depth
import aectorch.ops
import aectorch.sim

torch.set_num_threads(1)

# Every module of the subpackages, nested ones included (a package's __init__ only re-exports names
# and has no examples of its own; doctest does not collect objects defined in other modules).
PACKAGES = (aectorch.ops, aectorch.coding, aectorch.sim, aectorch.control, aectorch.depth)
MODULES = sorted(
    m.name for package in PACKAGES
    for m in pkgutil.walk_packages(package.__path__, prefix=f"{package.__name__}.") if not m.ispkg
) + ["aectorch.framework.joint", "aectorch.figures", "aectorch.profiling", "aectorch.runtime.watchdog",
     "aectorch.runtime.provenance", "aectorch.runtime.config_docs", "aectorch.evaluation.trials", "aectorch.evaluation.summary", "aectorch._checks", "aectorch.runs",
     "aectorch.report.command", "aectorch.report.code"]  # top-level modules with examples


def test_module_discovery_finds_the_modules():
    expected = {
        "coding.dictionary", "coding.encoder", "coding.patches", "coding.batch_omp",
        "coding.sparse_code", "sim.camera", "sim.env", "sim.hoap3", "sim.render_pyrender",
        "sim.render_torch", "sim.scene", "sim.textures.bank", "sim.textures.procedural",
    }
    assert expected <= {name.split(".", 1)[1] for name in MODULES}


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
