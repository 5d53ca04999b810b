"""What ``train.py``'s Hydra app checks before Hydra writes anything into a run folder.

Hydra writes ``.hydra/`` and ``train.log`` into the run folder before the job's function runs, so
the refusal to start a new run over a finished one (`aectorch.runtime.checkpoint.check_new_run`)
is made here, in a Hydra callback (``hydra.callbacks.run_folder_guard``, registered by
`aectorch.runtime.store.register_configs`), at the start of a run or sweep: a refused rerun
leaves the folder byte-identical.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from aectorch.runtime.checkpoint import AUTO, RunExists, check_new_run, check_started_groups, started_groups
from aectorch.runtime.outputs import RunFolder, RunFolderBusy
from aectorch.runtime.presets import GROUPS

__all__ = ["RunFolderGuard"]


def _refuse(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def _fresh(config: DictConfig) -> bool:
    """Whether the job starts new runs that must not replace an existing one."""
    train = config.get("train") or {}
    return train.get("resume") is None and not train.get("overwrite", False)


class RunFolderGuard(Callback):
    """Stop ``train.py`` with status 2 and one line, before any write, when its run folder is in use
    by another training process, or when a new run (no ``train.resume``, no ``train.overwrite``)
    would go into a folder that holds a run's ``checkpoint.pt``; a sweep is refused when its folder
    holds any."""

    def on_run_start(self, config: DictConfig, **kwargs) -> None:
        if int(os.environ.get("RANK", "0")) > 0:  # other ranks write a temporary folder
            return
        run_dir = Path(config.hydra.run.dir)
        try:
            RunFolder.check_free(run_dir)  # a run training there now: say so, write nothing
            _check_writable(run_dir, "hydra.run.dir")
            resume = (config.get("train") or {}).get("resume")
            if resume not in (None, AUTO) and Path(resume).resolve() != run_dir.resolve():
                _check_writable(Path(resume), "train.resume")
            if _fresh(config):
                check_new_run(run_dir)
            resumed = _resumed_folder(config, run_dir)
            if resumed is not None:  # a group the run was not started with: refused before Hydra writes
                check_started_groups(_given_groups(config), started_groups(resumed), resumed)
        except (RunExists, RunFolderBusy, ValueError) as err:
            _refuse(str(err))
        _keep_the_start_record(config, run_dir)

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        try:
            _check_writable(Path(config.hydra.sweep.dir), "hydra.sweep.dir")
        except ValueError as err:
            _refuse(str(err))
        if not _fresh(config):
            return
        sweep = Path(config.hydra.sweep.dir)
        held = sorted(sweep.glob("**/checkpoint.pt")) if sweep.is_dir() else []
        if held:
            try:
                check_new_run(held[0].parent, elsewhere="hydra.sweep.dir=...")
            except RunExists as err:
                _refuse(f"the sweep folder {str(sweep)!r} holds {len(held)} run(s) of an earlier sweep, e.g. {err}; "
                        f"re-launch the sweep with train.resume={AUTO} to continue each job in its folder")


#: Where Hydra writes its record of a resume (config, overrides) inside the run folder: ``.hydra/``
#: keeps what the run was started with (`aectorch.runtime.checkpoint.started_groups` reads it).
RESUME_RECORD = ".hydra/resumed"


def _resumed_folder(config: DictConfig, run_dir: Path) -> Path | None:
    """The run folder a ``train.resume`` continues (``None``: a new run)."""
    resume = (config.get("train") or {}).get("resume")
    if resume == AUTO:
        return run_dir if (run_dir / "checkpoint.pt").is_file() else None
    return None if resume is None else Path(resume)


def _given_groups(config: DictConfig) -> dict[str, str | None]:
    """The config groups the command line names, with the option each has in this run."""
    choices = config.hydra.runtime.choices
    keys = {str(item).split("=", 1)[0].lstrip("+~") for item in config.hydra.overrides.task}
    return {key: choices.get(key) for key in keys if key in GROUPS}


def _keep_the_start_record(config: DictConfig, run_dir: Path) -> None:
    """A resume into the folder of a run started by ``train.py`` writes Hydra's record into
    :data:`RESUME_RECORD`, not over the start's ``.hydra/``."""
    from omegaconf import open_dict, read_write

    resumed = _resumed_folder(config, run_dir)
    resumes_here = resumed is not None and resumed.resolve() == run_dir.resolve()
    if resumes_here and config.hydra.output_subdir == ".hydra" and (run_dir / ".hydra" / "overrides.yaml").is_file():
        with read_write(config.hydra), open_dict(config.hydra):
            config.hydra.output_subdir = RESUME_RECORD


def _check_writable(folder: Path, key: str) -> None:
    """``ValueError`` naming ``key`` when ``folder`` (or, if it does not exist yet, the nearest
    folder above it, where it would be made) cannot be written: checked before Hydra writes."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{key}: {str(existing)!r} is not a folder, so {str(folder)!r} cannot be made there")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{key}: cannot write into {str(existing)!r} (permission denied or read-only); give a "
                         f"folder this user can write")
