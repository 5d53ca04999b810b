"""What every benchmark records about the machine it ran on."""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

from aectorch.runtime.provenance import cpu_model  # noqa: F401  (re-exported for the benchmarks)


def machine_info() -> dict:
    """The command, the CPU and the torch version, for a benchmark's JSON."""
    import torch

    return {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
    }
