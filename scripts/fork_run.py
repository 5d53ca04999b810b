"""Continue a run from one of its checkpoints, with some settings changed, in a new folder.

    .venv/bin/python scripts/fork_run.py <run>/best.pt <new folder> key=value ... --iterations N

The question it answers: "from this state on, what if ...?" (a frozen dictionary, a slower
actor). The new folder gets the checkpoint, its config with the ``key=value`` overrides (the
dotted names of ``train.py``; validated like a fresh config, so a bad one stops here naming the
field) and the source run's ``metrics.jsonl`` (and ``code_readouts.jsonl``) up to the checkpoint's
iteration; the run then continues there exactly like ``train.py train.resume=<new folder>
train.iterations=N`` (bit for bit, without overrides). The checkpoint's early-stopping record (``best``) is dropped: the fork
chooses its own best window. The source run is not touched.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
from pathlib import Path


def _parse(overrides: list[str]):
    """The overrides in ``train.py``'s grammar (Hydra's: ``perturbations=[{kind:roll,start:8}]`` as
    the docs write it), as one config."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf import OmegaConf

    config = OmegaConf.create()
    for item in overrides:
        try:
            (override,) = OverridesParser.create().parse_overrides([item])
        except HydraException as err:
            raise ValueError(f"override {item!r} cannot be parsed: {str(err).splitlines()[0]}") from err
        OmegaConf.update(config, override.key_or_group, override.value(), merge=False)
    return config


def fork(checkpoint: Path, folder: Path, overrides: list[str], iterations: int) -> None:
    """Write the fork's folder (``ValueError`` before writing anything when an argument is bad)."""
    from omegaconf import OmegaConf

    from aectorch.runtime import checkpoint_config, load_checkpoint, save_checkpoint
    from aectorch.runtime.outputs import CODE_READOUTS

    if folder.exists() and any(folder.iterdir()):
        raise ValueError(f"folder {str(folder)!r} exists and is not empty; forks go to a new folder")
    for item in overrides:
        if "=" not in item:
            raise ValueError(f"override {item!r} is not key=value")
    payload = load_checkpoint(checkpoint)
    if iterations <= payload["iteration"]:
        raise ValueError(f"--iterations must be above the checkpoint's iteration {payload['iteration']}, "
                         f"got {iterations}")
    # The fork runs until ``iterations``: its config says so (perturbation events are checked
    # against the run's length).
    merged = OmegaConf.merge(OmegaConf.create(payload["config"]), {"train": {"iterations": iterations}},
                             _parse(overrides))
    payload["config"] = OmegaConf.to_container(merged)
    checkpoint_config(payload, checkpoint)  # names the field of a bad override
    payload.pop("best", None)
    folder.mkdir(parents=True, exist_ok=True)
    save_checkpoint(folder / "checkpoint.pt", payload)
    for name in ("metrics.jsonl", CODE_READOUTS):  # the resume keeps their lines up to the checkpoint
        if (checkpoint.parent / name).exists():
            shutil.copy(checkpoint.parent / name, folder / name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path, help="checkpoint.pt or best.pt of a run")
    parser.add_argument("folder", type=Path, help="the new run folder")
    parser.add_argument("overrides", nargs="*", help="key=value settings to change")
    parser.add_argument("--iterations", type=int, required=True, help="continue until this iteration")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_intermixed_args(argv)

    from aectorch.runtime.config import to_experiment_config
    from aectorch.runtime import run_experiment

    try:
        fork(args.checkpoint, args.folder, args.overrides, args.iterations)
    except ValueError as err:
        print(f"Error: {err}", file=sys.stderr)
        return 2
    cfg = to_experiment_config({"train": {"resume": str(args.folder), "iterations": args.iterations,
                                          "progress": not args.no_progress}})
    # The library's messages (resuming, a closed cue reopening, the watchdog) as plain lines on
    # stderr, around the progress bar, as train.py shows them.
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger = logging.getLogger("aectorch")
    handlers, level = logger.handlers[:], logger.level
    logger.handlers[:] = [handler]
    logger.setLevel(logging.INFO)
    from tqdm.contrib.logging import logging_redirect_tqdm

    try:
        with logging_redirect_tqdm(loggers=[logger]):
            run_experiment(cfg, args.folder)
    finally:  # (called in-process, as the tests do, the caller's logging is left as it was)
        logger.handlers[:] = handlers
        logger.setLevel(level)
    return 0


if __name__ == "__main__":
    sys.exit(main())
