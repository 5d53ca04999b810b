"""Wall-clock time per stage of the training loop, for benchmarks and curious users.

The learner marks its stages with :class:`stage` (``"render"``, ``"encode"``, ``"rl"``,
``"dictionary"``, ``"env"``, ``"depth"``, ``"metrics"``). Nothing is measured unless a
:class:`StageTimer` is active, and then only in the thread that runs the loop; with no timer a
stage costs one global read on entry and exit.

Example:
    >>> import torch
    >>> from aectorch.framework import JointLearner, LearnerConfig
    >>> from aectorch.sim import ActiveDepthEnv, TrialProtocol
    >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64), seed=0)
    >>> learner = JointLearner(LearnerConfig())
    >>> with StageTimer() as timer:
    ...     _ = learner.iteration(env)
    >>> sorted(timer.seconds) == sorted(["render", "encode", "rl", "dictionary", "env", "metrics"])
    True
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import Literal

import torch

__all__ = ["StageTimer", "stage"]

_active: "StageTimer | None" = None


class StageTimer:
    """Accumulates exclusive wall time per stage name while active (``with StageTimer() as t``).

    Stages may nest; a stage's time excludes the stages inside it. On CUDA (``device``), the
    device is synchronised at every stage boundary so that each stage is charged its own
    kernels, which slows the loop: use it for a breakdown, not for throughput.
    """

    def __init__(self, device: torch.device | str | None = None) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        device = torch.device(device) if device is not None else None
        self._sync = device is not None and device.type == "cuda"
        self._stack: list[list] = []  # [name, start, time spent in children]
        self._previous: StageTimer | None = None

    def __enter__(self) -> "StageTimer":
        global _active
        self._previous, _active = _active, self
        return self

    def __exit__(self, *exc) -> Literal[False]:
        global _active
        _active = self._previous
        return False

    def reset(self) -> None:
        """Forget what was measured so far."""
        self.seconds.clear()
        self.calls.clear()

    def total(self) -> float:
        """Seconds measured in all stages together."""
        return sum(self.seconds.values())

    def _push(self, name: str) -> None:
        if self._sync:
            torch.cuda.synchronize()
        self._stack.append([name, time.perf_counter(), 0.0])

    def _pop(self, name: str) -> None:
        if self._sync:
            torch.cuda.synchronize()
        top, start, children = self._stack.pop()
        if top != name:  # pragma: no cover - a programming error in the stage marks
            raise RuntimeError(f"stage {name!r} closed while {top!r} was open")
        elapsed = time.perf_counter() - start
        self.seconds[name] += elapsed - children
        self.calls[name] += 1
        if self._stack:
            self._stack[-1][2] += elapsed


class stage:
    """Context manager marking a named stage for the active :class:`StageTimer` (if any)."""

    __slots__ = ("name", "timer")

    def __init__(self, name: str) -> None:
        self.name = name
        self.timer: StageTimer | None = None

    def __enter__(self) -> "stage":
        self.timer = _active
        if self.timer is not None:
            self.timer._push(self.name)
        return self

    def __exit__(self, *exc) -> Literal[False]:
        if self.timer is not None:
            self.timer._pop(self.name)
        return False
