"""The command lines as console scripts (``[project.scripts]`` in pyproject.toml): one module per command,
each a thin ``main(argv=None) -> int`` around the command's implementation, whose own grammar it keeps.

- ``aectorch-train``: `aectorch.cli.train`, which ``train.py`` runs too: Hydra's ``key=value`` overrides (``-m``
  for a sweep).
- ``aectorch-evaluate``: ``python -m aectorch.evaluate``, ``key=value``.
- ``aectorch-report``: ``python -m aectorch.report``, subcommands with ``--options`` (argparse).
- ``aectorch-record``: ``python -m aectorch.record``, ``key=value`` (it needs LeRobot).
- ``aectorch-view``: ``python -m aectorch.visualize``, ``key=value``.

This package is the top layer of the import contract (pyproject.toml's ``[tool.importlinter]``): it may
import every other part of aectorch, and nothing imports it.
"""

from __future__ import annotations

from typing import Callable

__all__ = ["exit_status"]


def exit_status(call: Callable[[], int | None]) -> int:
    """``call()``'s status, with a ``SystemExit`` it raises (argparse's and Hydra's ``--help``, an
    ``error:`` line's exit) returned as its status rather than raised; a ``SystemExit`` carrying a
    message, not a number, is raised on (the interpreter prints it and exits with status 1)."""
    try:
        return call() or 0
    except SystemExit as done:
        if done.code is None or isinstance(done.code, int):
            return done.code or 0
        raise
