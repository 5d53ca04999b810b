"""Adaptation, measured: how the errors react to a perturbation and whether they come back.

The read-out works on the lines of a run's ``metrics.jsonl`` (`aectorch.runtime.metrics`): a run
with perturbations logs the short window ``<movement>_recent_deg`` (the MAE of the last
``train.recent_window`` fixation ends), ``<movement>_recent_1px`` (the fraction of them within
one pixel) and ``depth_recent_m``; the 1000-fixation window of eq. (9) lags a transient by
hundreds of iterations. For every change (an event's start or end) and each error it gives:

- ``before``: the window before the change (the last line at or before it);
- ``peak`` and ``peak_ratio`` (peak / before) over the stretch to the next change;
- ``iterations_to_recover``: from the change to the first line after the peak within
  ``RECOVERED`` (1.2) times ``before`` (``None``: not within the stretch);
- ``final``: the last line of the stretch;
- for the eye movements: ``within_1px_before``, ``within_1px_min`` and ``iterations_to_95pct``,
  the iterations until 95 % of the window's fixation ends are again within one pixel (counted
  from the change; after the fraction's lowest point; 0 when it never fell below).
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

__all__ = ["RECOVERED", "WITHIN_TARGET", "adaptation", "recovery_of"]

#: A window within this factor of the window before the change counts as recovered.
RECOVERED = 1.2
#: The fraction of fixation ends within one pixel that counts as calibrated again.
WITHIN_TARGET = 0.95


def _value(record: Mapping, key: str) -> float:
    value = record.get(key)
    if value is None or isinstance(value, (bool, str, list, dict)):
        return math.nan
    return float(value)


def recovery_of(records: Sequence[Mapping], key: str, change: int, stop: int, *,
                within_key: str | None = None) -> dict:
    """The read-out of one error ``key`` around one change (see the module).

    Args:
        records: metrics lines with ``iteration`` (iterations done) and ``key``, in order.
        key: the error, larger is worse (e.g. ``vergence_recent_deg``).
        change: the learner iteration (0-based) the change acts from: lines with ``iteration <=
            change`` are before it.
        stop: the end of the stretch (the next change, or the run's end): lines with ``change <
            iteration <= stop``.
        within_key: the fraction within one pixel (``vergence_recent_1px``), for the
            self-calibration numbers.

    Example:
        >>> lines = [{"iteration": i, "e": v} for i, v in zip(range(0, 80, 10), [1, 1, 4, 3, 1.1, 1, 1, 1])]
        >>> r = recovery_of(lines, "e", 10, 70)
        >>> r["before"], r["peak"], r["peak_ratio"], r["iterations_to_recover"], r["final"]
        (1.0, 4.0, 4.0, 30, 1.0)
    """
    before = [r for r in records if r["iteration"] <= change and math.isfinite(_value(r, key))]
    after = [r for r in records if change < r["iteration"] <= stop and math.isfinite(_value(r, key))]
    out: dict = {"key": key, "before": None, "peak": None, "peak_ratio": None, "peak_iteration": None,
                 "iterations_to_recover": None, "final": None}
    if after:
        values = [_value(r, key) for r in after]
        peak = max(range(len(values)), key=values.__getitem__)
        out.update(peak=values[peak], peak_iteration=int(after[peak]["iteration"]), final=values[-1])
        if before:
            base = _value(before[-1], key)
            out["before"] = base
            out["peak_ratio"] = values[peak] / base if base > 0 else None
            recovered = [r for r, v in zip(after[peak + 1:], values[peak + 1:]) if v <= RECOVERED * base]
            if recovered:
                out["iterations_to_recover"] = int(recovered[0]["iteration"]) - change
    if within_key is not None:
        out.update(_calibration(records, within_key, change, stop))
    return out


def _calibration(records: Sequence[Mapping], key: str, change: int, stop: int) -> dict:
    before = [_value(r, key) for r in records if r["iteration"] <= change and math.isfinite(_value(r, key))]
    after = [(int(r["iteration"]), _value(r, key)) for r in records
             if change < r["iteration"] <= stop and math.isfinite(_value(r, key))]
    out = {"within_1px_before": before[-1] if before else None, "within_1px_min": None, "iterations_to_95pct": None}
    if after:
        lowest = min(range(len(after)), key=lambda i: after[i][1])
        out["within_1px_min"] = after[lowest][1]
        if after[lowest][1] >= WITHIN_TARGET:
            out["iterations_to_95pct"] = 0
        else:
            again = [it for it, v in after[lowest + 1:] if v >= WITHIN_TARGET]
            out["iterations_to_95pct"] = again[0] - change if again else None
    return out


def adaptation(records: Sequence[Mapping], changes: Sequence[tuple[int, int, str]]) -> dict[str, dict]:
    """The read-out of every change: ``{label: {movement or "depth": recovery_of(...)}}``.

    Args:
        records: a run's metrics lines (``metrics.jsonl``).
        changes: ``(change, stop, label)``: the iteration a change acts from, the end of its
            stretch, its name.

    The short window's keys are used where the lines have them (``<m>_recent_deg``,
    ``depth_recent_m``), else the long window's (``<m>_mae_deg``, ``depth_mae_m``).
    """
    keys = list(dict.fromkeys(k for r in records for k in r))
    recent = any(k.endswith("_recent_deg") for k in keys)
    suffix = "_recent_deg" if recent else "_mae_deg"
    movements = [k[: -len(suffix)] for k in keys if k.endswith(suffix)]
    out: dict[str, dict] = {}
    for change, stop, label in changes:
        entry = {m: recovery_of(records, f"{m}{suffix}", change, stop,
                                within_key=f"{m}_recent_1px" if recent else None) for m in movements}
        entry["depth"] = recovery_of(records, "depth_recent_m" if recent else "depth_mae_m", change, stop)
        out[label] = {"iteration": change, "stop": stop, **entry}
    return out
