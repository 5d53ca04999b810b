"""The ``key=value`` command lines of ``python -m aectorch.evaluate`` and ``python -m aectorch.record``."""

from __future__ import annotations

from typing import Sequence

__all__ = ["UsageError", "parse_key_values"]


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
