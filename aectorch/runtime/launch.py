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

from aectorch.runtime.checkpoint import AUTO, RunExists, check_new_run
from aectorch.runtime.outputs import RunFolder, RunFolderBusy

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
        try:
            RunFolder.check_free(config.hydra.run.dir)  # a run training there now: say so, write nothing
            if _fresh(config):
                check_new_run(config.hydra.run.dir)
        except (RunExists, RunFolderBusy) as err:
            _refuse(str(err))

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        if not _fresh(config):
            return
        sweep = Path(config.hydra.sweep.dir)
        held = sorted(sweep.glob("**/checkpoint.pt")) if sweep.is_dir() else []
        if held:
            try:
                check_new_run(held[0].parent)
            except RunExists as err:
                _refuse(f"the sweep folder {str(sweep)!r} holds {len(held)} run(s) of an earlier sweep, e.g. {err}; "
                        f"re-launch the sweep with train.resume={AUTO} to continue each job in its folder")
