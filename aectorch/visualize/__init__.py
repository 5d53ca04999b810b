"""Watch one trial of a trained learner: both eyes' views, their difference and the errors.

:func:`record_trial` runs one frozen trial (a leftward and a rightward fixation of ``h``
iterations each, the protocol of :func:`aectorch.evaluation.run_trials`) of a
:class:`~aectorch.framework.JointLearner` on one texture at one distance and keeps, per
iteration, the image pair one cue's policy saw (by default the last cue's: the stereo pair the
vergence policy saw, the left eye after the pursuit step and the right eye before the vergence
step, as 128 px crops) and every eye movement's error after the iteration. :func:`animate_trial`
draws them as a GIF (or an MP4 when ffmpeg is installed), one frame per iteration: the two views,
their difference, and the error curves so far.

From the command line, on a checkpoint written by ``train.py`` (see ``python -m aectorch.visualize --help``)::

    python -m aectorch.visualize checkpoint=outputs/run/checkpoint.pt out=trial.gif distance=1.5
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from aectorch._checks import check_choice, check_int, check_real
from aectorch.choices import Policy
from aectorch.evaluation import frozen_iterations
from aectorch.figures import COLORS
from aectorch.sim import WINDOW, ActiveDepthEnv, TextureBank, TrialProtocol, resolve_protocol

__all__ = ["TrialFrames", "animate_trial", "check_output", "frame_steps", "record_trial"]

log = logging.getLogger("aectorch")

#: Output formats of :func:`animate_trial`, by file suffix.
FORMATS = (".gif", ".mp4")
FIXATION_NAMES = ("leftward", "rightward")


@dataclass(frozen=True)
class TrialFrames:
    """One trial as CPU tensors, ``T = 2 h`` iterations (``h`` per fixation).

    Attributes:
        first, second: ``[T, H, W]`` the image pair the watched cue's policy saw at each
            iteration (float32 in [0, 1]; for the stereo cue the left and the right eye).
        errors_deg: ``{movement: [T]}`` each eye movement's signed error after each iteration (eq. 9).
        fixation_end: ``[T]`` bool, True at the last iteration of each fixation.
        fixation: ``[T]`` 0 during the leftward fixation, 1 during the rightward one.
        depth_prediction_m: the depth MLP's estimate at the trial's end (NaN before its first fit).
        distance_m: the true distance.
        texture_name: the texture's name, for titles.
        degrees_per_pixel: the camera's angular pixel size (one pixel of error, for the plot).
        cue: the cue whose pair ``first`` and ``second`` are.
        names: the two images' names (`aectorch.sim.Movement.images`), for titles.
    """

    first: Tensor
    second: Tensor
    errors_deg: dict
    fixation_end: Tensor
    fixation: Tensor
    depth_prediction_m: float
    distance_m: float
    texture_name: str = ""
    degrees_per_pixel: float = math.nan
    cue: str = ""
    names: tuple = ("first", "second")

    def __len__(self) -> int:
        return int(self.first.shape[0])


def _check_record_arguments(texture, distance_m, policy: str) -> float:
    if not isinstance(texture, Tensor) or texture.dim() != 2 or not texture.is_floating_point():
        raise ValueError(f"texture must be a floating [H, W] tensor in [0, 1], got "
                         f"{type(texture).__name__} {tuple(getattr(texture, 'shape', ()))}")
    check_choice(policy, "policy", Policy)
    return float(check_real(distance_m, "distance_m", above=0, unit="metres"))


def _environment(texture: Tensor, name: str, distance: float, seed: int, device, dtype,
                 protocol: TrialProtocol) -> ActiveDepthEnv:
    bank = TextureBank(texture[None].detach().cpu(), [name], source="record_trial")
    try:
        return ActiveDepthEnv(1, protocol=protocol, textures=bank, distances_m=[distance], seed=seed,
                              device=device, dtype=dtype)
    except ValueError as err:
        if str(err).startswith("distances_m"):  # beyond the background plane
            raise ValueError(f"distance_m: {err}") from err
        raise


def _run(learner, env: ActiveDepthEnv, distance: float, greedy: bool, cue: str) -> tuple[list[Tensor], list]:
    """One trial of ``env``'s single texture at ``distance``: ``cue``'s pairs seen and the records."""
    pairs: list[Tensor] = []

    def watch(name: str, observation: dict) -> None:
        if name == cue:
            pairs.append(observation[WINDOW][0].detach().to(device="cpu", dtype=torch.float32).clone())

    env.set_trial(torch.zeros(1, dtype=torch.long, device=env.device),
                  torch.full((1,), distance, dtype=env.dtype, device=env.device))
    records = list(frozen_iterations(learner, env, greedy=greedy, watch=watch))
    return pairs, records


def record_trial(learner, texture: Tensor, distance_m: float, *, protocol: TrialProtocol | None = None,
                 policy: str = "greedy", seed: int = 0,
                 texture_name: str = "texture", cue: str | None = None) -> TrialFrames:
    """Run one frozen trial of ``learner`` on ``texture`` at ``distance_m`` and keep what it saw.

    The trial is the one :func:`aectorch.evaluation.run_trials` runs for this texture and distance
    with the same protocol and ``seed`` (a leftward then a rightward fixation from the standard
    start state; the errors are identical): learning is frozen, and the learner's generator
    (sampled actions) is seeded from ``seed`` for the trial and then given its own state back.

    Args:
        learner: a :class:`~aectorch.framework.JointLearner` (not modified).
        texture: the object's texture, a floating ``[H, W]`` tensor in [0, 1].
        distance_m: the object's distance, metres.
        protocol: the trial protocol (`aectorch.sim.TrialProtocol`, default its defaults); a
            learner is watched under the protocol it trained in (``EnvConfig.protocol`` of its run's
            config).
        policy: ``"greedy"`` (the argmax action) or ``"sampled"`` (as in training).
        seed: seeds the environment and, with ``policy="sampled"``, the actions.
        texture_name: a name for titles.
        cue: the cue whose image pair is kept (default: the learner's last, in the environment's
            order: the stereo pair of the vergence policy).

    Returns:
        :class:`TrialFrames` of ``2 * fixation_iterations`` iterations.
    """
    distance = _check_record_arguments(texture, distance_m, policy)
    protocol = resolve_protocol(protocol)
    parameter = next(learner.parameters())
    env = _environment(texture, texture_name, distance, seed, parameter.device, parameter.dtype, protocol)
    learned = [name for name in env.CUES if name in learner.cues]
    if cue is None:
        cue = learned[-1]
    elif cue not in learned:
        env.close()
        raise ValueError(f"cue must be one of the learner's cues {learned}, got {cue!r}")
    saved_generator = learner.generator.get_state()
    saved_previous = {name: c.previous for name, c in learner.cues.items()}  # the pending transitions
    learner.generator.manual_seed(seed)
    try:
        pairs, records = _run(learner, env, distance, policy == "greedy", cue)
    finally:
        learner.generator.set_state(saved_generator)
        for name, previous in saved_previous.items():
            learner.cues[name].previous = previous
        env.close()
    frames = _frames(pairs, records, texture_name, env.camera.degrees_per_pixel, cue, env.cue(cue).images)
    final = ", ".join(f"{m} {float(e[-1]):+.4f} deg" for m, e in frames.errors_deg.items())
    log.info("trial of %d iterations on %s at %.3f m: final errors %s, depth estimate %.4f m", len(frames),
             texture_name, distance, final, frames.depth_prediction_m)
    return frames


def _frames(pairs: list[Tensor], records: list, name: str, degrees_per_pixel: float, cue: str,
            names: tuple[str, str]) -> TrialFrames:
    pair = torch.stack(pairs)  # [T, 2, H, W]
    fixation_end = torch.tensor([bool(r.fixation_end) for r in records])
    last = records[-1]
    return TrialFrames(
        first=pair[:, 0], second=pair[:, 1],
        errors_deg={m: torch.cat([r.errors_deg[m].detach().cpu() for r in records]) for m in last.errors_deg},
        fixation_end=fixation_end,
        fixation=torch.cumsum(fixation_end.long(), 0) - fixation_end.long(),
        depth_prediction_m=float(last.depth_prediction_m[0]),
        distance_m=float(last.distance_m[0]),
        texture_name=name,
        degrees_per_pixel=float(degrees_per_pixel),
        cue=cue,
        names=tuple(names),
    )


# -- the animation ---------------------------------------------------------------------------------
def check_output(out: str | os.PathLike) -> Path:
    """``out`` as a path :func:`animate_trial` can write: ``ValueError`` naming ``out`` for another
    suffix than .gif or .mp4, an .mp4 without ffmpeg, or a missing folder."""
    path = Path(out)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"out must end in {' or '.join(FORMATS)}, got {str(out)!r}")
    if suffix == ".mp4":
        from matplotlib.animation import FFMpegWriter

        if not FFMpegWriter.isAvailable():
            raise ValueError(f"out: writing {path.name} needs ffmpeg, which is missing "
                             "(install ffmpeg, or write a .gif)")
    if not path.resolve().parent.is_dir():
        raise ValueError(f"out: no such folder {str(path.parent)!r}")
    return path


def _writer(path: Path, fps: int):
    from matplotlib.animation import FFMpegWriter, PillowWriter

    return PillowWriter(fps=fps) if path.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)


def _limits(values: list, band: float) -> tuple[float, float]:
    lo, hi = min(min(float(v.min()) for v in values), -band), max(max(float(v.max()) for v in values), band)
    pad = 0.08 * (hi - lo) if hi > lo else 0.1
    return lo - pad, hi + pad


def _error_axes(ax, frames: TrialFrames):
    """The error plot with the whole trial's limits, the fixation boundary and the one-pixel band;
    returns the movements' lines (empty) and the x values."""
    import numpy as np

    x = np.arange(1, len(frames) + 1)
    band = frames.degrees_per_pixel if math.isfinite(frames.degrees_per_pixel) else 0.0
    ax.set_xlim(0.5, len(frames) + 0.5)
    ax.set_ylim(*_limits(list(frames.errors_deg.values()), band))
    ax.axhline(0.0, color="grey", linewidth=0.8)
    if band > 0:
        ax.axhspan(-band, band, color="0.9", zorder=0, label="±1 pixel")
    ends = x[frames.fixation_end.numpy()]
    starts = np.concatenate(([0], ends[:-1]))
    for start, end, name in zip(starts, ends, FIXATION_NAMES):
        if start > 0:
            ax.axvline(start + 0.5, color="black", linestyle="--", linewidth=1.0)
        ax.text((start + end + 1) / 2, 0.96, f"{name} fixation", transform=ax.get_xaxis_transform(),
                ha="center", va="top", fontsize=8, color="0.3")
    lines = [ax.plot([], [], color=COLORS[i % len(COLORS)], marker=".", markersize=3, linewidth=1.2, label=m)[0]
             for i, m in enumerate(frames.errors_deg)]
    ax.set_xlabel("iteration", fontsize=8)
    ax.set_ylabel("error (deg)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3, fontsize=7, frameon=False)
    return lines, x


def _caption(frames: TrialFrames, t: int) -> str:
    errors = ", ".join(f"{m} {float(e[t]):+.3f} deg" for m, e in frames.errors_deg.items())
    line = f"iteration {t + 1}/{len(frames)}, {FIXATION_NAMES[int(frames.fixation[t])]} fixation: {errors}"
    if t < len(frames) - 1:
        return line + "\n"
    depth = frames.depth_prediction_m
    estimate = f"{depth:.3f} m" if math.isfinite(depth) else "none (the depth MLP was never fitted)"
    return f"{line}\ndepth estimate {estimate}, true distance {frames.distance_m:.3f} m"


def _figure(frames: TrialFrames, figsize: tuple[float, float], dpi: int):
    """The figure at the trial's first iteration and ``update(t)``, which draws iteration ``t``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure  # never attached to pyplot: no window, no global backend

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 3, height_ratios=(1.0, 0.8), left=0.1, right=0.97, top=0.9, bottom=0.17,
                            hspace=0.3, wspace=0.08)
    difference = frames.first - frames.second
    limit = max(float(difference.abs().max()), 1e-6)  # one symmetric colour range for the whole trial
    grey = {"cmap": "gray", "vmin": 0.0, "vmax": 1.0}
    first, second = (n.replace("_", " ") for n in frames.names)
    panels = ((first, frames.first, grey), (second, frames.second, grey),
              (f"{first} - {second} (±{limit:.2f})", difference, {"cmap": "RdBu_r", "vmin": -limit, "vmax": limit}))
    images = []
    for column, (title, data, style) in enumerate(panels):
        ax = fig.add_subplot(grid[0, column])
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=9)
        images.append((ax.imshow(data[0].numpy(), interpolation="nearest", **style), data))
    lines, x = _error_axes(fig.add_subplot(grid[1, :]), frames)
    fig.suptitle(f"{frames.texture_name} at {frames.distance_m:.2f} m", fontsize=10)
    caption = fig.text(0.5, 0.015, "", ha="center", va="bottom", fontsize=8)
    errors = [e.double().numpy() for e in frames.errors_deg.values()]

    def update(t: int) -> None:
        for image, data in images:
            image.set_data(data[t].numpy())
        for line, e in zip(lines, errors):
            line.set_data(x[: t + 1], e[: t + 1])
        caption.set_text(_caption(frames, t))

    return fig, update


def frame_steps(iterations: int, every: int = 1) -> list[int]:
    """The iterations :func:`animate_trial` draws: every ``every``-th, and always the last."""
    steps = list(range(0, iterations, every))
    if steps and steps[-1] != iterations - 1:
        steps.append(iterations - 1)
    return steps


def animate_trial(frames: TrialFrames, out: str | os.PathLike, fps: int = 8, *, every: int = 1,
                  figsize: tuple[float, float] = (7.2, 5.0), dpi: int = 100) -> Path:
    """Write ``frames`` as an animation, one frame per iteration: the two views (the left and the
    right eye for the stereo cue), their difference (one symmetric colour range for the whole
    trial) and the eye movements' errors so far (the whole trial's axis limits, the fixation boundary dashed, the band
    of one pixel's error grey), with a caption (iteration, fixation, errors; at the end the depth
    estimate against the true distance).

    Args:
        frames: a :func:`record_trial` result.
        out: a ``.gif`` (Pillow) or ``.mp4`` (ffmpeg, when installed; ``ValueError`` otherwise) file.
        fps: frames per second.
        every: draw every ``every``-th iteration (and always the last), for a smaller file.
        figsize, dpi: the frames' size in inches and their resolution.

    Returns:
        The path written.
    """
    path = check_output(out)
    for name, value in (("fps", fps), ("every", every), ("dpi", dpi)):
        check_int(value, name)
    if not isinstance(frames, TrialFrames) or len(frames) == 0:
        raise ValueError("frames must be a non-empty TrialFrames (record_trial's result)")
    fig, update = _figure(frames, figsize, dpi)
    steps = frame_steps(len(frames), every)
    writer = _writer(path, fps)
    with writer.saving(fig, str(path), dpi):
        for t in steps:
            update(t)
            writer.grab_frame()
    log.info("wrote %s (%d frames)", path, len(steps))
    return path
