"""The grammar of the command lines beside ``train.py`` (``python -m aectorch.evaluate``, ``record``,
``visualize``): ``key=value`` arguments merged into a structured config and checked as
``train.py``'s are, ``--help`` from the config's docstring, and one ``error:`` line for bad input.

A command's config is a dataclass: its docstring says what the command does and, under
``Args:``, what each key means; a field without a default (``MISSING``) is required; its
``__post_init__`` rejects impossible values with a message that starts with the key's name.
OmegaConf merges the arguments into it (YAML values: ``depths=[1.0,2.0]``, ``progress=false``),
rejecting unknown keys and values of the wrong type or outside an enum's choices.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import sys
import textwrap
from enum import Enum
from typing import Callable, Sequence, TypeVar

__all__ = ["check_checkpoint_file", "check_output_file", "parse", "run", "usage"]

C = TypeVar("C")


def _field_docs(cls) -> dict[str, str]:
    """``{field: description}`` from the ``Args:`` section of ``cls``'s docstring."""
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    docs: dict[str, str] = {}
    key = None
    inside = False
    for line in lines:
        if line.strip() == "Args:":
            inside = True
            continue
        if not inside:
            continue
        if line and not line.startswith(" "):
            break  # the section after Args
        text = line.strip()
        name, colon, rest = text.partition(":")
        if line.startswith("    ") and not line.startswith("        ") and colon and name.isidentifier():
            key = name
            docs[key] = rest.strip()
        elif key is not None and text:
            docs[key] += " " + text
    return docs


def usage(cls, command: str) -> str:
    """``--help`` of ``python -m <command>``: the docstring's summary, then every key with its
    description and default (``required`` for a field without one)."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    summary = doc.split("\nArgs:")[0].strip()
    fields = dataclasses.fields(cls)
    described = _field_docs(cls)
    required = [f.name for f in fields if f.default == "???"]  # (OmegaConf's MISSING)
    lines = [f"usage: python -m {command} " + " ".join(f"{name}=..." for name in required) + " [key=value ...]",
             "", summary, "", "keys (values are YAML: depths=[1.0,2.0], progress=false):"]
    for f in fields:
        value = None if f.name in required else \
            f.default_factory() if f.default is dataclasses.MISSING else f.default
        # (a key without a default says in its description what it falls back to)
        default = " (required)" if f.name in required else "" if value is None else f" (default: {_show(value)})"
        text = described.get(f.name, "").rstrip(".") + default + "."
        lines.append(textwrap.fill(text, width=100, initial_indent=f"  {f.name:<12} ",
                                   subsequent_indent=" " * 15))
    lines += ["", 'Errors print one "error: ..." line and exit with status 2.']
    return "\n".join(lines) + "\n"


def _show(value) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_show(v) for v in value) + "]"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def check_checkpoint_file(value: str, key: str = "checkpoint") -> None:
    """``ValueError`` naming ``key`` when ``value`` is not a file: a run folder is answered with its
    ``checkpoint.pt``. (What the file holds is `aectorch.runtime.checkpoint.load_checkpoint`'s check.)"""
    if os.path.isdir(value):
        inside = os.path.join(value, "checkpoint.pt")
        hint = f"; give its checkpoint, {key}={inside}" if os.path.isfile(inside) else \
            "; give a checkpoint file (a run folder's checkpoint.pt)"
        raise ValueError(f"{key}: {value!r} is a folder, not a checkpoint file{hint}")
    if not os.path.isfile(value):
        raise ValueError(f"{key}: no such file {value!r}")


def check_output_file(value: str | os.PathLike, key: str = "out", suffixes: Sequence[str] = (), *,
                      makes_folder: bool = False) -> None:
    """``ValueError`` naming ``key`` unless ``value`` is a file this command can write, checked
    before any work: its folder exists (or, ``makes_folder``, can be made) and is writable, it is
    not a folder, and it ends in one of ``suffixes`` (when given)."""
    value = os.fspath(value)
    if os.path.isdir(value):
        raise ValueError(f"{key}: {value!r} is a folder; give a file in it")
    if suffixes and not value.lower().endswith(tuple(suffixes)):
        raise ValueError(f"{key} must end in {' or '.join(suffixes)}, got {value!r}")
    folder = os.path.dirname(value) or "."
    if makes_folder:
        while not os.path.exists(folder) and os.path.dirname(folder) not in ("", folder):
            folder = os.path.dirname(folder)
        if os.path.exists(folder) and not os.path.isdir(folder):
            raise ValueError(f"{key}: {folder!r} is a file, so {value!r} cannot be made")
    if not os.path.isdir(folder):
        raise ValueError(f"{key}: no such folder {folder!r} (make it first, or give another {key})")
    if not os.access(folder, os.W_OK | os.X_OK) or os.path.exists(value) and not os.access(value, os.W_OK):
        raise ValueError(f"{key}: cannot write {value!r} (permission denied or a read-only file system); "
                         f"give another {key}")


def _expected(cls, key: str) -> str:
    """What the field ``key`` of ``cls`` takes, for a value OmegaConf could not convert."""
    import typing

    hints = typing.get_type_hints(cls)
    kind = hints.get(key)
    if typing.get_origin(kind) is typing.Union:  # Optional[X]
        kind = next(a for a in typing.get_args(kind) if a is not type(None))
    if typing.get_origin(kind) in (list, tuple):
        return "a list such as [1.0,2.0]"
    if isinstance(kind, type) and issubclass(kind, Enum):
        return "one of " + ", ".join(m.name for m in kind)
    return {int: "an int", float: "a number", bool: "true or false", str: "a string"}.get(kind, str(kind))


def parse(cls: type[C], argv: Sequence[str]) -> C:
    """The config ``cls`` with the ``key=value`` arguments ``argv`` merged in and checked.

    Raises:
        ValueError: a malformed argument, an unknown key, a value of the wrong type, a missing
            required key, or the config's own check (each message names the key).
    """
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigKeyError, MissingMandatoryValue, OmegaConfBaseException

    names = [f.name for f in dataclasses.fields(cls)]
    overrides = []
    for item in argv:
        key, equals, _ = item.partition("=")
        if not equals:
            raise ValueError(f"arguments are key=value, got {item!r} (see --help)")
        if key not in names:
            raise ValueError(f"unknown key {key!r}; keys are {', '.join(names)}")
        try:
            overrides.append(OmegaConf.from_dotlist([item]))
        except Exception as err:  # noqa: BLE001 - OmegaConf's grammar or YAML's parser: the value does not parse
            raise ValueError(f"{key}: cannot parse {item!r}: {str(err).splitlines()[0]}") from err
    try:
        merged = OmegaConf.merge(OmegaConf.structured(cls), *overrides)
        return OmegaConf.to_object(merged)
    except MissingMandatoryValue as err:
        raise ValueError(f"{err.full_key}=<...> is required (see --help)") from err
    except ConfigKeyError as err:  # (the keys are checked above; kept for nested configs)
        raise ValueError(f"unknown key {err.full_key!r}; keys are {', '.join(names)}") from err
    except OmegaConfBaseException as err:
        message = str(err.msg).splitlines()[0]
        if "is not a ListConfig" in message:  # (OmegaConf's own words name its node type, not the key's)
            given = dict(item.partition("=")[::2] for item in argv).get(err.full_key)
            raise ValueError(f"{err.full_key} must be {_expected(cls, err.full_key)}, got {given!r}") from err
        raise ValueError(f"{err.full_key}: {message}") from err


def run(argv: Sequence[str] | None, cls: type[C], command: str, body: Callable[[C], int]) -> int:
    """``--help`` (or no arguments) prints `usage`; otherwise ``body(parse(cls, argv))``, whose
    bad-input errors (``ValueError``, ``ImportError``, ``OSError``) become one ``error:`` line and
    status 2 unless ``AECTORCH_DEBUG=1`` asks for the traceback."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or any(a in ("-h", "--help", "help") for a in argv):
        print(usage(cls, command), end="")
        return 0 if argv else 2
    try:
        return body(parse(cls, argv))
    except (ValueError, ImportError, OSError) as err:
        if os.environ.get("AECTORCH_DEBUG", "") not in ("", "0"):
            raise
        print(f"error: {str(err).strip().splitlines()[0]} (AECTORCH_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2
