"""Whole runs checked end to end: a default run against the recorded fixture, a study's commands,
and damaged run files read by the commands."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


def study_module(study: str, name: str) -> ModuleType:
    """``experiments/<study>/<name>.py`` imported as a module (``<study>_<name>``, once per
    process), the way its scripts import each other: with its folder first on the path, and a
    sibling another study's module imported under the same bare name (``report``) forgotten, so
    that ``from report import ...`` reads this study's."""
    key = f"{study}_{name}"
    if key not in sys.modules:
        folder = EXPERIMENTS / study
        for path in folder.glob("*.py"):
            sibling = sys.modules.get(path.stem)
            if sibling is not None and Path(getattr(sibling, "__file__", None) or "").parent != folder:
                del sys.modules[path.stem]
        if str(folder) in sys.path:
            sys.path.remove(str(folder))
        sys.path.insert(0, str(folder))
        spec = importlib.util.spec_from_file_location(key, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module  # (dataclasses and doctest look the module up by name)
        spec.loader.exec_module(module)
    return sys.modules[key]


ROOT = EXPERIMENTS.parent
#: The tiny run the studies' scripts are tested with (a few seconds of training).
TINY = ["env.num_envs=4", "env.fixation_iterations=2", "env.distances_m=[1.0,2.0]",
        "learner.cues.parallax.encoder.num_atoms=16", "learner.cues.stereo.encoder.num_atoms=16",
        "learner.depth_every_trials=10", "train.tensorboard=false"]


def run_script(*args: str):
    """``python <args>`` from the repository's root, its output captured."""
    import subprocess

    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def noise_images(folder: Path, count: int, size: int, seed: int, prefix: str = "t") -> Path:
    """``folder`` (made) with ``count`` PNGs of uniform grey noise, ``size`` px square."""
    import numpy as np
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(count):
        Image.fromarray((rng.random((size, size)) * 255).astype(np.uint8)).save(folder / f"{prefix}{i}.png")
    return folder
