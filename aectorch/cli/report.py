"""``aectorch-report``: ``python -m aectorch.report``, the tables and figures of run folders;
subcommands with ``--options``, ``--help`` lists them."""

from __future__ import annotations

from typing import Sequence

from aectorch.cli import exit_status
from aectorch.report.__main__ import main as _command

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m aectorch.report`` with ``argv`` (default: the process's arguments);
    returns its exit status."""
    return exit_status(lambda: _command(argv))
