"""aectorch training entry point (Hydra): the paper's experiment, `aectorch.runtime.run_experiment`.
``train.py`` at the repository's root and the console script ``aectorch-train`` run it (``aectorch-train``
takes the same arguments as ``python train.py``).

B simulated HOAP-3 heads learn, jointly, sparse codes of what their eyes see, pursuit and
vergence eye movements (PPO by default; the paper's natural actor-critic with ``preset=paper``)
and the object's distance (an MLP); the run folder
(Hydra's, ``outputs/<date>/<time>`` by default) receives config.yaml, metrics.jsonl, tb/,
checkpoint.pt, figures/, evaluation.json and summary.json. See docs/training.md.

    python train.py                                   # defaults (aectorch.runtime.config.ExperimentConfig)
    python train.py env.num_envs=64 train.iterations=500 seed=3 hydra.run.dir=/tmp/x
    python train.py preset=paper +experiment=roll_perturbation
    python train.py train.resume=/tmp/x train.iterations=1000   # continue a run in place
    python train.py train.resume=auto hydra.run.dir=/tmp/x     # resume /tmp/x if it holds a run, else start
                                                      # (auto needs hydra.run.dir, or hydra.sweep.dir with -m)
    python train.py -m seed=0,1,2                     # multirun sweep
    torchrun --standalone --nproc_per_node=2 train.py env.num_envs=16   # 2 processes x 16 envs

A new run into a folder that holds a run's checkpoint.pt stops before writing anything, with status 2
and one line (`aectorch.runtime.launch`): give ``train.resume``, another folder, or ``train.overwrite=true``.
Invalid values and bad files exit with status 2 and one ``error: ...`` line, a run stopped by
the watchdog (`aectorch.runtime.watchdog`) with status 3, and one interrupted by Ctrl-C or SIGTERM, after
writing its checkpoint and printing how to resume, with status 130; set ``AECTORCH_DEBUG=1`` for
the full traceback.
"""

from __future__ import annotations

import logging
import os
import re
import sys
from pathlib import Path
from typing import NoReturn, Sequence

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from tqdm.contrib.logging import logging_redirect_tqdm

from aectorch.runtime import format_summary, prepare_run, run_experiment
from aectorch.runtime.config import to_experiment_config
from aectorch.runtime.store import register_configs
from aectorch.runtime.checkpoint import load_checkpoint
from aectorch.runtime.outputs import WriteFailed
from aectorch.runtime.watchdog import WatchdogError

register_configs()


def _debug() -> bool:
    return os.environ.get("AECTORCH_DEBUG", "") not in ("", "0")


def _fail(message: str) -> NoReturn:
    print(f"error: {message} (AECTORCH_DEBUG=1 for the traceback)", file=sys.stderr)
    sys.exit(2)


def _command_line_keys() -> set[str]:
    keys = set()
    for override in HydraConfig.get().overrides.task:
        key = override.split("=", 1)[0].lstrip("+~")
        keys.add(key)
    return keys


def _command_line_groups() -> dict[str, str | None]:
    """The config groups the command line names (``rearing=strabismus``, ``+experiment=...``) and
    the option each group has in this run."""
    from aectorch.runtime.presets import GROUPS

    choices = HydraConfig.get().runtime.choices
    return {key: choices.get(key) for key in _command_line_keys() if key in GROUPS}


def _groups() -> dict[str, str | None]:
    """Every config group's option in this run (``provenance.json`` records them)."""
    from aectorch.runtime.presets import GROUPS

    choices = HydraConfig.get().runtime.choices
    return {group: choices.get(group) for group in GROUPS}


def _log_to_stderr() -> None:
    """The library's messages (the ``aectorch`` logger: resuming, interruptions, the watchdog, the
    depth calibration) go to stderr as plain lines, around the progress bars."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger = logging.getLogger("aectorch")
    logger.handlers[:] = [handler]
    logger.setLevel(logging.INFO)
    logger.propagate = False  # not also into Hydra's own log handlers


def _run_dir() -> Path:
    """This run's folder: Hydra's; on the other ranks of a torchrun run, the folder rank 0 writes
    (`_other_ranks_write_elsewhere`), so that ``train.resume=auto`` finds the same checkpoint."""
    shared = os.environ.get(_RUN_DIR_VAR) if int(os.environ.get("RANK", "0")) > 0 else None
    return Path(shared) if shared else Path(HydraConfig.get().runtime.output_dir)


@hydra.main(version_base=None, config_name="train")
def _train(raw: DictConfig) -> dict:
    _log_to_stderr()
    try:
        # Validate everything before any work; on resume, the run's own config and checkpoint.
        cfg, checkpoint = prepare_run(to_experiment_config(raw), _command_line_keys(), _run_dir(),
                                      groups=_command_line_groups())
    except (ValueError, OmegaConfBaseException) as err:  # a value rejected by the configs' checks
        if _debug():
            raise
        # Exit here, inside the job: Hydra would add its own "Error executing job" line.
        _fail(str(err).strip().splitlines()[0])
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    # A resumed run's folder is the one it resumes (prepare_run has resolved train.resume to it).
    folder = Path(cfg.train.resume) if checkpoint is not None and cfg.train.resume else run_dir
    try:
        with logging_redirect_tqdm(loggers=[logging.getLogger("aectorch")]):
            summary = run_experiment(cfg, run_dir, checkpoint=checkpoint,
                                     groups=_groups() if checkpoint is None else None)  # (a new run's)
        if summary:
            print(format_summary(summary, folder))
        return summary
    except WatchdogError:
        if _debug():
            raise
        sys.exit(3)  # the message and the checkpoint's iteration are printed already
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the checkpoint and the resume line are printed
        if _debug():
            raise
        sys.exit(130)
    except WriteFailed as err:  # a full disk: the file, what is kept and the resume line
        if _debug():
            raise
        try:
            kept = f"checkpoint.pt holds iteration {load_checkpoint(folder / 'checkpoint.pt')['iteration']}"
        except ValueError:
            kept = "no checkpoint was written yet"
        print(f"error: {err}; {kept}; free space, then resume: python train.py train.resume={folder}", file=sys.stderr)
        sys.exit(4)
    except ValueError as err:  # a file found bad while building (an image, a checkpoint's state)
        if _debug():
            raise
        _fail(str(err).strip().splitlines()[0])


def _one_line(err: BaseException) -> str:
    """Hydra's error in one line, with what it lists on the next ones (a group's options) and a hint
    for a key that only a group adds."""
    lines = str(err).strip().splitlines()
    text = lines[0] if lines else type(err).__name__
    cause = err.__cause__
    if isinstance(err, HydraException) and isinstance(cause, OmegaConfBaseException):
        # e.g. "Error merging override train.iterations=abc: Value 'abc' ... could not be converted to Integer"
        text = f"{text}: {str(cause).strip().splitlines()[0]}"
    options = re.search(r"Available options in '([^']+)':\n((?:\t.*\n?)+)", str(err))
    if options:
        names = [name.strip() for name in options.group(2).splitlines() if name.strip()]
        text = f"{text}; {options.group(1)} is one of: {', '.join(names)}"
    key = re.search(r"Could not (?:override|append to) '([\w.]+)'", text)
    if key and "not in struct" in text:
        text += _adding_hint(key.group(1))
    return text


def _adding_hint(key: str) -> str:
    """How to make ``key`` exist: the group option that adds it (``+experiment=accommodation`` for
    ``learner.cues.accommodation.*``), else where the keys are listed."""
    from aectorch.runtime.presets import ADDED_GROUPS, GROUPS

    for group, options in GROUPS.items():
        for option, values in options.items():
            if any(key == set_key or key.startswith(set_key + ".") for set_key in values):
                plus = "+" if group in ADDED_GROUPS else ""
                return f"; {key} exists with {plus}{group}={option} (add it to the command line)"
    return "; no such key in train.py's config (python train.py --cfg job lists them)"


_RUN_DIR_VAR = "AECTORCH_RUN_DIR"


def _check_auto_has_a_folder() -> None:
    """``train.resume=auto`` resumes the run folder's checkpoint: without a folder given, Hydra's
    default is a new ``outputs/<date>/<time>`` (``multirun/...`` for a sweep) at every start, which
    never holds one, so the request would do nothing."""
    if "train.resume=auto" not in sys.argv:
        return
    sweep = any(a in ("-m", "--multirun") for a in sys.argv)
    key = "hydra.sweep.dir" if sweep else "hydra.run.dir"
    if not any(a.startswith(key + "=") for a in sys.argv):
        _fail(f"train.resume=auto needs {key}=<folder>: without it every start makes a new folder "
              f"(Hydra's {'multirun' if sweep else 'outputs'}/<date>/<time>), which holds no run to resume")


def _other_ranks_write_elsewhere() -> None:
    """Under torchrun only rank 0 writes the run folder (aectorch.runtime.distributed): Hydra's own folder
    and files of the other ranks go to a temporary folder, so a run makes one folder. The run folder
    given (``hydra.run.dir``) is kept in ``AECTORCH_RUN_DIR`` for ``train.resume=auto``, which a
    multi-process run can only use with that folder given (every process must find the same run)."""
    import tempfile

    rank, world = int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1"))
    given = [a.split("=", 1)[1] for a in sys.argv if a.startswith("hydra.run.dir=")]
    if world > 1 and "train.resume=auto" in sys.argv and not given:
        _fail("train.resume=auto with several processes needs hydra.run.dir=<folder>, the same on every "
              "process (torchrun restarts them with the same command, and they must find the same run)")
    _check_auto_has_a_folder()
    if rank > 0:
        if given:
            os.environ[_RUN_DIR_VAR] = given[-1]
        sys.argv = [a for a in sys.argv if not a.startswith(("hydra.run.dir=", "hydra.output_subdir="))]
        sys.argv += [f"hydra.run.dir={tempfile.mkdtemp(prefix=f'aectorch-rank{rank}-')}", "hydra.output_subdir=null"]


def main(argv: Sequence[str] | None = None) -> int:
    """Train with ``argv`` (default: the process's arguments) as Hydra's overrides; returns the exit status
    (0, or the status the module's docstring lists). Hydra reads ``sys.argv``: ``argv`` stands in for it
    during the call."""
    from aectorch.cli import exit_status

    saved_argv, saved_full_error = sys.argv, os.environ.get("HYDRA_FULL_ERROR")
    if argv is not None:
        sys.argv = [sys.argv[0] if sys.argv else "aectorch-train", *argv]
    # Let Hydra re-raise instead of printing and exiting 1, so config errors can be reported here.
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        return exit_status(_start)
    finally:
        sys.argv = saved_argv
        if saved_full_error is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = saved_full_error


def _start() -> int:
    _other_ranks_write_elsewhere()
    try:
        _train()
    except (HydraException, OmegaConfBaseException) as err:  # bad override: type, unknown key
        if _debug():
            raise
        _fail(_one_line(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
