"""Running a report command: parse, check the outputs, compute, print; one ``error:`` line
(status 2) for a missing file, a bad file or a bad argument. ``python -m aectorch.report`` and the
studies' own report scripts (``experiments/<study>/report.py``) share it."""

from __future__ import annotations

import argparse
import inspect
import os
import sys
from typing import Sequence

from aectorch.runs import Run, files_read, forget_files_read
from aectorch.runtime.command import check_output_file

__all__ = ["pairs", "run_command", "run_groups"]


def pairs(items: Sequence[str], what: str) -> list[tuple[str, str]]:
    """``name=value`` arguments as ``(name, value)`` pairs; ``what`` is the message of one that is
    not (an empty name or value).

    Example:
        >>> pairs(["a=1", "b=x=y"], "pairs are name=value")
        [('a', '1'), ('b', 'x=y')]
    """
    out = [item.partition("=")[::2] for item in items]
    bad = [item for item, (key, value) in zip(items, out) if not key or not value]
    if bad:
        raise ValueError(f"{what}, got {bad[0]!r}")
    return out


def run_groups(items: Sequence[str]) -> dict[str, list[Run]]:
    """``name=run,run,...`` arguments as groups of runs, by name (a study's or ``compare``'s)."""
    return {name: [Run(r) for r in runs.split(",")] for name, runs in pairs(items, "groups are name=run,run,...")}


def study_parser(prog: str, documented, run) -> argparse.ArgumentParser:
    """The parser of a study's command (``experiments/<study>/<name>.py``): ``prog``, its help the
    docstring of ``documented`` (the function it runs) kept as written, and ``run(args)`` the
    function `run_command` calls with the parsed arguments. Its scripts add their own arguments."""
    out = argparse.ArgumentParser(prog=prog, description=inspect.cleandoc(documented.__doc__ or ""),
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    out.set_defaults(run=run)
    return out


def run_command(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` with ``parser`` (whose parsed arguments carry ``run(args) -> lines``), check
    every output it names (``--json``, ``--plot``, ``--out``, ``--cache``, ``--curves``) before any
    work, run it and print its lines; returns 0, or 2 after one ``error:`` line
    (``AECTORCH_DEBUG=1`` raises instead, with the traceback)."""
    args = parser.parse_args(argv)
    forget_files_read()
    try:
        for key in ("json", "plot", "out", "cache", "curves"):  # the outputs, before any work
            if getattr(args, key, None) is not None:
                check_output_file(getattr(args, key), f"--{key}", makes_folder=True)
        lines = args.run(args)
    except (OSError, KeyError, ValueError, TypeError, AttributeError, IndexError, ArithmeticError) as err:
        if os.environ.get("AECTORCH_DEBUG", "") not in ("", "0"):
            raise
        message = str(err.args[0] if isinstance(err, KeyError) and err.args else err).strip()
        message = message.splitlines()[0] if message else ""
        read = [str(path) for path in files_read()]
        if read and not any(path in message for path in read):
            # A value not of the shape aectorch writes (a hand-edited or damaged file): name the files.
            message = (f"cannot use {', '.join(read)}: {type(err).__name__}: {message} (a value of another "
                       "type or a missing entry: is a file damaged or hand-edited?)")
        print(f"error: {message} (AECTORCH_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0
