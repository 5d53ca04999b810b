"""Whole runs checked end to end: a default run against the recorded fixture, a study's commands,
and damaged run files read by the commands."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


def study_module(study: str, name: str) -> ModuleType:
    """``experiments/<study>/<name>.py`` imported as a module (``<study>_<name>``, once per
    process), the way its scripts import each other: with its folder on the path."""
    key = f"{study}_{name}"
    if key not in sys.modules:
        folder = EXPERIMENTS / study
        if str(folder) not in sys.path:
            sys.path.append(str(folder))
        spec = importlib.util.spec_from_file_location(key, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module  # (dataclasses and doctest look the module up by name)
        spec.loader.exec_module(module)
    return sys.modules[key]
