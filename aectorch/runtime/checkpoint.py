"""Checkpoints and the rules of a resume, in one place.

A checkpoint (``checkpoint.pt``, ``best.pt``, ``calibrated.pt``) is a dict written with
``torch.save`` (atomically): ``format`` (:data:`CHECKPOINT_FORMAT`), ``config`` (the run's
resolved config as a plain dict), ``iteration``, the ``learner``'s, ``env``'s (one process: its
state; several: a list in rank order), ``metrics``' and ``watchdog``'s states,
``initial_dictionaries``, ``elapsed_s`` and ``best`` (the early-stopping record). A checkpoint
of an earlier format is read through `aectorch.runtime.migrations` (:func:`load_checkpoint`), so
the rest of the package sees today's layout only.

A resumed run is the stored run: :func:`prepare_run` loads the checkpoint once, takes its config,
lets only ``train.iterations``, ``train.progress``, ``train.resume``, ``watchdog.*`` and
``record.*`` come from the caller (:data:`RESUME_KEYS`), rejects a command-line value that
contradicts the stored config, and validates the resources once.
"""

from __future__ import annotations

import copy
import json
import os
import pickle
import re
from pathlib import Path

import torch

from aectorch.framework import JointLearner
from aectorch.runtime.builders import build_learner
from aectorch.runtime.config import ExperimentConfig, to_container, to_experiment_config
from aectorch.runtime.resources import validate_resources
from aectorch.runtime.migrations import CHECKPOINT_FORMAT, migrate
from aectorch.runtime.outputs import RUN_FILES, atomic_write
from aectorch.runtime.presets import ADDED_GROUPS, GROUP_DEFAULTS, GROUPS

__all__ = ["AUTO", "CHECKPOINT_FORMAT", "RESUME_KEYS", "RunExists", "check_new_run", "check_resume_groups",
           "check_resume_overrides", "check_started_groups", "started_groups",
           "checkpoint_config", "checkpoint_envs", "load_checkpoint", "load_learner", "prepare_run", "resolve_resume",
           "restore", "resume_config", "save_checkpoint"]

#: ``train.resume=auto``: resume the run folder's own checkpoint if there is one, else start there.
AUTO = "auto"

#: Keys of ``train`` kept from the command line when a run is resumed (and the whole ``watchdog``
#: and ``record`` sections, which change nothing that is learned); everything else is the run's own.
RESUME_KEYS = ("iterations", "progress", "resume", "overwrite")
#: Keys of ``train`` that a resume takes from the run unless the command line gives them.
_RUN_OWN_UNLESS_GIVEN = ("iterations", "progress")


def save_checkpoint(path: str | os.PathLike, payload: dict) -> None:
    """Write ``payload`` with ``torch.save`` atomically (temporary file, fsync, ``os.replace``):
    on a failed write (`aectorch.runtime.outputs.WriteFailed`) the previous file is kept."""
    atomic_write(path, lambda f: torch.save(payload, f), binary=True)


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read a checkpoint written by :func:`save_checkpoint` (of any format since the first release,
    in today's layout: `aectorch.runtime.migrations.migrate`); ``ValueError`` naming the path if
    it is missing, unreadable or not an aectorch checkpoint.

    Loading never runs code: the file is read with torch's restricted unpickler
    (``torch.load(weights_only=True)``), which builds tensors, numbers, strings and plain
    containers only, the whole of what a checkpoint holds (docs/security.md). A file that asks
    for anything else (a class, a function: what a malicious pickle calls) is refused with a
    ``ValueError`` before any of it is built.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no checkpoint at {str(path)!r}")
    _check_crcs(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        refused = re.search(r"GLOBAL ([\w.]+)", str(err))  # a class or function: what a malicious pickle calls
        if refused:
            raise ValueError(f"refusing to load {str(path)!r}: it holds objects that are not data (GLOBAL "
                             f"{refused.group(1)}); an aectorch checkpoint holds only tensors, numbers, strings "
                             f"and plain containers, and loading one never runs code") from None
        raise ValueError(f"cannot read the checkpoint {str(path)!r}: it is damaged (truncated?) or not a torch "
                         "checkpoint file") from None
    except Exception as err:  # a truncated, damaged or foreign file: torch's reader fails in many ways
        reason = f"{type(err).__name__}: {str(err).splitlines()[0]}" if str(err).strip() else type(err).__name__
        raise ValueError(f"cannot read the checkpoint {str(path)!r}: it is damaged (truncated?) or not a torch "
                         f"checkpoint file ({reason})") from err
    if not isinstance(payload, dict) or "format" not in payload or "config" not in payload:
        raise ValueError(f"{str(path)!r} is not an aectorch checkpoint (no format and config entries)")
    try:
        payload = migrate(payload)
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as err:
        raise ValueError(f"{str(path)!r} is not an aectorch checkpoint this version reads: "
                         f"{type(err).__name__}: {err}") from err
    return payload


def _check_crcs(path: Path) -> None:
    """A checkpoint is a zip archive whose entries carry CRC-32s, which ``torch.load`` does not
    check: a flipped bit in a tensor would load as another number. ``ValueError`` naming ``path``
    for an entry whose bytes do not match its CRC (a file that is no zip is left to ``torch.load``)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except zipfile.BadZipFile:
        return  # not a zip, or its directory damaged: torch.load names it
    except Exception as err:  # noqa: BLE001 - a damaged header: zipfile fails in several ways
        raise ValueError(f"cannot read the checkpoint {str(path)!r}: it is damaged (truncated?) or not a torch "
                         f"checkpoint file ({type(err).__name__}: {err})") from None
    if bad is not None:
        raise ValueError(f"cannot read the checkpoint {str(path)!r}: it is damaged ({bad} does not match its CRC-32)")


#: The entries of a run's checkpoint that a resume (all) and an evaluation (the first three) read.
_LAYOUT = (("config", dict), ("iteration", int), ("learner", dict), ("env", (dict, list)))


def _check_layout(payload: dict, path: str | os.PathLike, entries: int = len(_LAYOUT)) -> None:
    """The entries a reader of a run's checkpoint takes for granted (the first ``entries`` of
    :data:`_LAYOUT`), of the right types: a damaged or hand-edited file is named here, not met as a
    ``KeyError`` deep in a resume or an evaluation."""
    path = Path(path)
    for key, kind in _LAYOUT[:entries]:
        value = payload.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise ValueError(f"{str(path)!r} is not an aectorch checkpoint this version reads: its {key!r} entry "
                             f"is {type(value).__name__}, not {getattr(kind, '__name__', 'dict or list')}")
    train = payload["config"].get("train")
    if not isinstance(train, dict):
        raise ValueError(f"{str(path)!r} is not an aectorch checkpoint this version reads: its config has no train "
                         "section")


def checkpoint_config(payload: dict, path: str | os.PathLike) -> ExperimentConfig:
    """The validated config stored in a checkpoint (as :func:`load_checkpoint` returns it);
    ``ValueError`` naming ``path`` if this version of aectorch cannot use it."""
    # The watchdog and the recording change nothing that is learned and come from the command line
    # on resume, so a checkpoint from a version with other watchdog options still loads.
    stored = {k: v for k, v in payload["config"].items() if k not in ("watchdog", "record")}
    try:
        return to_experiment_config(stored)
    except Exception as err:  # unknown keys, wrong types, impossible values
        raise ValueError(f"the checkpoint {str(path)!r} holds a config this aectorch cannot use "
                         f"({type(err).__name__}: {str(err).strip().splitlines()[0]})") from err


def restore(target, state: dict, path: str | os.PathLike, what: str) -> None:
    """``target.load_state_dict(state)``; ``ValueError`` naming ``path`` when they do not fit."""
    try:
        target.load_state_dict(state)
    except Exception as err:  # missing/unexpected keys, shape mismatches
        raise ValueError(f"the {what} state in {str(path)!r} does not fit its config "
                         f"({type(err).__name__}: {str(err).strip().splitlines()[0]}); was it written "
                         "by an incompatible aectorch version?") from err


def load_learner(checkpoint_path: str | os.PathLike, device=None, *,
                 payload: dict | None = None) -> tuple[ExperimentConfig, JointLearner]:
    """The config and the trained learner of a checkpoint (on ``device``, default the run's);
    ``payload``: the checkpoint, when it was read already."""
    payload = load_checkpoint(checkpoint_path) if payload is None else payload
    _check_layout(payload, checkpoint_path, entries=3)
    cfg = checkpoint_config(payload, checkpoint_path)
    learner = build_learner(cfg, device=device)
    restore(learner, payload["learner"], checkpoint_path, "learner")
    return cfg, learner


def resume_config(cfg: ExperimentConfig, checkpoint: dict) -> ExperimentConfig:
    """The stored config of ``checkpoint`` with ``train.iterations/progress/resume`` of ``cfg``."""
    where = Path(cfg.train.resume) / "checkpoint.pt" if cfg.train.resume else "the checkpoint"
    stored = to_container(checkpoint_config(checkpoint, where))
    for key in RESUME_KEYS:
        stored["train"][key] = getattr(cfg.train, key)
    mine = to_container(cfg)
    stored["watchdog"], stored["record"] = mine["watchdog"], mine["record"]
    stored["env"]["num_envs"] = cfg.env.num_envs  # this run's share of the batch (`prepare_run` checks it)
    return to_experiment_config(stored)


def check_resume_overrides(cfg: ExperimentConfig, stored: ExperimentConfig, given: set[str]) -> None:
    """A resumed run is the stored run: a command-line key in ``given`` whose value contradicts it
    is an error, not silently ignored (only train.iterations/progress/resume, watchdog.* and
    record.* may change)."""
    from omegaconf import OmegaConf

    mine, theirs = OmegaConf.create(to_container(cfg)), OmegaConf.create(to_container(stored))
    for key in sorted(given):
        if key.startswith(("hydra.", "watchdog", "record")) or key in {f"train.{k}" for k in RESUME_KEYS} \
                or key in GROUPS or key == "env.num_envs":  # (the groups: `check_resume_groups`)
            continue
        ours, run = OmegaConf.select(mine, key), OmegaConf.select(theirs, key)
        if ours != run:
            raise ValueError(
                f"{key}={ours!r} contradicts the resumed run's {key}={run!r}: train.resume continues "
                f"{cfg.train.resume} with its own config (only train.iterations, train.progress, env.num_envs, "
                "watchdog.* and record.* may be given); start a new run to change it")


def started_groups(folder: str | os.PathLike) -> dict[str, str | None] | None:
    """The config groups' options a ``train.py`` run was started with: those its first session
    recorded in ``provenance.json`` (`aectorch.runtime.run_experiment`'s ``groups``), else its
    Hydra record (``.hydra/overrides.yaml``, which a resume leaves as it is:
    `aectorch.runtime.launch`); ``None`` when the folder has neither (a run of `run_experiment`
    without ``groups``)."""
    try:
        first = json.loads((Path(folder) / "provenance.json").read_text())["sessions"][0]
        recorded = first["groups"]
    except (OSError, ValueError, KeyError, IndexError, TypeError):
        recorded = None
    if isinstance(recorded, dict):
        return {group: recorded.get(group, GROUP_DEFAULTS[group]) for group in GROUPS}
    path = Path(folder) / ".hydra" / "overrides.yaml"
    try:
        from omegaconf import OmegaConf

        overrides = OmegaConf.to_container(OmegaConf.load(path))
    except Exception:  # noqa: BLE001 - missing or not Hydra's: the options are unknown
        return None
    if not isinstance(overrides, list):
        return None
    chosen = dict(GROUP_DEFAULTS)
    for item in overrides:
        key, _, value = str(item).partition("=")
        group = key.lstrip("+~")
        if group in GROUPS:
            chosen[group] = None if key.startswith("~") or value in ("", "null") else value
    return chosen


def _show(value) -> str:
    from omegaconf import OmegaConf

    return str(OmegaConf.to_container(value) if OmegaConf.is_config(value) else value)


def check_started_groups(groups: dict[str, str | None], started: dict[str, str | None] | None, where) -> None:
    """``ValueError`` when a config group given to a resume (``groups``) names another option than
    the run ``where`` was started with (``started``, `started_groups`; ``None``: unknown)."""
    for group, option in sorted(groups.items()):
        if started is not None and started.get(group) != option:
            given = f"{'+' if group in ADDED_GROUPS else ''}{group}={option}"
            was = f"{group}={started[group]}" if started.get(group) is not None else f"no {group}"
            raise ValueError(f"{given} contradicts the resumed run, started with {was}: train.resume continues "
                             f"{where} with its own config, groups included; start a new run to change it")


def check_resume_groups(cfg: ExperimentConfig, stored: ExperimentConfig, groups: dict[str, str | None],
                        started: dict[str, str | None] | None = None) -> None:
    """A resume is the stored run, its config groups included: a group given on the command line
    (``groups``: group -> option, e.g. ``{"rearing": "strabismus"}``) that names another option
    than the run was started with (``started``, `started_groups`), or whose keys contradict the
    stored config, is a ``ValueError`` naming it (only ``train.iterations`` may differ)."""
    from omegaconf import OmegaConf

    mine, theirs = OmegaConf.create(to_container(cfg)), OmegaConf.create(to_container(stored))
    where = cfg.train.resume
    check_started_groups(groups, started, where)
    for group, option in sorted(groups.items()):
        given = f"{'+' if group in ADDED_GROUPS else ''}{group}={option}"
        for key in sorted(GROUPS[group].get(option, {})):  # type: ignore[arg-type]  # (None: no option's keys)
            if key in {f"train.{k}" for k in RESUME_KEYS}:
                continue
            ours, run = OmegaConf.select(mine, key), OmegaConf.select(theirs, key)
            if ours != run:
                raise ValueError(f"{given} sets {key}={_show(ours)}, but the resumed run has {key}={_show(run)}: "
                                 f"train.resume continues {where} with its own config, groups included; start a "
                                 "new run to change it")


class RunExists(ValueError):
    """A new run into a folder that holds a run's ``checkpoint.pt`` (``train.overwrite`` is off)."""


def check_new_run(folder: str | os.PathLike, overwrite: bool = False, *, elsewhere: str = "hydra.run.dir=...") -> None:
    """Refuse to start a new run in ``folder`` when it holds a run's ``checkpoint.pt``, or, without
    the ``provenance.json`` a run writes when it starts, any other file a run writes
    (`aectorch.runtime.outputs.RUN_FILES`: a user's ``config.yaml`` or ``summary.json``), unless
    ``overwrite``: `RunExists`, one line naming the folder, what it holds and the ways on
    (``elsewhere``: the key that gives another folder).
    A rerun of a finished command, a re-launched sweep or a requeued job would otherwise erase the
    run (``train.py`` calls this before anything is written)."""
    path = Path(folder) / "checkpoint.pt"
    if overwrite:
        return
    if not path.is_file():
        found = [name for name in RUN_FILES if (Path(folder) / name).exists()]
        # A run's own start record without a checkpoint: a start killed before its first one
        # (nothing trained is kept), which a requeued job (train.resume=auto) starts again.
        if found and "provenance.json" not in found:
            raise RunExists(f"{str(folder)!r} holds {', '.join(found)} but no checkpoint.pt, which a new run would "
                            f"overwrite; nothing was written. Give another folder ({elsewhere}), or "
                            "train.overwrite=true to delete them and start afresh")
        return
    try:
        payload = load_checkpoint(path)
        held = f"iteration {payload['iteration']} of {payload['config']['train']['iterations']}"
    except (ValueError, KeyError, TypeError) as err:
        held = f"a checkpoint this aectorch cannot read ({str(err).splitlines()[0]})"
    raise RunExists(f"{str(folder)!r} holds a run (checkpoint.pt at {held}); nothing was written. Continue it with "
                    f"train.resume={folder} (train.resume=auto does so whenever its folder holds a checkpoint), or "
                    f"give another folder ({elsewhere}); train.overwrite=true deletes it and starts afresh")


def resolve_resume(cfg: ExperimentConfig, run_dir: str | os.PathLike | None) -> ExperimentConfig:
    """``cfg`` with ``train.resume=auto`` made definite: ``run_dir`` if it holds a ``checkpoint.pt``,
    else ``None`` (a new run there). Other values are returned as they are."""
    if cfg.train.resume != AUTO:
        return cfg
    if run_dir is None:
        raise ValueError("train.resume=auto needs the run folder it resumes (run_experiment's run_dir)")
    cfg = copy.deepcopy(cfg)
    cfg.train.resume = str(run_dir) if (Path(run_dir) / "checkpoint.pt").is_file() else None
    return cfg


def checkpoint_envs(checkpoint: dict) -> int:
    """The environments of the whole batch a checkpoint holds (over all the processes that wrote it)."""
    env = checkpoint["env"]
    return sum(int(part["num_envs"]) for part in env) if isinstance(env, list) else int(env["num_envs"])


def _resume_num_envs(cfg: ExperimentConfig, checkpoint: dict, given: set[str] | None, path: Path) -> None:
    """``env.num_envs`` of a resume: the command line's, else the checkpoint's whole batch split over
    this run's processes; either way the whole batch must be the checkpoint's."""
    from aectorch.runtime.distributed import world_from_env

    total, world = checkpoint_envs(checkpoint), world_from_env()[1]
    if given is None or "env.num_envs" not in given:
        if total % world:
            raise ValueError(f"env.num_envs: the checkpoint {str(path)!r} holds {total} environments, which "
                             f"{world} processes cannot share evenly; resume with a number of processes that divides it")
        cfg.env.num_envs = total // world
    if cfg.env.num_envs * world != total:
        raise ValueError(f"env.num_envs={cfg.env.num_envs} with {world} process(es) makes a batch of "
                         f"{cfg.env.num_envs * world}, but the checkpoint {str(path)!r} holds {total} environments; "
                         f"give env.num_envs={total // world if total % world == 0 else '...'} (the whole batch "
                         "stays the run's)")


def prepare_run(cfg: ExperimentConfig, given: set[str] | None = None,
                run_dir: str | os.PathLike | None = None,
                groups: dict[str, str | None] | None = None) -> tuple[ExperimentConfig, dict | None]:
    """The config a run uses and the checkpoint it resumes (``None`` for a new run).

    Validates the resources (`validate_resources`) once. ``train.resume=auto`` resumes ``run_dir``
    if it holds a checkpoint (`resolve_resume`). A new run into a ``run_dir`` that holds one is
    refused unless ``train.overwrite`` (`check_new_run`). With ``cfg.train.resume``, reads the
    checkpoint once and returns its stored config (:func:`resume_config`), with ``env.num_envs``
    the command line's or the checkpoint's whole batch split over this run's processes (the
    whole batch must stay the checkpoint's). ``given``: the keys
    set on the command line (``train.py``); then ``train.iterations`` and ``train.progress`` are
    the run's own unless given, and a given key that contradicts the stored config is an error
    (:func:`check_resume_overrides`); ``groups``: the config groups the command line gives and
    their options, which must be the run's (:func:`check_resume_groups`). ``ValueError`` naming the
    key or the file for anything wrong.
    """
    cfg = resolve_resume(cfg, run_dir)
    if cfg.train.resume is None:
        if run_dir is not None:
            check_new_run(run_dir, cfg.train.overwrite)
        validate_resources(cfg)
        return cfg, None
    path = Path(cfg.train.resume) / "checkpoint.pt"
    if not path.is_file():
        raise ValueError(f"train.resume: no checkpoint at {str(path)!r}")
    checkpoint = load_checkpoint(path)
    _check_layout(checkpoint, path)
    if given is not None:
        stored = checkpoint_config(checkpoint, path)
        for key in _RUN_OWN_UNLESS_GIVEN:
            if f"train.{key}" not in given:
                setattr(cfg.train, key, getattr(stored.train, key))
        check_resume_overrides(cfg, stored, given)
        check_resume_groups(cfg, stored, groups or {}, started_groups(cfg.train.resume))
    _resume_num_envs(cfg, checkpoint, given, path)
    cfg = resume_config(cfg, checkpoint)
    validate_resources(cfg)
    return cfg, checkpoint
