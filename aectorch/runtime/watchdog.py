"""A watchdog for long training runs: non-finite values and divergence, caught when they happen.

`Watchdog.check` runs after every learner iteration of `aectorch.runtime.run_experiment`
and looks for

- **non-finite values** in the iteration's rewards, reconstruction errors, TD errors and policy
  entropies, and in every floating-point parameter and buffer of the learner (dictionaries,
  actor and critic weights, the depth MLP and its stored trials): a sum per tensor and one host
  sync per iteration;
- **a TD error exploding**: a cue's mean |TD error| in one iteration above
  ``td_error_max``;
- **the policy entropy collapsing early**: a cue's policy entropy, averaged over the environments
  and over windows of ``entropy_window`` iterations, below ``entropy_min_nats`` within the first
  ``entropy_grace_iterations`` iterations of the run (later, a near-deterministic policy is what
  learning is for). The average matters: in a default run the pursuit policy is already
  deterministic in every environment at the first iteration of a trial (iteration 661: mean
  entropy 0.00015 nats) while its 25-iteration average is still about 1.5 nats;
- **dead atoms**: more than ``dead_atoms_max_fraction`` of a dictionary's atoms never chosen in a
  window of ``dead_atoms_window`` iterations.

With ``mode="stop"`` the first problem raises `WatchdogError`; the run's interruption handler
then writes the checkpoint of the last iteration that passed (so the fault is not in it) and the
message says how to resume. With ``mode="warn"`` each kind of problem is reported once as a
`RuntimeWarning` and the run goes on; ``mode="off"`` skips the checks.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from torch import nn

from aectorch._checks import check_choice, check_int, is_real
from aectorch.choices import WatchdogMode

__all__ = ["WATCHDOG_MODES", "Watchdog", "WatchdogConfig", "WatchdogError"]

WATCHDOG_MODES = WatchdogMode.values()


class WatchdogError(RuntimeError):
    """A training run found unhealthy by the `Watchdog` (``mode="stop"``)."""


@dataclass
class WatchdogConfig:
    """What the watchdog checks after every iteration, and what it does about a problem.

    Attributes:
        mode: ``"stop"`` (raise `WatchdogError`; ``checkpoint.pt`` keeps the last checkpoint
            written, which the watchdog had passed), ``"warn"`` (a warning per kind of problem, the run goes on) or ``"off"``.
        td_error_max: a cue's mean |TD error| over the environments above this (> 0) is a
            diverging critic. The coding rewards are O(1), so are healthy TD errors.
        entropy_min_nats: a cue's mean policy entropy below this (>= 0) ...
        entropy_grace_iterations: ... within this many first iterations of the run (>= 0; five
            trials by default) is an early collapse of exploration. A count, not a fraction of
            ``train.iterations``, so that a long run does not call its learned policy a collapse.
        entropy_window: iterations (>= 1) the entropy is averaged over before it is compared (a
            default run's pursuit policy is deterministic at a trial's first iteration, while its
            25-iteration average is about 1.5 nats).
        dead_atoms_window: iterations (>= 1) over which atom selections are counted.
        dead_atoms_max_fraction: more than this fraction ((0, 1]) of a dictionary's atoms chosen
            never in a window means the dictionary is dying.
    """

    mode: WatchdogMode = WatchdogMode.stop
    td_error_max: float = 100.0
    entropy_min_nats: float = 1e-3
    entropy_grace_iterations: int = 300
    entropy_window: int = 25
    dead_atoms_window: int = 500
    dead_atoms_max_fraction: float = 0.5

    def __post_init__(self) -> None:
        owner = "watchdog"
        self.mode = check_choice(self.mode, f"{owner}.mode", WatchdogMode)
        checks = (
            ("td_error_max", lambda v: v > 0, "a number > 0"),
            ("entropy_min_nats", lambda v: v >= 0, "a number >= 0"),
            ("dead_atoms_max_fraction", lambda v: 0 < v <= 1, "a number in (0, 1]"),
        )
        for name, ok, expected in checks:
            value = getattr(self, name)
            if not is_real(value) or not ok(value):
                raise ValueError(f"{owner}.{name} must be {expected}, got {value!r}")
        for name, minimum in (("dead_atoms_window", 1), ("entropy_grace_iterations", 0), ("entropy_window", 1)):
            check_int(getattr(self, name), f"{owner}.{name}", minimum)


def _all_finite(tensors: list[torch.Tensor]) -> list[bool]:
    """Whether each tensor's values are all finite, with one host sync (two when some sum is not finite).

    A tensor's sum is finite when all its values are (a NaN or an infinity makes it NaN or
    infinite); the converse fails only where finite values overflow, so those tensors are checked
    element by element. A sum reads each value once; ``isfinite().all()`` writes a mask and reduces
    it, several times slower on a default learner's state. The sums are stacked (promoted to a
    common dtype, which keeps an infinity or a NaN as it is) and checked in one operation, not each
    on its own (a default learner's 32 state tensors: 0.258 instead of 0.569 ms per check,
    measured by ``benchmarks/loop_ops.py`` of commit c196118).
    """
    device = tensors[0].device
    finite = torch.stack([t.detach().sum().to(device) for t in tensors]).isfinite().tolist()
    return [ok or bool(t.detach().isfinite().all()) for ok, t in zip(finite, tensors)]


class Watchdog:
    """Checks a `JointLearner` and its `IterationRecord` after every iteration (see the module).

    Args:
        config: `WatchdogConfig`.

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> from aectorch.sim import ActiveDepthEnv, TextureBank
        >>> from aectorch.runtime.watchdog import Watchdog, WatchdogConfig
        >>> env = ActiveDepthEnv(2, textures=TextureBank.procedural(4, size=(64, 64), seed=0), seed=0)
        >>> learner = JointLearner(LearnerConfig(), generator=torch.Generator().manual_seed(0))
        >>> dog = Watchdog(WatchdogConfig())
        >>> dog.check(1, learner.iteration(env), learner)
        []
    """

    def __init__(self, config: WatchdogConfig) -> None:
        self.config = config
        self.warned: set[str] = set()
        self._counts: dict[str, torch.Tensor] = {}
        self._window_start = 0
        self._entropy: dict[str, float] = {}  # sums of the per-iteration mean entropies in a window
        self._entropy_start = 0

    def _state_tensors(self, learner: nn.Module) -> list[tuple[str, torch.Tensor]]:
        # Named as the checkpoint names them, parameters first, then buffers.
        named = list(learner.named_parameters()) + list(learner.named_buffers())
        return [(name, t) for name, t in named if t.is_floating_point() and t.numel() > 0]

    def check(self, iteration: int, record, learner: nn.Module) -> list[str]:
        """The problems after completed iteration ``iteration`` (1-based); raises in ``stop`` mode.

        Returns:
            One message per problem found (empty when healthy, or when ``mode="off"``).
        """
        cfg = self.config
        if cfg.mode == "off":
            return []
        cues = record.cues
        named: list[tuple[str, torch.Tensor]] = []
        for cue, c in cues.items():
            named += [(f"{cue} reward", c.reward), (f"{cue} reconstruction error", c.errors),
                      (f"{cue} policy entropy", c.entropy)]
            if c.td_error is not None:
                named.append((f"{cue} TD error", c.td_error))
        named += [(f"learner.{name}", t) for name, t in self._state_tensors(learner)]
        finite = _all_finite([t for _, t in named])
        problems = [("nonfinite", f"non-finite values (NaN or inf) in {name} at iteration {iteration}")
                    for (name, _), ok in zip(named, finite) if not ok]
        if not problems:
            problems += self._divergence(iteration, cues)
        messages = [text for _, text in problems]
        if not problems:
            return messages
        if cfg.mode == "stop":
            raise WatchdogError(f"watchdog: {messages[0]}" + (
                f" (and {len(messages) - 1} more problem(s))" if len(messages) > 1 else ""))
        for kind, text in problems:
            if kind not in self.warned:
                self.warned.add(kind)
                warnings.warn(f"watchdog: {text} (reported once; watchdog.mode=warn)", RuntimeWarning,
                              stacklevel=2)
        return messages

    def _divergence(self, iteration: int, cues: dict) -> list[tuple[str, str]]:
        cfg = self.config
        out = []
        for cue, c in cues.items():
            if c.td_error is not None:
                td = float(c.td_error.detach().abs().double().mean())
                if td > cfg.td_error_max:
                    out.append(("td_error", f"{cue} mean |TD error| {td:.4g} > watchdog.td_error_max "
                                            f"{cfg.td_error_max:g} at iteration {iteration}: the critic diverges"))
            if iteration <= cfg.entropy_grace_iterations:
                self._entropy[cue] = self._entropy.get(cue, 0.0) + float(c.entropy.detach().double().mean())
            counts = c.atom_counts.detach().cpu()
            self._counts[cue] = counts if cue not in self._counts else self._counts[cue] + counts
        if self._entropy and (iteration - self._entropy_start >= cfg.entropy_window
                              or iteration == cfg.entropy_grace_iterations):
            span = iteration - self._entropy_start
            for cue, total in self._entropy.items():
                entropy = total / span
                if entropy < cfg.entropy_min_nats:
                    out.append(("entropy", f"{cue} policy entropy {entropy:.3g} nats (mean of iterations "
                                           f"{self._entropy_start + 1}-{iteration}) < watchdog.entropy_min_nats "
                                           f"{cfg.entropy_min_nats:g}, within the first {cfg.entropy_grace_iterations} "
                                           "iterations (watchdog.entropy_grace_iterations): exploration collapsed"))
            self._entropy, self._entropy_start = {}, iteration
        if iteration - self._window_start >= cfg.dead_atoms_window:
            for cue, counts in self._counts.items():
                for scale, row in enumerate(counts):
                    dead = float((row == 0).double().mean())
                    if dead > cfg.dead_atoms_max_fraction:
                        out.append(("dead_atoms", f"{cue} dictionary (scale {scale}): {dead:.0%} of the atoms "
                                                  f"never chosen in iterations {self._window_start + 1}-{iteration} "
                                                  f"> watchdog.dead_atoms_max_fraction "
                                                  f"{cfg.dead_atoms_max_fraction:g}"))
            self._counts, self._window_start = {}, iteration
        return out

    def state_dict(self) -> dict:
        """What a resumed run needs to check exactly as an uninterrupted one would."""
        return {"warned": sorted(self.warned), "counts": {k: v.clone() for k, v in self._counts.items()},
                "window_start": self._window_start, "entropy": dict(self._entropy),
                "entropy_start": self._entropy_start}

    def load_state_dict(self, state: dict) -> None:
        self.warned = set(state["warned"])
        self._counts = {k: v.clone() for k, v in state["counts"].items()}
        self._window_start = int(state["window_start"])
        self._entropy = dict(state.get("entropy", {}))
        self._entropy_start = int(state.get("entropy_start", 0))
