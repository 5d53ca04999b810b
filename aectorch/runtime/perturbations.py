"""Perturbations as data: the experiment's list of events and their schedule.

``perturbations`` in the experiment config is a list of events (:class:`PerturbationEventConfig`):
when each starts (and, optionally, ends), which eye, its kind (a name of
`aectorch.sim.perturbations.PERTURBATIONS`) and its parameters. :func:`resolve_events` checks
them against the run's length and turns them into :class:`Event` s; a :class:`Schedule` says
which act at an iteration and composes their `Optics`, which the training loop's
`aectorch.runtime.loop.Perturbations` callback hands the environment before the iteration runs
(and logs with the metrics). The schedule is a function of the iteration alone, so a resumed run
sees exactly the events the uninterrupted run saw.

Example, the paper's Fig. 4 written out (``+experiment=roll_perturbation`` holds such a list):

    perturbations:
      - {kind: roll, start: 0.5, eye: right, params: {deg: 10}}
      - {kind: roll, start: 0.75, eye: left, params: {deg: 10}}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from aectorch._checks import is_int, is_real
from aectorch.choices import PerturbationKind
from aectorch.sim.perturbations import EYES, NEUTRAL, Optics, Perturbation, make_perturbation

__all__ = ["Event", "PerturbationEventConfig", "Schedule", "resolve_events"]

#: ``eye`` values of an event that acts on an eye.
EVENT_EYES = (*EYES, "both")


@dataclass
class PerturbationEventConfig:
    """One perturbation event of the experiment (an entry of ``perturbations``).

    Attributes:
        kind: the perturbation (`aectorch.sim.perturbations.PERTURBATIONS`): ``roll``,
            ``strabismus``, ``anisometropia``, ``refractive_error``, ``monocular_deprivation``,
            ``aniseikonia``, ``orientation_rearing``, ``camera_shift``, ``vertical_misalignment``.
        start: when it starts: an integer is a learner iteration (0-based: it acts from that
            iteration on), a number with a decimal point in [0, 1] a fraction of
            ``train.iterations`` (rounded down). Before the run's end.
        end: when it ends (it no longer acts from this iteration on), as ``start``; ``null``
            (default): it holds to the end of the run. After ``start``, at most the run's end.
        eye: ``left``, ``right`` or ``both`` for a kind that acts on an eye; ``null`` (default)
            for ``orientation_rearing``, which acts on the world.
        params: the kind's parameters (`aectorch.sim.perturbations`: ``roll: {deg}``,
            ``strabismus: {deg}`` (positive inward), ``anisometropia: {arcmin}`` (blur-disc
            diameter), ``refractive_error: {dioptres}`` (the eye's focus offset, positive myopic;
            needs ``env.aperture_m > 0``), ``monocular_deprivation: {contrast}``, ``aniseikonia: {percent}``,
            ``orientation_rearing: {orientation, bandwidth_deg}``, ``camera_shift: {x_m, y_m,
            z_m}``, ``vertical_misalignment: {deg}`` (positive up)).
        label: the event's name in logs, the summary and the figures (default: eye and kind).
    """

    kind: str = ""
    start: Any = None
    end: Any = None
    eye: Optional[str] = None
    params: dict[str, Any] = field(default_factory=dict)
    label: Optional[str] = None


@dataclass(frozen=True)
class Event:
    """A checked event: it acts on iterations ``start <= i < end`` (``end`` ``None``: to the end).

    Attributes:
        start, end: learner iterations.
        eyes: the eye indices it acts on (0 left, 1 right; ``(None,)`` for the world).
        perturbation: what it does (`aectorch.sim.perturbations.Perturbation`).
        label: its name.
    """

    start: int
    end: Optional[int]
    eyes: tuple
    perturbation: Perturbation
    label: str

    def active(self, iteration: int) -> bool:
        return self.start <= iteration and (self.end is None or iteration < self.end)

    def apply(self, optics: Optics) -> Optics:
        for eye in self.eyes:
            optics = self.perturbation.apply(optics, eye)
        return optics

    def as_dict(self) -> dict:
        """JSON-ready: start, end, label, kind, eyes (names)."""
        return {"start": self.start, "end": self.end, "label": self.label, "kind": str(self.perturbation.kind),
                "eyes": [None if e is None else EYES[e] for e in self.eyes]}


def _iteration(value, name: str, iterations: int) -> int:
    """An event's ``start``/``end``: an iteration (int) or a fraction of the run (float in [0, 1])."""
    if is_int(value):
        if value < 0:
            raise ValueError(f"{name} must be an iteration >= 0 or a fraction in [0, 1], got {value!r}")
        return int(value)
    if is_real(value) and isinstance(value, float):
        if not 0 <= value <= 1:
            raise ValueError(f"{name} must be an iteration (an integer) or a fraction of train.iterations in [0, 1] "
                             f"(a number with a decimal point), got {value!r}")
        return int(value * iterations)
    raise ValueError(f"{name} must be an iteration (an integer) or a fraction of train.iterations in [0, 1], "
                     f"got {value!r}")


def _field(entry, key: str, default=None):
    return entry.get(key, default) if isinstance(entry, dict) else getattr(entry, key, default)


def resolve_events(entries, iterations: int, owner: str = "perturbations") -> list[Event]:
    """The events of ``entries`` (:class:`PerturbationEventConfig` s or dicts) for a run of
    ``iterations``, checked: ``ValueError`` naming the entry's key (``perturbations[2].eye``) for an
    unknown kind, an unknown or impossible parameter, an eye that does not exist or is missing,
    a start at or after the run's end, an end before the start or after the run's end."""
    events = []
    for i, entry in enumerate(entries or []):
        where = f"{owner}[{i}]"
        kind = _field(entry, "kind")
        if not kind:
            raise ValueError(f"{where}.kind is missing: give one of the perturbation kinds "
                             f"({', '.join(PerturbationKind.values())})")
        try:
            perturbation = make_perturbation(kind, dict(_field(entry, "params") or {}))
        except ValueError as err:
            raise ValueError(f"{where}.{err}") from None
        start_value, end_value = _field(entry, "start"), _field(entry, "end")
        if start_value is None:
            raise ValueError(f"{where}.start is missing: the iteration (or fraction of train.iterations) it starts at")
        start = _iteration(start_value, f"{where}.start", iterations)
        if start >= iterations:
            raise ValueError(f"{where}.start={start_value!r} is at or after the run's end (train.iterations="
                             f"{iterations}): the event would never act")
        end = None if end_value is None else _iteration(end_value, f"{where}.end", iterations)
        if end is not None and not start < end <= iterations:
            raise ValueError(f"{where}.end={end_value!r} must come after its start ({start}) and at most at the run's "
                             f"end (train.iterations={iterations})")
        eye = _field(entry, "eye")
        if perturbation.acts_on == "world":
            if eye is not None:
                raise ValueError(f"{where}.eye={eye!r}: {kind} acts on the world, not on an eye; leave eye out (null)")
            eyes: tuple = (None,)
        elif eye is None:
            raise ValueError(f"{where}.eye is missing: {kind} acts on an eye: left, right or both")
        elif str(eye) not in EVENT_EYES:
            raise ValueError(f"{where}.eye={eye!r} is not an eye of the robot: left, right or both")
        else:
            eyes = (0, 1) if str(eye) == "both" else (EYES.index(str(eye)),)
        label = _field(entry, "label") or (perturbation.describe() if eyes == (None,)
                                           else f"{'both eyes' if len(eyes) == 2 else EYES[eyes[0]] + ' eye'}: "
                                                f"{perturbation.describe()}")
        events.append(Event(start, end, eyes, perturbation, str(label)))
    return events


class Schedule:
    """Which events act at an iteration, and the `Optics` they compose to (in their order).

    Example:
        >>> schedule = Schedule(resolve_events([{"kind": "roll", "start": 5, "eye": "right", "params": {"deg": 3}}], 10))
        >>> schedule.optics_at(4).roll_deg, schedule.optics_at(5).roll_deg
        ((0.0, 0.0), (0.0, 3.0))
        >>> schedule.changes
        [5]
    """

    def __init__(self, events: list[Event]) -> None:
        self.events = list(events)
        self._cache: dict[frozenset, Optics] = {}

    def __bool__(self) -> bool:
        return bool(self.events)

    def active(self, iteration: int) -> list[Event]:
        return [e for e in self.events if e.active(iteration)]

    def optics_at(self, iteration: int) -> Optics:
        """The optics of iteration ``iteration``: every event acting then, applied in order."""
        active = self.active(iteration)
        key = frozenset(id(e) for e in active)
        optics = self._cache.get(key)
        if optics is None:
            optics = NEUTRAL
            for event in active:
                optics = event.apply(optics)
            self._cache[key] = optics
        return optics

    @property
    def changes(self) -> list[int]:
        """The iterations at which an event starts or ends, in order."""
        points = {e.start for e in self.events} | {e.end for e in self.events if e.end is not None}
        return sorted(points)

    def starting(self, iteration: int) -> list[Event]:
        return [e for e in self.events if e.start == iteration]

    def ending(self, iteration: int) -> list[Event]:
        return [e for e in self.events if e.end == iteration]

    def stretches(self, total: int) -> list[tuple[int, int]]:
        """``(start, stop)`` of the stretches between changes, from each change to the next (or
        ``total``): what the recovery read-out measures."""
        points = [p for p in self.changes if p < total]
        return [(p, points[i + 1] if i + 1 < len(points) else total) for i, p in enumerate(points)]

