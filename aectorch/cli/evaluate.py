"""``aectorch-evaluate``: ``python -m aectorch.evaluate``, evaluate a checkpoint;
``key=value`` arguments, ``--help`` lists the keys."""

from __future__ import annotations

from typing import Sequence

from aectorch.cli import exit_status
from aectorch.evaluate import main as _command

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m aectorch.evaluate`` with ``argv`` (default: the process's arguments);
    returns its exit status."""
    return exit_status(lambda: _command(argv))
