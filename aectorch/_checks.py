"""Input checks and choice types shared by every subpackage: the one place a value is checked.

Each check returns the (normalised) value or raises ``ValueError`` naming the argument and what
was expected, e.g. ``num_envs must be an int >= 1, got 0``. Config dataclasses pass dotted
names (``env.num_envs``), so the message points at the command-line key.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import Any, Sequence, TypeVar

import torch

__all__ = ["check_bool", "check_choice", "check_device", "check_distances", "check_range", "check_finite",
           "check_int", "check_real", "is_int", "is_real"]

E = TypeVar("E", bound=Enum)


def is_int(value: object) -> bool:
    """An int that is not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_real(value: object) -> bool:
    """A finite int or float that is not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_finite(tensor: torch.Tensor, name: str) -> None:
    """Raise ``ValueError`` naming ``name`` when ``tensor`` holds NaN or inf.

    One pass over the data and a host sync: call it at public boundaries, optionally; it is
    skipped while ``torch.compile`` traces.
    """
    if torch.compiler.is_compiling():
        return
    if not bool(torch.isfinite(tensor).all()):
        raise ValueError(f"{name} contains non-finite values (NaN or inf)")


def check_int(value, name: str, minimum: int = 1) -> int:
    """Return ``value`` if it is an int (not a bool) >= ``minimum``, else raise ``ValueError`` naming ``name``.

    Example:
        >>> check_int(True, "env.num_envs")
        Traceback (most recent call last):
        ...
        ValueError: env.num_envs must be an int >= 1, got True
    """
    if not is_int(value) or value < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")
    return value


def check_bool(value, name: str) -> bool:
    """Return ``value`` if it is a bool, else raise ``ValueError`` naming ``name``."""
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}")
    return value


def check_real(value, name: str, *, minimum: float | None = None, above: float | None = None,
               unit: str = "") -> float:
    """Return ``value`` if it is a finite number (>= ``minimum``, > ``above`` when given), else
    raise ``ValueError`` naming ``name`` (``unit``, e.g. ``"metres"``, is added to the message)."""
    ok = is_real(value) and (minimum is None or value >= minimum) and (above is None or value > above)
    if not ok:
        bound = f" >= {minimum}" if minimum is not None else f" > {above}" if above is not None else ""
        raise ValueError(f"{name} must be a finite number{bound}{f' ({unit})' if unit else ''}, got {value!r}")
    return value


def check_choice(value: Any, name: str, choices: type[E]) -> E:
    """The member of the enum ``choices`` (e.g. one of `aectorch.choices`) whose value is ``value``
    (a member or its value), else ``ValueError`` naming ``name`` and the choices.

    Example:
        >>> from aectorch.choices import RendererName
        >>> check_choice("pyrender", "env.renderer", RendererName) is RendererName.pyrender
        True
        >>> check_choice("opengl", "env.renderer", RendererName)
        Traceback (most recent call last):
        ...
        ValueError: env.renderer must be one of 'torch', 'pyrender', got 'opengl'
    """
    try:
        return choices(value)
    except ValueError:
        names = ", ".join(repr(str(member.value)) for member in choices)
        raise ValueError(f"{name} must be one of {names}, got {value!r}") from None


def check_range(value, name: str, *, unit: str = "") -> tuple[float, float]:
    """A ``(low, high)`` pair of finite numbers with low <= high, as floats, else ``ValueError``
    naming ``name`` (``unit``, e.g. ``"degrees per iteration"``, is added to the message).

    Example:
        >>> check_range([-1, 1], "env.object_speed_deg")
        (-1.0, 1.0)
    """
    try:
        low, high = value
        ok = is_real(low) and is_real(high) and low <= high
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be a (low, high) pair of finite numbers with low <= high"
                         f"{f' ({unit})' if unit else ''}, got {value!r}")
    return float(low), float(high)


def check_distances(value: Sequence[float], name: str) -> list[float]:
    """A non-empty list of finite distances > 0 (metres), as floats, else ``ValueError`` naming ``name``."""
    try:
        distances = [float(d) for d in value]
    except (TypeError, ValueError):
        distances = []
    if not distances or any(not math.isfinite(d) or d <= 0 for d in distances) \
            or any(isinstance(d, bool) for d in value):
        raise ValueError(f"{name} must be a non-empty list of distances > 0 (metres), got {value!r}")
    return distances


def check_device(value, name: str) -> torch.device:
    """``torch.device(value)``, else ``ValueError`` naming ``name``."""
    try:
        return torch.device(value)
    except (RuntimeError, TypeError) as err:
        raise ValueError(f"{name} must be a torch device string such as 'cpu' or 'cuda', got {value!r}") from err
