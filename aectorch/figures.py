"""Figures of a training run of the joint learning framework (Wong et al. 2017, Figs. 2-4).

Every plotting function takes plain data (tensors, lists of metric dicts), draws on a
:class:`matplotlib.figure.Figure` that is never attached to pyplot (so no window opens and no
global backend state is touched; the PNG is rendered by Agg), writes the file at ``dpi=120``
with a tight layout, creates the parent folders and returns the :class:`pathlib.Path` written.

- :func:`plot_dictionaries`: Fig. 2, every dictionary on its first two PCs, initial vs trained
  (:func:`aectorch.coding.readouts.principal_components`);
- :func:`plot_training`: Fig. 3, each eye movement's MAE (deg; pursuit, vergence) and depth MAE (m)
  over training;
- :func:`plot_perturbation`: Fig. 4, the same around perturbation events;
- :func:`plot_evaluation`: per-distance breakdown of :func:`aectorch.evaluation.evaluate`;
- :func:`plot_code`: the learned code's read-outs (binocularity, disparity, orientation
  histograms per dictionary, :func:`aectorch.coding.readouts.code_summary`; groups of runs side by
  side: `aectorch.report.code.plot_code_comparison`).

Metric records are dicts with an ``'iteration'`` key (`aectorch.runs.read_metrics` reads a run's); a value that is missing, ``None`` or NaN
is a gap in the curve (the depth error is NaN before the depth MLP's first fit). The eye
movements are the records' ``<movement>_mae_deg`` keys and the cues their ``<cue>/reward`` and
``<cue>/entropy`` keys, each drawn in the colour of its position (:data:`COLORS`: the paper's Fig.
3(a) has pursuit, the first, blue and vergence red).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from torch import Tensor

from aectorch._checks import is_int
from aectorch.coding.readouts import check_atoms, principal_components  # re-exported: its public path before it moved to the read-outs

__all__ = [
    "principal_components",
    "plot_dictionaries",
    "plot_training",
    "plot_perturbation",
    "plot_evaluation",
    "plot_tracking",
    "save_figure",
    "plot_code",
]

DPI = 120
#: The colours of the eye movements (and the cues that drive them), in their order: the paper's
#: Fig. 3(a) draws pursuit blue and vergence red.
COLORS = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange")
DEPTH_COLOR = "black"
EVENT_STYLE = {"color": "grey", "linestyle": ":", "linewidth": 1.5}


# ----------------------------------------------------------------------------------------------
# helpers


def _new_figure(figsize: tuple[float, float]):
    from matplotlib.figure import Figure  # Agg renders it on savefig; pyplot is never used

    return Figure(figsize=figsize, dpi=DPI)


def save_figure(fig, path: str | os.PathLike, dpi: float = DPI) -> Path:
    """Write ``fig`` to ``path`` (its folder made), whole or not at all: a failed write (a full
    disk) leaves the previous figure, not half of one. Raises ``ValueError`` when ``path`` has no
    image suffix."""
    out = Path(path)
    if out.suffix == "":
        raise ValueError(f"path must name a file with an image suffix such as '.png', got {str(path)!r}")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp{out.suffix}")
    try:
        fig.savefig(tmp, dpi=dpi)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


def _save(fig, path: str | os.PathLike) -> Path:
    if Path(path).suffix == "":
        raise ValueError(f"path must name a file with an image suffix such as '.png', got {str(path)!r}")
    # tight_layout leaves the suptitle out of account: keep the top 0.45 inch free for it.
    top = 1.0 if fig._suptitle is None else 1.0 - 0.45 / fig.get_figheight()
    fig.tight_layout(rect=(0.0, 0.0, 1.0, top))
    return save_figure(fig, path)


def _as_float(value: Any) -> float:
    """A metric value as a float; missing, None or non-numeric-NaN gives NaN."""
    if value is None:
        return math.nan
    if isinstance(value, Tensor):
        if value.numel() != 1:
            return math.nan
        value = value.item()
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _check_records(records: Sequence[Mapping], name: str = "records") -> np.ndarray:
    """Validate metric records and return their iterations as a float array."""
    if isinstance(records, (str, bytes)) or not isinstance(records, Sequence):
        raise ValueError(f"{name} must be a sequence of dicts, got {type(records).__name__}")
    if len(records) == 0:
        raise ValueError(f"{name} must not be empty")
    iterations = np.empty(len(records))
    for i, record in enumerate(records):
        if not isinstance(record, Mapping):
            raise ValueError(f"{name}[{i}] must be a dict, got {type(record).__name__}")
        if "iteration" not in record:
            raise ValueError(f"{name}[{i}] has no 'iteration' key (keys: {sorted(record)})")
        it = _as_float(record["iteration"])
        if not math.isfinite(it):
            raise ValueError(f"{name}[{i}]['iteration'] must be a finite number, got {record['iteration']!r}")
        iterations[i] = it
    return iterations


def _series(records: Sequence[Mapping], key: str) -> np.ndarray:
    return np.array([_as_float(r.get(key)) for r in records], dtype=float)


def _check_events(events: Sequence[tuple[int, str]], name: str = "events") -> list[tuple[float, str]]:
    if isinstance(events, (str, bytes)) or not isinstance(events, Sequence):
        raise ValueError(f"{name} must be a sequence of (iteration, label) pairs, got {type(events).__name__}")
    checked = []
    for i, event in enumerate(events):
        if not (isinstance(event, Sequence) and not isinstance(event, (str, bytes)) and len(event) == 2):
            raise ValueError(f"{name}[{i}] must be an (iteration, label) pair, got {event!r}")
        it = _as_float(event[0])
        if not math.isfinite(it) or isinstance(event[0], bool):
            raise ValueError(f"{name}[{i}][0] must be a finite iteration number, got {event[0]!r}")
        checked.append((it, str(event[1])))
    return checked


def _log_if_positive(ax, *arrays: np.ndarray) -> None:
    """Logarithmic y axis when all finite values are positive and span at least a factor of 4.

    Ticks read 0.2, 1, 4 (not 4 x 10^0). Over a smaller span a log axis has too few ticks to read
    (between 0.1 and 0.2 there is none), so the axis stays linear.
    """
    from matplotlib.ticker import LogFormatterSciNotation

    class _PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):  # label the ticks matplotlib would label, in plain numbers
            return f"{x:g}" if super().__call__(x, pos) else ""

    values = np.concatenate([a[np.isfinite(a)] for a in arrays])
    if values.size and bool((values > 0).all()) and values.max() >= 4 * values.min():
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(_PlainLogFormatter())
        ax.yaxis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.5)))


def _curve(ax, x: np.ndarray, y: np.ndarray, **kwargs) -> None:
    """A line with gaps at NaN; isolated finite points (a gap on both sides) still show as dots."""
    finite = np.isfinite(y)
    if not finite.any():
        return
    ax.plot(x, y, **kwargs)
    left = np.concatenate([[False], finite[:-1]])
    right = np.concatenate([finite[1:], [False]])
    isolated = finite & ~left & ~right
    if isolated.any():
        ax.plot(x[isolated], y[isolated], linestyle="none", marker=".", color=kwargs.get("color"))


def _no_data(ax, key_text: str) -> None:
    ax.text(0.5, 0.5, f"no finite values of {key_text}", transform=ax.transAxes,
            ha="center", va="center", color="grey")


def _draw_events(axes, events: list[tuple[float, str]]) -> None:
    for ax_index, ax in enumerate(axes):
        for it, label in events:
            ax.axvline(it, **EVENT_STYLE)
            if ax_index == 0 and label:
                ax.text(it, 0.98, f" {label}", transform=ax.get_xaxis_transform(), rotation=90,
                        ha="right", va="top", color="dimgrey", fontsize=8)


def _keys(records: Sequence[Mapping], suffix: str) -> list[str]:
    """The keys of ``records`` ending in ``suffix``, in their order of appearance."""
    keys: dict[str, None] = {}
    for record in records:
        keys.update((k, None) for k in record if k.endswith(suffix))
    return list(keys)


def _color(index: int) -> str:
    return COLORS[index % len(COLORS)]


def _eye_ylabel(movements: Sequence[str]) -> str:
    """The eye-error axis's label: degrees, and degrees per iteration for a velocity among
    ``movements`` (``pursuit_velocity``, the slip cue's)."""
    velocity = any(m.endswith("velocity") for m in movements)
    return "eye movement MAE (deg" + ("; velocity: deg per iteration)" if velocity else ")")


def _error_panels(ax_eye, ax_depth, x: np.ndarray, records: Sequence[Mapping]) -> None:
    """Panels (a) the eye movements' MAE (deg) and (b) depth MAE (m) over iterations."""
    keys = _keys(records, "_mae_deg")
    eyes = [_series(records, key) for key in keys]
    depth = _series(records, "depth_mae_m")
    for i, (key, y) in enumerate(zip(keys, eyes)):
        _curve(ax_eye, x, y, color=_color(i), label=key[: -len("_mae_deg")])
    if any(np.isfinite(y).any() for y in eyes):
        _log_if_positive(ax_eye, *eyes)
        ax_eye.legend(loc="upper right", fontsize=8)
    else:
        _no_data(ax_eye, " / ".join(repr(k) for k in keys) or "'<movement>_mae_deg'")
    ax_eye.set_ylabel(_eye_ylabel([k[: -len("_mae_deg")] for k in keys]))
    ax_eye.set_title("(a) eye movement error", loc="left", fontsize=10)
    _curve(ax_depth, x, depth, color=DEPTH_COLOR, label="depth")
    if np.isfinite(depth).any():
        _log_if_positive(ax_depth, depth)
    else:
        _no_data(ax_depth, "'depth_mae_m'")
    ax_depth.set_ylabel("depth MAE (m)")
    ax_depth.set_title("(b) depth estimation error", loc="left", fontsize=10)
    for ax in (ax_eye, ax_depth):
        ax.grid(True, which="major", alpha=0.3)


# ----------------------------------------------------------------------------------------------
# Fig. 2: dictionaries


def plot_dictionaries(initial: Mapping[str, Tensor], trained: Mapping[str, Tensor],
                      path: str | os.PathLike) -> Path:
    """Fig. 2: every dictionary's atoms on its first two principal components, initial vs trained.

    One row per key (in the order of ``initial``), two panels: the initial and the trained
    dictionary, each a scatter of its ``N`` atoms' PC1 / PC2 scores (PCA of that dictionary,
    :func:`aectorch.coding.readouts.principal_components`); axis labels give the explained variance in %.

    Args:
        initial: dictionaries before training, ``{key: atoms [P, N]}``, e.g. keys
            ``'parallax/coarse'``, ``'parallax/fine'``, ``'stereo/coarse'``, ``'stereo/fine'``.
        trained: the same keys after training.
        path: the image file to write (``.png``; any matplotlib format suffix works).

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> import torch
        >>> d = {"stereo/coarse": torch.randn(20, 30)}
        >>> out = plot_dictionaries(d, d, Path(tempfile.mkdtemp()) / "fig2.png")
        >>> out.name, out.stat().st_size > 0
        ('fig2.png', True)
    """
    for name, mapping in (("initial", initial), ("trained", trained)):
        if not isinstance(mapping, Mapping):
            raise ValueError(f"{name} must be a mapping {{key: atoms [P, N]}}, got {type(mapping).__name__}")
    if len(initial) == 0:
        raise ValueError("initial must hold at least one dictionary")
    for key in initial:
        if key not in trained:
            raise ValueError(f"trained is missing key {key!r} (initial has {sorted(initial)})")
    for key in trained:
        if key not in initial:
            raise ValueError(f"initial is missing key {key!r} (trained has {sorted(trained)})")
    pcs: dict = {}  # (key, "initial" | "trained") -> NumPy scores and ratio, the atoms' shape
    for key in initial:
        for name, mapping in (("initial", initial), ("trained", trained)):
            atoms = check_atoms(mapping[key], f"{name}[{key!r}]")
            if atoms.shape[0] < 2 or atoms.shape[1] < 2:
                raise ValueError(f"{name}[{key!r}] must be [P, N] with P >= 2 and N >= 2, got {tuple(atoms.shape)}")
            scores, ratio = principal_components(atoms.double().cpu(), k=2)
            pcs[key, name] = (scores.numpy(), ratio.numpy(), atoms.shape)

    rows = len(initial)
    fig = _new_figure((8.0, 3.6 * rows + 0.4))
    axes = fig.subplots(rows, 2, squeeze=False)
    for row, key in enumerate(initial):
        for col, name in enumerate(("initial", "trained")):
            scores, ratio, shape = pcs[key, name]
            ax = axes[row, col]
            ax.scatter(scores[:, 0], scores[:, 1], s=8, alpha=0.7,
                       color="tab:grey" if name == "initial" else "tab:green", edgecolors="none")
            ax.set_xlabel(f"PC1 score ({100 * ratio[0]:.1f} % of variance)")
            ax.set_ylabel(f"PC2 score ({100 * ratio[1]:.1f} % of variance)")
            ax.set_title(f"{key}: {name} ({shape[1]} atoms, dim {shape[0]})", fontsize=10)
            ax.axhline(0, color="lightgrey", linewidth=0.8, zorder=0)
            ax.axvline(0, color="lightgrey", linewidth=0.8, zorder=0)
            ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle("Visual dictionaries on their first two principal components (Fig. 2)")
    return _save(fig, path)


# ----------------------------------------------------------------------------------------------
# metrics and Figs. 3, 4


_EXTRA_PANELS = (("(c) rewards", "reward", "/reward"), ("(d) policy entropies", "entropy (nats)", "/entropy"))


def _cue_keys(records: Sequence[Mapping], suffix: str) -> list[str]:
    """The per-cue keys ``<cue><suffix>`` of ``records`` (``parallax/reward``; not the scales')."""
    return [k for k in _keys(records, suffix) if k.count("/") == 1]


def plot_training(records: Sequence[Mapping], path: str | os.PathLike, *,
                  events: Sequence[tuple[int, str]] = ()) -> Path:
    """Fig. 3: eye movement and depth errors over training.

    Panels (a) each eye movement's MAE in degrees (pursuit blue, vergence red) and (b) depth MAE
    in metres against ``record['iteration']``; a panel's y axis is logarithmic when all its
    finite values are positive. Missing, ``None`` or NaN values are gaps. When the records hold
    per-cue ``'<cue>/reward'`` or ``'<cue>/entropy'`` values, panels (c) rewards and (d) policy
    entropies are added (each cue in the colour of its position).

    Args:
        records: metric dicts, each with ``'iteration'`` and some of ``'<movement>_mae_deg'``
            (``'pursuit_mae_deg'``, ``'vergence_mae_deg'``) and ``'depth_mae_m'``.
        path: the image file to write.
        events: ``(iteration, label)`` pairs drawn as grey dotted vertical lines.

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> records = [{"iteration": i, "pursuit_mae_deg": 1 / (i + 1), "vergence_mae_deg": 2 / (i + 1),
        ...             "depth_mae_m": None if i < 3 else 0.1} for i in range(10)]
        >>> plot_training(records, Path(tempfile.mkdtemp()) / "fig3.png").suffix
        '.png'
    """
    x = _check_records(records)
    checked_events = _check_events(events)
    extra = any(_cue_keys(records, suffix) for _, _, suffix in _EXTRA_PANELS)
    rows = 4 if extra else 2
    fig = _new_figure((8.0, 2.7 * rows + 0.5))
    axes = list(fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0])
    _error_panels(axes[0], axes[1], x, records)
    if extra:
        for ax, (title, ylabel, suffix) in zip(axes[2:], _EXTRA_PANELS):
            drawn = False
            keys = _cue_keys(records, suffix)
            for i, key in enumerate(keys):
                y = _series(records, key)
                if np.isfinite(y).any():
                    _curve(ax, x, y, color=_color(i), label=key)
                    drawn = True
            if drawn:
                ax.legend(loc="best", fontsize=8)
            else:
                _no_data(ax, " / ".join(repr(k) for k in keys) or repr(f"<cue>{suffix}"))
            ax.set_ylabel(ylabel)
            ax.set_title(title, loc="left", fontsize=10)
            ax.grid(True, alpha=0.3)
    _draw_events(axes, checked_events)
    axes[-1].set_xlabel("learner iteration")
    fig.suptitle("Development of eye movements and depth estimation (Fig. 3)")
    return _save(fig, path)


def plot_perturbation(records: Sequence[Mapping], path: str | os.PathLike, *,
                      events: Sequence[tuple[int, str]], margin: int | None = None,
                      readout: Mapping | None = None) -> Path:
    """Fig. 4: eye movement and depth errors around perturbation events.

    Panels (a) and (b) of :func:`plot_training`, restricted to the records with iteration in
    ``[first event - margin, last event + margin]``; the events are grey dotted lines. Records of
    a run with perturbations carry the short window (``<movement>_recent_deg``,
    ``depth_recent_m``, ``<movement>_recent_1px``; `aectorch.runtime.metrics`): then (a) and (b)
    draw it (the long window thin and dashed behind it) and a panel (c) the fraction of fixation
    ends within one pixel, with the 95 % line; ``readout`` (`aectorch.evaluation.adaptation`) marks
    each change's peak (triangle) and recovery within 1.2x (circle).

    Args:
        records: metric dicts as for :func:`plot_training`.
        path: the image file to write.
        events: ``(iteration, label)`` pairs, at least one.
        margin: iterations shown before the first and after the last event; by default the
            distance between the first and the last event, or 20 % of the run's iteration span
            when there is one event (or all events are at one iteration), at least 1, before the
            first, and everything after the last (where the recovery, or its absence, is).
        readout: ``{label: {"iteration": change, movement or "depth": {"peak_iteration", "peak",
            "iterations_to_recover", ...}}}``, or ``None``.

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> records = [{"iteration": i, "pursuit_mae_deg": 1.0, "vergence_mae_deg": 1.0 + (i >= 50),
        ...             "depth_mae_m": 0.1} for i in range(100)]
        >>> out = plot_perturbation(records, Path(tempfile.mkdtemp()) / "fig4.png", events=[(50, "roll")])
        >>> out.exists()
        True
    """
    x = _check_records(records)
    checked_events = _check_events(events)
    if not checked_events:
        raise ValueError("events must hold at least one (iteration, label) pair, got none")
    first = min(it for it, _ in checked_events)
    last = max(it for it, _ in checked_events)
    if margin is None:
        span = last - first if last > first else 0.2 * (float(x.max()) - float(x.min()))
        margin_value = max(span, 1.0)
    else:
        if not (is_int(margin) or isinstance(margin, float)) or not margin >= 0:  # inf keeps all
            raise ValueError(f"margin must be a non-negative number of iterations or None, got {margin!r}")
        margin_value = float(margin)
    low, high = first - margin_value, (max(float(x.max()), last) if margin is None else last + margin_value)
    keep = (x >= low) & (x <= high)
    if not keep.any():
        raise ValueError(f"records has no record with iteration in [{low:g}, {high:g}] "
                         f"(records span [{x.min():g}, {x.max():g}])")
    window = [r for r, k in zip(records, keep) if k]
    if not _keys(window, "_recent_deg"):
        fig = _new_figure((8.0, 5.9))
        ax_eye, ax_depth = fig.subplots(2, 1, sharex=True)
        _error_panels(ax_eye, ax_depth, x[keep], window)
        axes = [ax_eye, ax_depth]
    else:
        fig = _new_figure((8.0, 8.2))
        axes = list(fig.subplots(3, 1, sharex=True))
        _recent_panels(*axes, x[keep], window, readout or {})  # type: ignore[call-arg]  # three axes
    _draw_events(axes, checked_events)
    axes[-1].set_xlim(low, high)
    axes[-1].set_xlabel("learner iteration")
    fig.suptitle("Adaptation to perturbations (Fig. 4)")
    return _save(fig, path)


def _recent_panels(ax_eye, ax_depth, ax_within, x: np.ndarray, records: Sequence[Mapping], readout: Mapping) -> None:
    """Fig. 4's panels from the short window: (a) the movements' and (b) depth's errors (the long
    window thin and dashed), (c) the fraction within one pixel; the read-out's peaks and
    recoveries marked."""
    movements = [k[: -len("_recent_deg")] for k in _keys(records, "_recent_deg")]
    curves = []
    for i, movement in enumerate(movements):
        y = _series(records, f"{movement}_recent_deg")
        curves.append(y)
        _curve(ax_eye, x, y, color=_color(i), label=f"{movement} (recent)")
        _curve(ax_eye, x, _series(records, f"{movement}_mae_deg"), color=_color(i), linewidth=0.8,
               linestyle="--", alpha=0.6, label=f"{movement} (1000-fixation window)")
        _curve(ax_within, x, _series(records, f"{movement}_recent_1px"), color=_color(i), label=movement)
    depth = _series(records, "depth_recent_m")
    _curve(ax_depth, x, depth, color=DEPTH_COLOR, label="depth (recent)")
    _curve(ax_depth, x, _series(records, "depth_mae_m"), color=DEPTH_COLOR, linewidth=0.8, linestyle="--",
           alpha=0.6, label="depth (1000-trial window)")
    for change in readout.values():
        for i, key in enumerate([*movements, "depth"]):
            entry = change.get(key) if isinstance(change, Mapping) else None
            if not isinstance(entry, Mapping) or entry.get("peak_iteration") is None:
                continue
            ax = ax_depth if key == "depth" else ax_eye
            color = DEPTH_COLOR if key == "depth" else _color(i)
            ax.plot([entry["peak_iteration"]], [entry["peak"]], marker="v", color=color, linestyle="none")
            if entry.get("iterations_to_recover") is not None:
                at = change["iteration"] + entry["iterations_to_recover"]
                level = _series([r for r in records if r["iteration"] == at], entry["key"])
                if level.size:
                    ax.plot([at], [level[0]], marker="o", markerfacecolor="none", color=color, linestyle="none")
    if any(np.isfinite(y).any() for y in curves):
        _log_if_positive(ax_eye, *curves)
    ax_eye.legend(loc="upper right", fontsize=7)
    ax_depth.legend(loc="upper right", fontsize=7)
    ax_within.axhline(0.95, color="grey", linewidth=0.8)
    ax_within.set_ylim(0, 1.02)
    ax_within.legend(loc="lower right", fontsize=7)
    ax_eye.set_ylabel(_eye_ylabel(movements))
    ax_depth.set_ylabel("depth MAE (m)")
    ax_within.set_ylabel("within 1 px")
    ax_eye.set_title("(a) eye movement error, last fixation ends (solid)", loc="left", fontsize=10)
    ax_depth.set_title("(b) depth estimation error", loc="left", fontsize=10)
    ax_within.set_title("(c) fixation ends within one pixel", loc="left", fontsize=10)
    for ax in (ax_eye, ax_depth, ax_within):
        ax.grid(True, which="major", alpha=0.3)


def plot_evaluation(result: Mapping, path: str | os.PathLike) -> Path:
    """Per-distance breakdown of an evaluation result (:func:`aectorch.evaluation.evaluate`).

    Two panels: (a) each eye movement's MAE in degrees (pursuit blue, vergence red) and (b) depth
    MAE in metres against the object distance; the title gives the overall errors and the number
    of trials.

    Args:
        result: a mapping with ``'per_distance'`` (a non-empty list of dicts with
            ``'distance_m'``, the movements' ``'<movement>_mae_deg'`` and ``'depth_mae_m'``) and
            the same overall errors and ``'trials'``.
        path: the image file to write.

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> result = {"pursuit_mae_deg": 0.1, "vergence_mae_deg": 0.2, "depth_mae_m": 0.05, "trials": 4,
        ...           "per_distance": [{"distance_m": d, "pursuit_mae_deg": 0.1, "vergence_mae_deg": 0.2,
        ...                             "depth_mae_m": 0.05} for d in (0.5, 1.0)]}
        >>> plot_evaluation(result, Path(tempfile.mkdtemp()) / "eval.png").exists()
        True
    """
    if not isinstance(result, Mapping):
        raise ValueError(f"result must be a mapping (an evaluation result), got {type(result).__name__}")
    eyes = _keys([result], "_mae_deg")
    if not eyes:
        raise ValueError(f"result has no eye movement's error '<movement>_mae_deg' (has {sorted(result)})")
    for key in ("per_distance", "depth_mae_m", "trials"):
        if key not in result:
            raise ValueError(f"result is missing key {key!r} (has {sorted(result)})")
    rows = result["per_distance"]
    if isinstance(rows, (str, bytes, Mapping)) or not isinstance(rows, Sequence) or len(rows) == 0:
        raise ValueError("result['per_distance'] must be a non-empty list of dicts")
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            raise ValueError(f"result['per_distance'][{i}] must be a dict, got {type(row).__name__}")
        if not math.isfinite(_as_float(row.get("distance_m"))):
            raise ValueError(f"result['per_distance'][{i}] needs a finite 'distance_m', got {row.get('distance_m')!r}")
    rows = sorted(rows, key=lambda r: _as_float(r["distance_m"]))
    distance = _series(rows, "distance_m")
    depth = _series(rows, "depth_mae_m")

    fig = _new_figure((9.0, 3.8))
    ax_eye, ax_depth = fig.subplots(1, 2)
    for i, key in enumerate(eyes):
        ax_eye.plot(distance, _series(rows, key), marker="os^vD"[i % 5], color=_color(i),
                    label=key[: -len("_mae_deg")])
    ax_eye.legend(fontsize=8)
    ax_eye.set_ylabel(_eye_ylabel([k[: -len("_mae_deg")] for k in eyes]))
    ax_eye.set_title("(a) eye movement error", loc="left", fontsize=10)
    ax_depth.plot(distance, depth, marker="o", color=DEPTH_COLOR)
    ax_depth.set_ylabel("depth MAE (m)")
    ax_depth.set_title("(b) depth estimation error", loc="left", fontsize=10)
    for ax in (ax_eye, ax_depth):
        ax.set_xlabel("object distance (m)")
        ax.grid(True, alpha=0.3)
        ax.set_ylim(bottom=0)
    overall = ", ".join(f"{key[: -len('_mae_deg')]} {_as_float(result[key]):.3g} deg" for key in eyes)
    fig.suptitle(f"Evaluation: {overall}, depth {_as_float(result['depth_mae_m']):.3g} m MAE "
                 f"({result['trials']} trials)", fontsize=11)
    return _save(fig, path)


def plot_tracking(runs: Sequence[Sequence[Mapping]], path: str | os.PathLike, *, target_deg: float | None = None,
                  title: str = "Tracking a moving object") -> Path:
    """Tracking error against the object's speed (`aectorch.evaluation.tracking_by_speed`), one
    panel per error of each eye movement (``<movement>[_lead|_speed]_tracking_deg``, three panels a
    row): each run's curve (thin) and their mean (thick, with markers).

    Args:
        runs: one list of rows per run (seed), each row ``{"speed_deg": v,
            "<movement>_tracking_deg": e, ...}``.
        path: the image file to write.
        target_deg: draw this error as a dotted line (a target), when given.
        title: the figure's title.

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> rows = [{"speed_deg": v, "pursuit_tracking_deg": 0.1 * v, "vergence_tracking_deg": 0.05} for v in (0, 1, 2)]
        >>> plot_tracking([rows, rows], Path(tempfile.mkdtemp()) / "tracking.png", target_deg=0.2).exists()
        True
    """
    if isinstance(runs, (str, bytes, Mapping)) or not isinstance(runs, Sequence) or not runs:
        raise ValueError("runs must be a non-empty list of runs, each a list of rows of tracking_by_speed")
    checked = [list(rows) for rows in runs]
    keys = _keys(checked[0], "_tracking_deg") if all(isinstance(r, Mapping) for r in checked[0]) else []
    if not keys or any(not rows or not all(isinstance(r, Mapping) and "speed_deg" in r for r in rows)
                       for rows in checked):
        raise ValueError("each run must be a non-empty list of rows with 'speed_deg' and '<movement>_tracking_deg' "
                         "(tracking_by_speed's rows)")
    columns = min(3, len(keys))
    rows_of_panels = -(-len(keys) // columns)
    fig = _new_figure((4.2 * columns, 3.4 * rows_of_panels))
    axes = np.atleast_1d(fig.subplots(rows_of_panels, columns)).reshape(-1)
    for ax in axes[len(keys):]:
        ax.set_visible(False)
    for i, (ax, key) in enumerate(zip(axes, keys)):
        curves = []
        for rows in checked:
            rows = sorted(rows, key=lambda r: _as_float(r["speed_deg"]))
            speed, error = _series(rows, "speed_deg"), _series(rows, key)
            ax.plot(speed, error, color=_color(i), alpha=0.35, linewidth=1)
            curves.append(error)
        if len({len(c) for c in curves}) == 1:
            ax.plot(speed, np.mean(curves, axis=0), color=_color(i), marker="o", linewidth=2,
                    label=f"mean of {len(curves)}")
            ax.legend(fontsize=8)
        if target_deg is not None:
            ax.axhline(target_deg, **EVENT_STYLE)
        ax.set_xlabel("object speed (deg per iteration)")
        name = key[: -len("_tracking_deg")]
        ax.set_ylabel(f"{name} {'(deg per iteration)' if name.endswith('_speed') else '(deg)'}")
        ax.grid(True, alpha=0.3)
        if not name.endswith("_lead"):  # (a lead is signed)
            ax.set_ylim(bottom=0)
    fig.suptitle(title, fontsize=11)
    return _save(fig, path)


# ----------------------------------------------------------------------------------------------
# the learned code's read-outs (aectorch.coding.readouts)

#: The three read-outs of :func:`aectorch.coding.readouts.code_summary`, with their bins' key and
#: the label of their axis.
_READOUTS = (("binocularity", "edges", "binocularity index (R - L) / (R + L)"),
             ("disparity", "disparities_px", "preferred disparity (px of the scale)"),
             ("orientation", "centres_deg", "preferred orientation (deg)"))


def _check_code(code: Any, name: str) -> None:
    if not isinstance(code, Mapping) or not code:
        raise ValueError(f"{name} must be a non-empty mapping {{dictionary: code_summary(atoms)}}, "
                         f"got {type(code).__name__}")
    for key, readout in code.items():
        for part, bins, _ in _READOUTS:
            entry = readout.get(part) if isinstance(readout, Mapping) else None
            if not isinstance(entry, Mapping) or bins not in entry or "counts" not in entry:
                raise ValueError(f"{name}[{key!r}] must be a code_summary result with {part!r}: "
                                 f"{{{bins!r}, 'counts', ...}}")


def _bars(ax, entry: Mapping, bins: str, **style) -> None:
    """One read-out's histogram as bars (binocularity: between its edges; the others: centred)."""
    counts = np.asarray(entry["counts"], dtype=float)
    x = np.asarray(entry[bins], dtype=float)
    if bins == "edges":
        ax.bar(x[:-1], counts, width=np.diff(x), align="edge", **style)
    else:
        width = x[1] - x[0] if len(x) > 1 else 1.0
        ax.bar(x, counts, width=width, **style)


def plot_code(code: Mapping[str, Mapping], path: str | os.PathLike, *,
              initial: Mapping[str, Mapping] | None = None) -> Path:
    """The read-outs of the learned code: one row per dictionary, three histograms.

    Columns: (a) the atoms' binocularity index, -1 left (first image) only, +1 right only; (b)
    their preferred disparity in pixels of the dictionary's scale; (c) their preferred
    orientation (0 horizontal stripes, 90 vertical). Each row's title gives the mean absolute
    binocularity index and the tuning curves' mean depth of modulation. With ``initial``, the
    dictionaries' random start is drawn as a grey outline behind each histogram: the read-out
    of a code that has learned nothing.

    Args:
        code: ``{dictionary: code_summary(atoms)}`` (:func:`aectorch.coding.readouts.code_summary`,
            what a run's ``summary.json`` holds under ``"code"``), e.g. keys ``"stereo/fine"``.
        path: the image file to write.
        initial: the same for the dictionaries' start (``summary.json``'s ``"code_initial"``).

    Returns:
        The path written.

    Example:
        >>> import tempfile
        >>> import torch
        >>> from aectorch.coding.readouts import code_summary
        >>> code = {"stereo/fine": code_summary(torch.randn(200, 64))}
        >>> plot_code(code, Path(tempfile.mkdtemp()) / "code.png").exists()
        True
    """
    _check_code(code, "code")
    if initial is not None:
        _check_code(initial, "initial")
    rows = len(code)
    fig = _new_figure((12.0, 2.5 * rows + 0.5))
    axes = fig.subplots(rows, 3, squeeze=False)
    for row, (name, readout) in enumerate(code.items()):
        for column, (part, bins, label) in enumerate(_READOUTS):
            ax = axes[row, column]
            _bars(ax, readout[part], bins, color=_color(column), alpha=0.8, label="trained")
            if initial is not None and name in initial:
                _bars(ax, initial[name][part], bins, fill=False, edgecolor="dimgrey", linewidth=0.8,
                      label="initial")
            ax.set_xlabel(label, fontsize=8)
            ax.set_ylabel("atoms", fontsize=8)
            ax.tick_params(labelsize=7)
        b, d = readout["binocularity"], readout["disparity"]
        axes[row, 0].set_title(f"{name}: mean |index| {_as_float(b.get('mean_abs_index')):.3f}", loc="left",
                               fontsize=9)
        axes[row, 1].set_title(f"{name}: mean modulation {_as_float(d.get('mean_modulation')):.3f}", loc="left",
                               fontsize=9)
        axes[row, 2].set_title(f"{name}: mean selectivity "
                               f"{_as_float(readout['orientation'].get('mean_selectivity')):.3f}", loc="left",
                               fontsize=9)
        axes[row, 2].set_xticks(np.asarray(readout["orientation"]["centres_deg"], dtype=float)[::2])
    if initial is not None:
        axes[0, 0].legend(fontsize=7)
    fig.suptitle("The learned code: binocularity, disparity and orientation of each atom")
    return _save(fig, path)
