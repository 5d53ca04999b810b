"""What made a run: the versions, the git commit, the device and the machine (``provenance.json``).

`run_experiment` writes `provenance()` into the run folder when a run starts and appends one
entry per resumed session, so a result can be traced to the code and machine that produced it.

Example:
    >>> from aectorch.runtime.provenance import provenance
    >>> info = provenance("cpu")
    >>> {"aectorch", "torch", "git", "device"} <= set(info)
    True
"""

from __future__ import annotations

import datetime
import platform
import socket
import subprocess
import sys
from pathlib import Path

import torch

__all__ = ["cpu_model", "git_commit", "provenance"]

_ROOT = Path(__file__).resolve().parents[2]


def git_commit(folder: str | Path = _ROOT) -> dict | None:
    """``{"commit": sha, "dirty": bool}`` of the git checkout holding ``folder``; None outside one."""
    try:
        sha = subprocess.run(["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10, check=True).stdout.strip()
        status = subprocess.run(["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True, timeout=10, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": sha, "dirty": bool(status.strip())}


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (``platform.processor()`` is often empty on Linux)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance(device: str | torch.device) -> dict:
    """The aectorch, torch and Python versions, the git commit, the device, CPU, threads and host."""
    import aectorch
    from aectorch.ops import native

    device = torch.device(device)
    info = {
        "aectorch": aectorch.__version__,
        "git": git_commit(),
        "torch": torch.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "host": socket.gethostname(),
        "cpu": cpu_model(),
        "device": str(device),
        "threads": torch.get_num_threads(),
        "deterministic_algorithms": torch.are_deterministic_algorithms_enabled(),
        "native_kernels": native.available(),
        "native_kernel_threads": native.get_threads(),
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    if device.type == "cuda":
        info["cuda"] = torch.version.cuda
        info["gpu"] = torch.cuda.get_device_name(device)
    return info
