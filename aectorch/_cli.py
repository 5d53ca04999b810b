"""The ``key=value`` command lines of ``python -m aectorch.evaluate`` and ``python -m aectorch.record``."""

from __future__ import annotations

import os
import sys
from typing import Callable, Sequence

__all__ = ["UsageError", "parse_key_values", "run_main"]


class UsageError(ValueError):
    """A command-line argument is missing, unknown or malformed (one ``error:`` line, exit 2)."""


def parse_key_values(argv: Sequence[str], keys: Sequence[str], required: Sequence[str],
                     paths: Sequence[str] = ()) -> dict:
    """``["a=1", "b=[1,2]"]`` -> ``{"a": 1, "b": [1, 2]}`` (values parsed as OmegaConf/YAML).

    Raises `UsageError` naming the key for an argument without ``=``, an unknown key, a value that
    does not parse or a missing ``required`` key; ``paths`` are returned as strings.
    """
    from omegaconf import OmegaConf

    args: dict = {}
    for item in argv:
        if "=" not in item:
            raise UsageError(f"arguments are key=value, got {item!r} (see --help)")
        key = item.split("=", 1)[0]
        if key not in keys:
            raise UsageError(f"unknown key {key!r}; keys are {', '.join(keys)}")
        try:
            args[key] = OmegaConf.to_container(OmegaConf.from_dotlist([item]))[key]
        except Exception as err:
            raise UsageError(f"{key}: cannot parse {item!r}: {str(err).splitlines()[0]}") from err
    for key in required:
        if args.get(key) in (None, ""):
            raise UsageError(f"{key}=<...> is required (see --help)")
    for key in paths:
        if key in args and args[key] is not None and not isinstance(args[key], str):
            args[key] = str(args[key])
    return args


def run_main(argv: Sequence[str] | None, usage: str, run: Callable[[list[str]], int]) -> int:
    """``--help`` (or no arguments) prints ``usage``; otherwise ``run(argv)``, whose bad-input errors
    (``ValueError``, ``ImportError``, ``OSError``) become one ``error:`` line and status 2 unless
    ``AECTORCH_DEBUG=1`` asks for the traceback."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or any(a in ("-h", "--help", "help") for a in argv):
        print(usage, end="")
        return 0 if argv else 2
    try:
        return run(argv)
    except (ValueError, ImportError, OSError) as err:
        if os.environ.get("AECTORCH_DEBUG", "") not in ("", "0"):
            raise
        print(f"error: {str(err).strip().splitlines()[0]} (AECTORCH_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2
