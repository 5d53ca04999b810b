"""The experiment runtime: run the paper's experiment from an `ExperimentConfig` into a run folder.

:func:`run_experiment` is what ``train.py`` calls with a validated config and a run folder. The
package holds, one idea per module:

- `config.py`: the structured configs (`ExperimentConfig`); `presets.py` the named settings;
  `store.py` Hydra's store; `resources.py` `validate_resources`;
- `builders.py`: textures, environments, learner and threads from a config;
- `checkpoint.py`: the checkpoint format and the rules of a resume (`prepare_run`);
- `loop.py`: the training loop (`TrainingRun`) and its extras as `Callback` s: the perturbation, the
  recording, the watchdog, the metrics log, the best state, checkpoints, the progress bar;
- `migrations.py`: checkpoints of earlier formats, read as today's;
- `outputs.py`: the run folder's files (`RunFolder`);
- `finish.py`: the end of a run: the code's read-outs, figures, depth calibration, evaluation,
  ``summary.json``;
- `metrics.py`, `watchdog.py`, `provenance.py`, `distributed.py`: what the loop reads and writes.

The run folder receives

- ``config.yaml``: the resolved config;
- ``provenance.json``: the aectorch, torch and Python versions, the git commit, device, CPU and
  host of the run, one entry per session (the first run and every resume);
- ``metrics.jsonl``: one JSON line every ``train.log_every`` iterations (`TrainingMetrics`);
- ``tb/``: the same scalars as TensorBoard events;
- ``checkpoint.pt``: every ``train.checkpoint_every`` iterations, at the end and when
  interrupted (atomic: a temporary file in the same folder replaces the old one);
- ``figures/``: Fig. 2 (dictionaries), Fig. 3 (training), the code's read-outs, Fig. 4
  (perturbation, when one is configured) and the evaluation figure (`aectorch.figures`);
- ``evaluation.json``: `aectorch.evaluation.evaluate` on held-out textures;
- ``summary.json``: final metrics, evaluation headline numbers, timing, perturbation recovery, and
  the read-outs of each dictionary, trained and initial (`aectorch.coding.code_summary`).

A run continues in place from its checkpoint (``train.resume=<run folder>``) and ends
bit-identical to an uninterrupted one (the learner's, the environments' and the metrics' state,
random generators included, are in the checkpoint). Messages go to the ``aectorch`` logger.
"""

from __future__ import annotations

import logging
import os
from typing import Callable

import torch

from aectorch.framework import IterationRecord
from aectorch.runtime import distributed
from aectorch.runtime.builders import (
    available_threads, build_env, build_learner, build_textures, compile_hot_path, dictionaries, set_threads,
    trial_options,
)
from aectorch.runtime.checkpoint import (
    AUTO, CHECKPOINT_FORMAT, RESUME_KEYS, RunExists, check_new_run, check_resume_overrides, checkpoint_config,
    checkpoint_envs, load_checkpoint, load_learner, prepare_run, resolve_resume, restore, resume_config,
    save_checkpoint,
)
from aectorch.runtime.config import ExperimentConfig, to_container, to_experiment_config
from aectorch.runtime.resources import validate_resources
from aectorch.runtime.finish import calibrate_depth, calibration_conditions, finish
from aectorch.runtime.loop import Callback, TrainingRun, default_callbacks
from aectorch.runtime.outputs import RunFolder, format_summary

__all__ = [
    "AUTO", "CHECKPOINT_FORMAT", "RESUME_KEYS", "Callback", "ExperimentConfig", "RunExists", "RunFolder", "TrainingRun",
    "available_threads", "build_env", "build_learner", "build_textures", "calibrate_depth", "calibration_conditions",
    "check_new_run", "check_resume_overrides", "checkpoint_config", "checkpoint_envs", "compile_hot_path",
    "default_callbacks", "dictionaries", "format_summary", "load_checkpoint", "load_learner", "prepare_run",
    "resolve_resume", "restore", "resume_config", "run_experiment",
    "save_checkpoint", "set_threads", "to_container", "to_experiment_config", "trial_options",
    "validate_resources",
]


log = logging.getLogger("aectorch")

#: ``torch.utils.deterministic.fill_uninitialized_memory`` during a run with ``train.deterministic``.
#: Deterministic mode would also fill every new tensor's memory with NaN, a guard against reading
#: memory never written: about 360 fills per default iteration, 5 % of its self CPU time in torch's
#: profiler (measured at commit c196118 by its ``benchmarks/loop_ops.py``).
#: A run never reads such memory: its checkpoint is bit-identical either way
#: (``tests/runtime/test_reliability.py::test_the_nan_fill_of_new_tensors_changes_no_bit``).
FILL_UNINITIALIZED_MEMORY = False

#: ``run_experiment``'s ``checkpoint`` when the caller did not call `prepare_run`.
_NOT_PREPARED = object()


def _agree_on_start(shard, folder: RunFolder, cfg: ExperimentConfig, checkpoint: dict | None) -> None:
    """Before anything is written: a new run's folder holds no run, unless ``train.overwrite``
    (checked again under the folder's lock: another process may have written one since
    `prepare_run`), and every process starts from the same iteration (a restarted ``torchrun``
    group whose processes found different checkpoints would otherwise train on silently)."""
    if folder.main and checkpoint is None:
        check_new_run(folder.path, cfg.train.overwrite)
        deleted = folder.clear() if cfg.train.overwrite else []
        if deleted:
            log.warning("train.overwrite: deleted %s of the run in %s", ", ".join(deleted), folder.path)
    starts = shard.gather_objects(None if checkpoint is None else int(checkpoint["iteration"]))
    if len(set(starts)) > 1:
        raise ValueError(f"the processes of this run start from different iterations ({starts}, in rank order; "
                         "None: a new run): every process must resume the same checkpoint (give train.resume=<run "
                         "folder> on all, on a file system they share)")


def run_experiment(
    cfg: ExperimentConfig,
    run_dir: str | os.PathLike,
    *,
    callback: Callable[[int, IterationRecord], None] | None = None,
    checkpoint: dict | None = _NOT_PREPARED,  # type: ignore[assignment]
    groups: dict[str, str | None] | None = None,
) -> dict:
    """Train, log, checkpoint, draw and evaluate; returns the final summary (``summary.json``).

    Args:
        cfg: the experiment. With ``cfg.train.resume`` set, the run continues in that folder
            (``run_dir`` is ignored) with its stored config (see `resume_config`);
            ``train.resume=auto`` continues ``run_dir``'s run if it holds one.
        run_dir: the run folder (created if needed). One that holds a run's ``checkpoint.pt`` is
            refused for a new run (`RunExists`, a ``ValueError``) unless ``train.overwrite``, which
            deletes that run's files (`aectorch.runtime.outputs.RUN_FILES`) first.
        callback: called as ``callback(iteration, record)`` after every learner iteration
            (1-based count of completed iterations); an exception it raises stops the run, which
            keeps the last checkpoint written (`aectorch.runtime.loop`).
        checkpoint: with ``cfg`` from `prepare_run`: the checkpoint it returned (``None`` for a
            new run); ``cfg`` is then used as it is, and nothing is read or validated again. Not
            given: `run_experiment` calls `prepare_run` itself.
        groups: the config groups' options ``cfg`` was composed with (``train.py`` gives Hydra's,
            e.g. ``{"rearing": "monocular", ...}``); ``provenance.json`` records them with the
            session, and a later resume given another option of a group is refused
            (`aectorch.runtime.checkpoint.started_groups`).
    """
    if checkpoint is _NOT_PREPARED:
        cfg, checkpoint = prepare_run(cfg, run_dir=run_dir)
    if checkpoint is not None and cfg.train.resume is None:
        raise ValueError("run_experiment got a checkpoint but cfg.train.resume is null: pass what prepare_run returned")
    previous = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled(),
                torch.utils.deterministic.fill_uninitialized_memory)  # type: ignore[attr-defined]  # not in the stubs
    if cfg.train.deterministic:
        if torch.device(cfg.env.device).type == "cuda":
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # cuBLAS's condition for it
        torch.use_deterministic_algorithms(True, warn_only=True)
        torch.utils.deterministic.fill_uninitialized_memory = FILL_UNINITIALIZED_MEMORY  # type: ignore[attr-defined]
    shard = distributed.setup(cfg.env.num_envs, cfg.env.device)
    try:
        # (cfg.train.resume is set when there is a checkpoint, checked above)
        folder = RunFolder(cfg.train.resume if checkpoint is not None else run_dir,  # type: ignore[arg-type]
                           main=shard.is_main)
        try:
            _agree_on_start(shard, folder, cfg, checkpoint)
            run = TrainingRun(cfg, folder, shard, checkpoint, default_callbacks(cfg, folder.main, callback), groups)
            try:
                run.run()
            finally:
                run.env.close()  # the renderers' OpenGL contexts, on every process and after an error
            return finish(run) if folder.main else {}
        finally:
            folder.release()
    finally:
        distributed.teardown()
        torch.use_deterministic_algorithms(previous[0], warn_only=previous[1])  # as the caller had it
        torch.utils.deterministic.fill_uninitialized_memory = previous[2]  # type: ignore[attr-defined]
