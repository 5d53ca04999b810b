"""``aectorch-view``: ``python -m aectorch.visualize``, an animation of one trial;
``key=value`` arguments, ``--help`` lists the keys."""

from __future__ import annotations

from typing import Sequence

from aectorch.cli import exit_status
from aectorch.visualize.__main__ import main as _command

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m aectorch.visualize`` with ``argv`` (default: the process's arguments);
    returns its exit status."""
    return exit_status(lambda: _command(argv))
