"""The paper's test as tensors: every texture x distance runs one trial, learning frozen."""

from __future__ import annotations

import contextlib
import itertools
from dataclasses import replace
from typing import Iterator, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_choice, check_distances, check_int
from aectorch.choices import Policy
from aectorch.evaluation.summary import LAST_ITERATIONS, LAST_SUFFIX
from aectorch.evaluation.views import view_statistics
from aectorch.sim import DEFAULT_DISTANCES_M, ActiveDepthEnv, TextureBank, TrialProtocol, resolve_protocol

__all__ = ["EVAL_BATCH_SIZE", "LAST_ITERATIONS", "LAST_SUFFIX", "TRACKING_ERRORS", "TRACKING_SKIP", "TRACKING_SPEEDS_DEG",
           "frozen_iterations", "run_trials", "run_tracking", "tracking_by_speed", "tracking_rows"]

#: Environments simulated at once by default.
EVAL_BATCH_SIZE = 256
#: A moving object's tracking error leaves out each fixation's first this many iterations (the eyes
#: catch up with it): the mean |error| of the rest.
TRACKING_SKIP = 5
#: The sideways speeds (degrees per iteration) of `run_tracking` by default: up to Wilmot et al.'s
#: (2021) fastest screens.
TRACKING_SPEEDS_DEG = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25)
#: The tracking test's errors, each eye movement's key suffixes: the mean |error| (the eye against
#: the object where it is during the iteration, after the eye's increments); the mean error ahead
#: of the object (signed along its sideways motion: positive, the eye leads; 0 without sideways
#: motion); the mean |change of the error| from one iteration to the next, the eye's speed
#: against the object's (degrees per iteration).
TRACKING_ERRORS = ("_tracking_deg", "_lead_tracking_deg", "_speed_tracking_deg")


def _all_conditions(num_textures: int, distances: Sequence[float]) -> tuple[Tensor, Tensor]:
    index = torch.arange(num_textures).repeat_interleave(len(distances))
    distance = torch.tensor(list(distances), dtype=torch.float64).repeat(num_textures)
    return index, distance


def placement(learner) -> tuple[torch.device, torch.dtype]:
    """The device and float type of ``learner``'s first parameter (or buffer, for a controller
    without parameters such as `aectorch.baselines.Matcher`): where its environments live."""
    for tensor in itertools.chain(learner.parameters(), learner.buffers()):
        if tensor.is_floating_point():
            return tensor.device, tensor.dtype
    return torch.device("cpu"), torch.float32


@contextlib.contextmanager
def _trial_session(learner, bank: TextureBank, distances: list[float], protocol: TrialProtocol, seed: int, bar=None):
    """``env_for(size, h, instant=False)``: environments of ``bank`` under ``protocol`` made once per
    (size, h, instant), all closed at the end. ``instant`` environments shift the body at once (the
    vergence test, which starts at the shifted position); the others follow the protocol's profile.

    For the session the learner's generator (sampled actions) is seeded from ``seed``; it gets
    its own state back afterwards, and the progress bar ``bar`` is closed.
    """
    device, dtype = placement(learner)
    envs: dict[tuple[int, int, bool], ActiveDepthEnv] = {}

    def env_for(size: int, h: int, instant: bool = False) -> ActiveDepthEnv:
        if (size, h, instant) not in envs:
            trial = replace(protocol, fixation_iterations=h,
                            shift_iterations=1 if instant else protocol.shift_iterations)
            envs[size, h, instant] = ActiveDepthEnv(size, protocol=trial, textures=bank, distances_m=distances,
                                                    seed=seed, device=device, dtype=dtype)
        return envs[size, h, instant]

    saved_generator = learner.generator.get_state()
    learner.generator.manual_seed(seed)
    try:
        yield env_for
    finally:
        learner.generator.set_state(saved_generator)
        if bar is not None:
            bar.close()
        for env in envs.values():
            env.close()


def _check_trial_arguments(distances_m: Sequence[float], batch_size: int, policy: str) -> tuple[list[float], Policy]:
    """The distances as floats and the policy, or ``ValueError`` naming the argument."""
    policy = check_choice(policy, "policy", Policy)
    distances = check_distances(distances_m, "distances_m")
    check_int(batch_size, "batch_size", 1)
    return distances, policy


def _check_conditions(conditions, num_textures: int, distances: list[float]) -> tuple[Tensor, Tensor]:
    if not (isinstance(conditions, (tuple, list)) and len(conditions) == 2
            and all(isinstance(c, Tensor) and c.dim() == 1 for c in conditions)
            and conditions[0].shape == conditions[1].shape and conditions[0].numel() > 0):
        raise ValueError("conditions must be (texture_index, distance_m), two non-empty 1-D tensors of one length")
    index, distance = conditions[0].long().cpu(), conditions[1].double().cpu()
    if bool(((index < 0) | (index >= num_textures)).any()):
        raise ValueError(f"conditions' texture indices must be in [0, {num_textures})")
    known = torch.tensor(distances, dtype=torch.float64)
    if not bool(((distance[:, None] - known).abs() < 1e-9).any(1).all()):
        raise ValueError(f"conditions' distances must be among distances_m {distances}")
    return index, distance


def frozen_iterations(learner, env, *, greedy: bool = True, iterations: int | None = None,
                      watch=None) -> Iterator:
    """The one trial loop (the evaluation, the vergence test, the viewer): ``learner``'s frozen
    iterations on ``env`` as it stands, each `IterationRecord` yielded, until the trial ends (or
    ``iterations`` of them). No transition of the learner is pending before or after; ``watch``:
    see `JointLearner.iteration`."""
    learner.forget_transitions()
    try:
        for _ in range(iterations if iterations is not None else 2 * env.fixation_iterations):
            with torch.no_grad():  # not around the yield: the caller's code keeps its grad mode
                record = learner.iteration(env, learn=False, greedy=greedy, watch=watch)
            yield record
            if iterations is None and record.trial_end:
                return
        if iterations is None:
            raise RuntimeError(f"the trial did not end after {2 * env.fixation_iterations} iterations")
    finally:
        learner.forget_transitions()


def _paper_trials(learner, index: Tensor, distance: Tensor, env_for, batch_size: int,
                  fixation_iterations: int, greedy: bool, bar) -> dict[str, Tensor]:
    """The paper's test: one full trial per (texture index, distance), learning frozen; each eye
    movement's signed errors at the fixation ends as ``<movement>_deg`` ``[N, fixations]``."""
    device, dtype = placement(learner)
    total = index.numel()
    out: dict[str, list[Tensor]] = {"q_deg": [], "depth_error_m": []}
    for start in range(0, total, batch_size):
        stop = min(start + batch_size, total)
        env = env_for(stop - start, fixation_iterations)
        env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
        for key, value in view_statistics(env).items():  # what the eyes see at the trial's start
            out.setdefault(key, []).append(value)
        finals: dict[str, list[Tensor]] = {}
        lasts: dict[str, list[Tensor]] = {}
        recent: dict[str, list[Tensor]] = {}
        for record in frozen_iterations(learner, env, greedy=greedy):
            for movement, error in record.errors_deg.items():
                recent.setdefault(movement, []).append(error)
                del recent[movement][:-LAST_ITERATIONS]
            if record.fixation_end:
                for movement, error in record.errors_deg.items():
                    finals.setdefault(movement, []).append(error)
                    lasts.setdefault(movement, []).append(torch.stack(recent.pop(movement)).mean(0))
        for movement, errors in finals.items():
            out.setdefault(f"{movement}_deg", []).append(torch.stack(errors, 1))  # [b, 2 fixations]
            out.setdefault(f"{movement}{LAST_SUFFIX}", []).append(torch.stack(lasts[movement], 1))
        out["q_deg"].append(record.q_deg)
        out["depth_error_m"].append(record.depth_prediction_m - record.distance_m)
        if bar is not None:
            bar.update(stop - start)
    result = {key: torch.cat(value).cpu() for key, value in out.items()}
    result["texture_index"], result["distance_m"] = index, distance
    return result


def run_trials(
    learner,
    textures: TextureBank | Tensor,
    *,
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    protocol: TrialProtocol | None = None,
    batch_size: int = EVAL_BATCH_SIZE,
    seed: int = 0,
    policy: str = "greedy",
    progress: bool | str = False,
    conditions: tuple[Tensor, Tensor] | None = None,
) -> dict[str, Tensor]:
    """The paper's test as tensors: every texture x distance runs one trial, learning frozen.

    The trial loop of :func:`evaluate`, for callers that want the raw results: e.g. the final
    eye movements ``q_deg`` of greedy trials on the training textures, which
    ``train.depth_calibration_trials`` refits the depth MLP on (:meth:`JointLearner.calibrate_depth`).

    Args:
        learner: a :class:`~aectorch.framework.JointLearner`: its weights, statistics and generator are
            not modified; its pending transitions are dropped (`JointLearner.forget_transitions`).
        textures: the trials' textures.
        distances_m: object distances; every texture is tested at every distance.
        protocol: the trial protocol (`aectorch.sim.TrialProtocol`; default its defaults, the
            training's); a learner is evaluated under the protocol it trained in.
        batch_size: environments simulated at once.
        seed: seeds the environments and, with ``policy="sampled"``, the actions.
        policy: ``"greedy"`` or ``"sampled"``, as for :func:`evaluate`.
        progress: show a progress bar (a string: its label; ``True``: "trials").
        conditions: ``(texture_index, distance_m)``, two ``[N]`` tensors: run these N trials
            instead of every texture at every distance (the distances must be among
            ``distances_m``).

    Returns:
        CPU tensors over the N = textures x distances trials (texture-major): ``<movement>_deg``
        for each eye movement (``pursuit_deg``, ``vergence_deg``) ``[N, 2]`` (signed errors at
        the end of each fixation), ``<movement>_last5_deg`` ``[N, 2]`` (the mean signed error of
        each fixation's last `LAST_ITERATIONS` iterations), ``q_deg``
        ``[N, 4]`` (the MLP's inputs), ``depth_error_m`` ``[N]`` (NaN before the MLP's first fit),
        the texture statistics of the view at each trial's start ``view_contrast`` and
        ``view_energy_<scale>`` ``[N]`` (`aectorch.evaluation.views.view_statistics`),
        ``texture_index`` and ``distance_m`` ``[N]``.

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> learner = JointLearner(LearnerConfig(), generator=torch.Generator().manual_seed(0))
        >>> out = run_trials(learner, torch.rand(2, 64, 64), distances_m=[1.0, 2.0],
        ...                  protocol=TrialProtocol(fixation_iterations=2))
        >>> out["q_deg"].shape, out["distance_m"].tolist()
        (torch.Size([4, 4]), [1.0, 2.0, 1.0, 2.0])
    """
    distances, policy = _check_trial_arguments(distances_m, batch_size, policy)
    protocol = resolve_protocol(protocol)
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    if conditions is None:
        index, distance = _all_conditions(len(bank), distances)
    else:
        index, distance = _check_conditions(conditions, len(bank), distances)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=index.numel(), desc=progress if isinstance(progress, str) else "trials", unit="trial")
    with _trial_session(learner, bank, distances, protocol, seed, bar) as env_for:
        return _paper_trials(learner, index, distance, env_for, batch_size, protocol.fixation_iterations,
                            policy == Policy.greedy, bar)




def _tracking_trials(learner, index: Tensor, distance: Tensor, speed: Tensor, env_for, batch_size: int,
                     fixation_iterations: int, skip: int, greedy: bool, bar) -> dict[str, Tensor]:
    """One trial per row of (texture index, distance, speed ``[N, 2]``: sideways deg and depth m
    per iteration), the object pinned at its speed; each eye movement's errors over each
    fixation's iterations from ``skip`` on, ``[N, 2]`` each (`TRACKING_ERRORS`)."""
    device, dtype = placement(learner)
    out: dict[str, list[Tensor]] = {}
    for start in range(0, index.numel(), batch_size):
        stop = min(start + batch_size, index.numel())
        env = env_for(stop - start, fixation_iterations)
        rows = speed[start:stop].to(device=device, dtype=dtype)
        env.set_object_speed(rows[:, 0], rows[:, 1])
        env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
        direction = rows[:, 0].sign()
        sums: dict[str, list[Tensor]] = {}
        previous: dict[str, Tensor]
        step, previous = 0, {}
        for record in frozen_iterations(learner, env, greedy=greedy):
            for movement, error in record.errors_deg.items():
                if step == skip:
                    sums.setdefault(movement, []).append(torch.zeros(3, *error.shape, dtype=error.dtype,
                                                                     device=error.device))
                if step >= skip:  # |error|, error ahead of the object, |change of the error|
                    sums[movement][-1] += torch.stack((error.abs(), error * direction,
                                                       (error - previous[movement]).abs()))
                previous[movement] = error
            step = 0 if record.fixation_end else step + 1
        for movement, total in sums.items():
            means = torch.stack(total, -1) / (fixation_iterations - skip)  # [3, b, 2]
            for key, mean in zip(TRACKING_ERRORS, means):
                out.setdefault(f"{movement}{key}", []).append(mean)
        env.set_object_speed()
        if bar is not None:
            bar.update(stop - start)
    result = {key: torch.cat(value).cpu() for key, value in out.items()}
    result.update(texture_index=index, distance_m=distance, speed_deg=speed[:, 0].clone(),
                  depth_speed_m=speed[:, 1].clone())
    return result


def run_tracking(
    learner,
    textures: TextureBank | Tensor,
    *,
    speeds_deg: Sequence[float] = TRACKING_SPEEDS_DEG,
    depth_speed_m: float = 0.0,
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    protocol: TrialProtocol | None = None,
    skip: int = TRACKING_SKIP,
    batch_size: int = EVAL_BATCH_SIZE,
    seed: int = 0,
    policy: str = "greedy",
    progress: bool | str = False,
) -> dict[str, Tensor]:
    """A moving object's test: every texture x distance x speed runs one trial, learning frozen.

    In each fixation the object moves sideways at the speed (alternately leftward and rightward from
    trial to trial) and in depth at ``depth_speed_m`` (`ActiveDepthEnv.set_object_speed`), from the
    standard start state; the body shift is the protocol's.

    Args:
        learner, textures, distances_m, protocol, batch_size, seed, policy, progress: as for
            :func:`run_trials`.
        speeds_deg: sideways speeds, degrees per iteration (each >= 0).
        depth_speed_m: the speed in depth, metres per iteration (negative: approaching).
        skip: each fixation's first this many iterations are left out of the tracking errors.

    Returns:
        CPU tensors over N = speeds x textures x distances trials (speed-major), for each eye
        movement ``[N, 2]`` (each fixation's, from iteration ``skip`` on): ``<movement>_tracking_deg``
        (mean |error|), ``<movement>_lead_tracking_deg`` (mean error ahead of the object) and
        ``<movement>_speed_tracking_deg`` (mean |change of the error|, degrees per iteration;
        `TRACKING_ERRORS`); ``speed_deg`` (signed) and ``depth_speed_m`` ``[N]``,
        ``texture_index`` and ``distance_m`` ``[N]``. :func:`tracking_rows` and
        :func:`tracking_by_speed` read them.

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> learner = JointLearner(LearnerConfig(), generator=torch.Generator().manual_seed(0))
        >>> out = run_tracking(learner, torch.rand(1, 64, 64), speeds_deg=[0.0, 1.0], distances_m=[1.0],
        ...                    protocol=TrialProtocol(fixation_iterations=3), skip=1)
        >>> out["pursuit_tracking_deg"].shape, out["speed_deg"].tolist()
        (torch.Size([2, 2]), [0.0, 1.0])
    """
    distances, policy = _check_trial_arguments(distances_m, batch_size, policy)
    protocol = resolve_protocol(protocol)
    check_int(skip, "skip", 0)
    if skip >= protocol.fixation_iterations:
        raise ValueError(f"skip must be below fixation_iterations={protocol.fixation_iterations}, got {skip}")
    speeds = [float(v) for v in speeds_deg]
    if not speeds or any(not (v >= 0) for v in speeds):
        raise ValueError(f"speeds_deg must be a non-empty list of speeds >= 0 (degrees per iteration), got {speeds_deg!r}")
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    index, distance = _all_conditions(len(bank), distances)
    n = index.numel()
    direction = 1.0 - 2.0 * (torch.arange(n) % 2).double()  # leftward (positive), rightward, ...
    speed = torch.cat([torch.stack((v * direction, torch.full((n,), float(depth_speed_m), dtype=torch.float64)), -1)
                       for v in speeds])
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=speed.shape[0], desc=progress if isinstance(progress, str) else "tracking", unit="trial")
    with _trial_session(learner, bank, distances, protocol, seed, bar) as env_for:
        return _tracking_trials(learner, index.repeat(len(speeds)), distance.repeat(len(speeds)), speed, env_for,
                                batch_size, protocol.fixation_iterations, skip, policy == Policy.greedy, bar)


def tracking_rows(trials: dict[str, Tensor], names: Sequence[str]) -> list[dict]:
    """One JSON row per trial of :func:`run_tracking`: texture, distance, the object's speeds and each
    movement's tracking errors of both fixations (``<movement>_tracking_deg``, [leftward, rightward])."""
    keys = [key for key in trials if key.endswith("_tracking_deg")]
    return [{"texture": names[int(trials["texture_index"][i])], "distance_m": round(float(trials["distance_m"][i]), 6),
             "speed_deg": float(trials["speed_deg"][i]), "depth_speed_m": float(trials["depth_speed_m"][i]),
             **{key: trials[key][i].tolist() for key in keys}} for i in range(trials["distance_m"].numel())]


def tracking_by_speed(trials: dict[str, Tensor]) -> list[dict]:
    """The mean tracking errors of :func:`run_tracking`'s trials at each sideways speed (its
    magnitude, both directions together), over both fixations of every trial: a row per speed."""
    keys = [key for key in trials if key.endswith("_tracking_deg")]
    speed = trials["speed_deg"].abs()
    rows = []
    for v in sorted(set(speed.tolist())):
        mask = speed == v
        rows.append({"speed_deg": v, "trials": int(mask.sum()),
                     **{key: float(trials[key][mask].double().mean()) for key in keys}})
    return rows
