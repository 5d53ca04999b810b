"""``aectorch-record``: ``python -m aectorch.record``, record a trained learner's trials as a LeRobot dataset;
``key=value`` arguments (it needs LeRobot: `aectorch.integrations.lerobot`)."""

from __future__ import annotations

from typing import Sequence

from aectorch.cli import exit_status
from aectorch.record import main as _command

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m aectorch.record`` with ``argv`` (default: the process's arguments);
    returns its exit status."""
    return exit_status(lambda: _command(argv))
