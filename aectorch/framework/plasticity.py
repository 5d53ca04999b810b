"""When each cue learns: a closing plasticity, and its reopening when the coding reward falls.

A cue with ``learn_until=N`` (`CueConfig`) learns nothing from training iteration N on: its
dictionaries, its agent and the agent's feature statistics stay as they are while its eye
movement goes on acting. That keeps what it learned for as long as the run goes on
(experiments/long_training/README.md), and it would also keep a robot from re-learning after its
plant changes. With ``reopen_drop`` set the closed cue watches its own coding reward (R =
-(e^C + e^F), the mean over the environments, which the robot computes itself; no error against a
true optimum): the mean over the first ``reopen_window`` iterations after it closes is its level;
from then on, when the mean over the last ``reopen_window`` iterations falls below that level by
more than ``reopen_drop`` of its size, the cue learns again for ``reopen_for`` iterations, then
closes and takes its level again. A change of the plant that the closed code no longer explains
(a roll, a vertical misalignment) lowers the reward by tens of per cent; the reward's own drift
over 24,000 closed iterations stays within a few per cent (the study's measurements).

`Plasticity` holds this schedule's state (plain numbers, saved in every checkpoint beside the
learner's: `aectorch.runtime.loop`); `aectorch.framework.JointLearner.closed_cues` asks it, and
the training loop shows it each iteration's rewards (`Plasticity.observe`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Mapping

__all__ = ["Plasticity", "Reopening"]


@dataclass
class Reopening:
    """One reopening of a closed cue: at ``iteration`` its mean reward over the window, ``level``,
    had fallen below the ``baseline`` it closed with; it learns until ``until``."""

    cue: str
    iteration: int
    baseline: float
    level: float
    until: int

    def message(self) -> str:
        drop = (self.baseline - self.level) / abs(self.baseline) if self.baseline else float("inf")
        return (f"{self.cue}: the coding reward fell {100 * drop:.0f} % below its level since the cue closed "
                f"({self.baseline:.3f} -> {self.level:.3f}); it learns again from iteration {self.iteration + 1} "
                f"to {self.until}")


@dataclass
class _CueState:
    closed_at: int | None = None  # the iteration the cue last closed at (None while it learns)
    open_until: int | None = None  # learning again until this iteration (a reopening)
    baseline: float | None = None  # the mean reward over the window after the last closing
    window: deque = field(default_factory=deque)  # the last rewards since closing (per iteration, mean over B)


class Plasticity:
    """The closing and reopening schedule of every cue of a learner.

    Args:
        cues: ``{cue: CueConfig}``; the cues without ``learn_until`` always learn.
    """

    def __init__(self, cues: Mapping) -> None:
        self.cues = dict(cues)
        self.states: dict[str, _CueState] = {}
        self.reopenings: list[Reopening] = []

    @property
    def configs(self) -> dict:
        """The configs of the cues that close (``learn_until`` set), by name (read when asked, so a
        config changed in place counts)."""
        return {name: config for name, config in self.cues.items() if config.learn_until is not None}

    def _state(self, name: str) -> _CueState:
        return self.states.setdefault(name, _CueState())

    def closed(self, iteration: int) -> tuple[str, ...]:
        """The cues that learn nothing at training iteration ``iteration`` (0-based)."""
        out = []
        for name, config in self.configs.items():
            state = self._state(name)
            if iteration < config.learn_until:
                continue
            if state.open_until is not None and iteration < state.open_until:
                continue
            out.append(name)
        return tuple(out)

    def observe(self, iteration: int, rewards: Mapping[str, float]) -> list[Reopening]:
        """Take iteration ``iteration``'s mean coding reward of each cue (``{cue: R}``, after the
        iteration ran; cues not given are skipped) and return the cues that reopen from the next
        iteration on."""
        closed = set(self.closed(iteration))
        out = []
        for name, config in self.configs.items():
            if name not in rewards:
                continue
            state = self._state(name)
            if name not in closed:
                state.closed_at = None
                continue
            if state.closed_at is None:  # closing now: a new level to take
                state.closed_at, state.baseline = iteration, None
                state.window = deque(maxlen=config.reopen_window)
            if config.reopen_drop is None:
                continue
            state.window.append(float(rewards[name]))
            if len(state.window) < config.reopen_window:
                continue
            level = sum(state.window) / len(state.window)
            if state.baseline is None:
                state.baseline = level
                continue
            if level < state.baseline - config.reopen_drop * abs(state.baseline):
                state.open_until = iteration + 1 + config.reopen_for
                event = Reopening(name, iteration, state.baseline, level, state.open_until)
                self.reopenings.append(event)
                out.append(event)
        return out

    def state_dict(self) -> dict:
        return {"states": {name: {"closed_at": s.closed_at, "open_until": s.open_until, "baseline": s.baseline,
                                  "window": list(s.window)} for name, s in self.states.items()},
                "reopenings": [vars(r).copy() for r in self.reopenings]}

    def load_state_dict(self, state: dict) -> None:
        for name, saved in state.get("states", {}).items():
            if name in self.cues:
                self.states[name] = _CueState(saved["closed_at"], saved["open_until"], saved["baseline"],
                                              deque(saved["window"], maxlen=self.cues[name].reopen_window))
        self.reopenings = [Reopening(**r) for r in state.get("reopenings", [])]
