"""Evaluation of a trained :class:`~aectorch.framework.JointLearner`, separate from training.

Learning is frozen and both policies are greedy (``policy="sampled"`` draws the actions as in
training instead, for analysis). Two tests:

- **the paper's test**: every texture x distance runs one full trial (a leftward and a rightward
  fixation of ``h`` iterations) from the standard start state; the pursuit and vergence errors
  at the last iteration of each fixation (eq. 9) and the depth MLP's error on the trial's ``q``
  are collected;
- **the earlier models' vergence test**: the left eye is put at its optimal pan and the right
  eye at a random vergence offset (uniform in ``+-offset_deg``), then ``steps`` greedy
  iterations run; the vergence error at the last step is summarised as RMSE, median and 4 x IQR
  in degrees and in pixels (at the camera's degrees per pixel).

From the command line, on a checkpoint written by ``train.py`` (see :func:`main`)::

    python -m aectorch.evaluate checkpoint=outputs/run/checkpoint.pt textures=photos/ out=eval.json
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
from typing import Sequence

import torch
from torch import Tensor

from aectorch._cli import UsageError, parse_key_values, run_main
from aectorch.sim import DEFAULT_DISTANCES_M, RENDERERS, ActiveDepthEnv, TextureBank

__all__ = ["evaluate", "fractions", "main", "per_trial_rows", "run_trials", "summarise",
           "WITHIN_DEG", "BEYOND_DEG"]

#: Evaluation policies: the argmax action (the protocol) or actions sampled as in training.
POLICIES = ("greedy", "sampled")
#: An eye within this many degrees of its optimum counts as on target: one pixel (0.2226 deg/px).
WITHIN_DEG = 0.22
#: An eye farther than this from its optimum counts as failed.
BEYOND_DEG = 2.0


def fractions(pursuit_deg: Tensor, vergence_deg: Tensor) -> dict:
    """The fractions of fixation ends on target (``|error| <= WITHIN_DEG``) and failed
    (``|error| > BEYOND_DEG``), for pursuit, vergence and both together.

    Args:
        pursuit_deg, vergence_deg: signed errors of the same fixation ends, any equal shape.

    Example:
        >>> fractions(torch.tensor([0.1, 0.3, 3.0]), torch.tensor([0.0, 0.1, 0.1]))["both"]
        {'within': 0.3333333333333333, 'beyond': 0.3333333333333333}
    """
    p, v = pursuit_deg.detach().double().reshape(-1).cpu().abs(), vergence_deg.detach().double().reshape(-1).cpu().abs()
    if p.numel() == 0:
        return {key: {"within": math.nan, "beyond": math.nan} for key in ("pursuit", "vergence", "both")}
    return {
        "pursuit": {"within": float((p <= WITHIN_DEG).double().mean()), "beyond": float((p > BEYOND_DEG).double().mean())},
        "vergence": {"within": float((v <= WITHIN_DEG).double().mean()), "beyond": float((v > BEYOND_DEG).double().mean())},
        "both": {"within": float(((p <= WITHIN_DEG) & (v <= WITHIN_DEG)).double().mean()),
                 "beyond": float(((p > BEYOND_DEG) | (v > BEYOND_DEG)).double().mean())},
    }


def per_trial_rows(trials: dict[str, Tensor], names: Sequence[str]) -> list[dict]:
    """One JSON row per trial of :func:`run_trials`' output: its texture's name, distance and the
    signed errors of its final state (the end of its second, rightward fixation), plus both
    fixation ends' pursuit and vergence errors as ``[leftward, rightward]``."""
    rows = []
    for i in range(trials["distance_m"].numel()):
        p, v = trials["pursuit_deg"][i].tolist(), trials["vergence_deg"][i].tolist()
        depth = float(trials["depth_error_m"][i])
        rows.append({
            "texture": names[int(trials["texture_index"][i])],
            "distance_m": round(float(trials["distance_m"][i]), 6),
            "pursuit_error_deg": p[-1],
            "vergence_error_deg": v[-1],
            "depth_error_m": depth if math.isfinite(depth) else None,
            "pursuit_errors_deg": p,
            "vergence_errors_deg": v,
        })
    return rows


def summarise(errors: Tensor) -> dict:
    """Mean absolute error, median absolute error, RMSE, median, 4 x IQR and count of ``errors``."""
    e = errors.detach().double().reshape(-1).cpu()
    e = e[torch.isfinite(e)]
    if e.numel() == 0:
        return {"mae": math.nan, "median_abs": math.nan, "rmse": math.nan, "median": math.nan,
                "iqr4": math.nan, "n": 0}
    q1, q3 = torch.quantile(e, torch.tensor([0.25, 0.75], dtype=torch.float64)).tolist()
    return {
        "mae": float(e.abs().mean()),
        "median_abs": float(e.abs().median()),
        "rmse": float(e.square().mean().sqrt()),
        "median": float(e.median()),
        "iqr4": 4.0 * (q3 - q1),
        "n": int(e.numel()),
    }


def _conditions(num_textures: int, distances: Sequence[float]) -> tuple[Tensor, Tensor]:
    index = torch.arange(num_textures).repeat_interleave(len(distances))
    distance = torch.tensor(list(distances), dtype=torch.float64).repeat(num_textures)
    return index, distance


@contextlib.contextmanager
def _trial_session(learner, bank: TextureBank, distances: list[float], renderer: str, shift_m: float,
                   seed: int, bar=None, shift_iterations: int = 1, yoked_pursuit: bool = False):
    """``env_for(size, h, instant=False)``: environments of ``bank`` made once per (size, h,
    instant), all closed at the end. ``instant`` environments shift the body at once (the vergence
    test, which starts at the shifted position); the others follow ``shift_iterations``.

    For the session the learner's generator (sampled actions) is seeded from ``seed``; it gets
    its own state back afterwards, and the progress bar ``bar`` is closed.
    """
    parameter = next(learner.parameters())
    envs: dict[tuple[int, int, bool], ActiveDepthEnv] = {}

    def env_for(size: int, h: int, instant: bool = False) -> ActiveDepthEnv:
        if (size, h, instant) not in envs:
            envs[size, h, instant] = ActiveDepthEnv(
                size, textures=bank, renderer=renderer, distances_m=distances, fixation_iterations=h,
                shift_m=shift_m, shift_iterations=1 if instant else shift_iterations,
                yoked_pursuit=yoked_pursuit, seed=seed, device=parameter.device, dtype=parameter.dtype)
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
            close = getattr(env.renderer, "close", None)
            if close is not None:
                close()


def _check_trial_arguments(distances_m: Sequence[float], batch_size: int, policy: str) -> list[float]:
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    distances = [float(d) for d in distances_m]
    if not distances or any(not math.isfinite(d) or d <= 0 for d in distances):
        raise ValueError(f"distances_m must be distances > 0 (metres), got {distances_m!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be an int >= 1, got {batch_size!r}")
    return distances


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


def _paper_trials(learner, index: Tensor, distance: Tensor, env_for, batch_size: int,
                  fixation_iterations: int, greedy: bool, bar) -> dict[str, Tensor]:
    """The paper's test: one full trial per (texture index, distance), learning frozen."""
    device, dtype = next(learner.parameters()).device, next(learner.parameters()).dtype
    total = index.numel()
    out: dict[str, list[Tensor]] = {"pursuit_deg": [], "vergence_deg": [], "q_deg": [], "depth_error_m": []}
    with torch.no_grad():
        for start in range(0, total, batch_size):
            stop = min(start + batch_size, total)
            env = env_for(stop - start, fixation_iterations)
            env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
            learner.forget_transitions()
            finals_p, finals_v = [], []
            while True:
                record = learner.iteration(env, learn=False, greedy=greedy)
                if record.fixation_end:
                    finals_p.append(record.pursuit_error_deg)
                    finals_v.append(record.vergence_error_deg)
                if record.trial_end:
                    break
            out["pursuit_deg"].append(torch.stack(finals_p, 1))  # [b, 2 fixations]
            out["vergence_deg"].append(torch.stack(finals_v, 1))
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
    renderer: str = "torch",
    batch_size: int = 256,
    fixation_iterations: int = 30,
    shift_m: float = 0.1,
    shift_iterations: int = 1,
    yoked_pursuit: bool = False,
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
        learner: a :class:`~aectorch.framework.JointLearner` (not modified).
        textures: the trials' textures.
        distances_m: object distances; every texture is tested at every distance.
        renderer: ``"torch"`` or ``"pyrender"``.
        batch_size: environments simulated at once.
        fixation_iterations: h, iterations per fixation.
        shift_m: the body shift.
        shift_iterations, yoked_pursuit: the body movement's profile and whether pursuit moves
            both eyes (`ActiveDepthEnv`); a learner is evaluated under the protocol it trained in.
        seed: seeds the environments and, with ``policy="sampled"``, the actions.
        policy: ``"greedy"`` or ``"sampled"``, as for :func:`evaluate`.
        progress: show a progress bar (a string: its label; ``True``: "trials").
        conditions: ``(texture_index, distance_m)``, two ``[N]`` tensors: run these N trials
            instead of every texture at every distance (the distances must be among
            ``distances_m``).

    Returns:
        CPU tensors over the N = textures x distances trials (texture-major): ``pursuit_deg`` and
        ``vergence_deg`` ``[N, 2]`` (signed errors at the end of each fixation), ``q_deg``
        ``[N, 4]`` (the MLP's inputs), ``depth_error_m`` ``[N]`` (NaN before the MLP's first fit),
        ``texture_index`` and ``distance_m`` ``[N]``.

    Example:
        >>> import torch
        >>> from aectorch.framework import JointLearner, LearnerConfig
        >>> learner = JointLearner(LearnerConfig(num_atoms=16), generator=torch.Generator().manual_seed(0))
        >>> out = run_trials(learner, torch.rand(2, 64, 64), distances_m=[1.0, 2.0], fixation_iterations=2)
        >>> out["q_deg"].shape, out["distance_m"].tolist()
        (torch.Size([4, 4]), [1.0, 2.0, 1.0, 2.0])
    """
    greedy = policy == "greedy"
    distances = _check_trial_arguments(distances_m, batch_size, policy)
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    if conditions is None:
        index, distance = _conditions(len(bank), distances)
    else:
        index, distance = _check_conditions(conditions, len(bank), distances)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=index.numel(), desc=progress if isinstance(progress, str) else "trials", unit="trial")
    with _trial_session(learner, bank, distances, renderer, shift_m, seed, bar,
                        shift_iterations, yoked_pursuit) as env_for:
        return _paper_trials(learner, index, distance, env_for, batch_size, fixation_iterations, greedy, bar)


def evaluate(
    learner,
    textures: TextureBank | Tensor,
    *,
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    renderer: str = "torch",
    batch_size: int = 256,
    fixation_iterations: int = 30,
    shift_m: float = 0.1,
    shift_iterations: int = 1,
    yoked_pursuit: bool = False,
    vergence_test: bool = True,
    offset_deg: float = 2.0,
    steps: int = 20,
    seed: int = 0,
    progress: bool = False,
    policy: str = "greedy",
) -> dict:
    """Evaluate ``learner`` greedily with all learning frozen; returns a JSON-ready dict.

    Args:
        learner: a :class:`~aectorch.framework.JointLearner`; its weights and statistics are not
            modified (it runs with ``learn=False``).
        textures: the evaluation textures (e.g. ``TextureBank.from_folder(...)`` of photographs
            it never trained on).
        distances_m: object distances; every texture is tested at every distance.
        renderer: ``"torch"`` or ``"pyrender"``.
        batch_size: environments simulated at once.
        fixation_iterations, shift_m: the trial protocol (paper: 30, 0.1 m).
        shift_iterations, yoked_pursuit: the body movement's profile and whether pursuit moves
            both eyes (`ActiveDepthEnv`); a learner is evaluated under the protocol it trained in.
        vergence_test: also run the earlier models' vergence test.
        offset_deg, steps: its initial vergence offsets (uniform in +-offset_deg) and step count.
        seed: seeds the vergence test's offsets.
        progress: show a progress bar.
        policy: ``"greedy"`` (the argmax action; the evaluation protocol) or ``"sampled"``
            (actions drawn from the softmax policies, as in training, from the learner's own
            generator), to measure what greediness costs.

    Returns:
        ``pursuit_mae_deg``, ``vergence_mae_deg``, ``depth_mae_m`` and full summaries
        (:func:`summarise`) under ``pursuit``, ``vergence``, ``depth``; ``fractions`` (of the
        fixation ends within ``WITHIN_DEG`` and beyond ``BEYOND_DEG``, :func:`fractions`);
        per-distance and per-texture breakdowns (``per_distance``, ``per_texture``); one row per
        trial (``per_trial``, :func:`per_trial_rows`); ``trials``; and ``vergence_test`` when asked.
    """
    greedy = policy == "greedy"
    distances = _check_trial_arguments(distances_m, batch_size, policy)
    bank = textures if isinstance(textures, TextureBank) else TextureBank(textures)
    parameter = next(learner.parameters())
    device, dtype = parameter.device, parameter.dtype
    index, distance = _conditions(len(bank), distances)
    total = index.numel()
    chunks = [(start, min(start + batch_size, total)) for start in range(0, total, batch_size)]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total * (2 if vergence_test else 1), desc="evaluate", unit="trial")

    def run(env_for) -> dict:
        """The two tests (the closure keeps evaluate's prepared arguments)."""
        paper = _paper_trials(learner, index, distance, env_for, batch_size, fixation_iterations, greedy, bar)
        errors = {"pursuit": paper["pursuit_deg"], "vergence": paper["vergence_deg"],
                  "depth": paper["depth_error_m"]}
        names = {"pursuit": "pursuit_mae_deg", "vergence": "vergence_mae_deg", "depth": "depth_mae_m"}

        def maes(mask: Tensor) -> dict:
            """The three MAEs of the trials in ``mask`` (both fixations of each), and the fractions
            of their fixation ends on target and failed."""
            return {**{names[key]: summarise(x[mask])["mae"] for key, x in errors.items()},
                    "fractions": fractions(errors["pursuit"][mask], errors["vergence"][mask])}

        summaries = {key: summarise(x) for key, x in errors.items()}
        result = {
            **{names[key]: summary["mae"] for key, summary in summaries.items()},
            **summaries,
            "trials": total,
            "textures": len(bank),
            "distances_m": distances,
            "per_distance": [{"distance_m": d, **maes((distance - d).abs() < 1e-9)} for d in distances],
            "per_texture": [{"texture": name, **maes(index == i)} for i, name in enumerate(bank.names)],
            "fractions": fractions(errors["pursuit"], errors["vergence"]),
            "within_deg": WITHIN_DEG,
            "beyond_deg": BEYOND_DEG,
            "per_trial": per_trial_rows(paper, bank.names),
        }

        if vergence_test:
            generator = torch.Generator().manual_seed(seed)
            finals = []
            with torch.no_grad():
                for start, stop in chunks:
                    env = env_for(stop - start, steps, instant=True)
                    env.set_trial(index[start:stop].to(device), distance[start:stop].to(device=device, dtype=dtype))
                    left = env.optimal_left_pan_deg()
                    offsets = (torch.rand(stop - start, generator=generator, dtype=torch.float64) * 2 - 1) * offset_deg
                    right = env.optimal_right_pan_deg(left) + offsets.to(device=device, dtype=dtype)
                    env.set_pan_deg(torch.stack((left, right), -1))
                    learner.forget_transitions()
                    for _ in range(steps):
                        record = learner.iteration(env, learn=False, greedy=greedy)
                    finals.append(record.vergence_error_deg.cpu())
                    if bar is not None:
                        bar.update(stop - start)
            final = torch.cat(finals)
            per_pixel = env.camera.degrees_per_pixel
            deg = summarise(final)
            result["vergence_test"] = {
                "offset_deg": offset_deg,
                "steps": steps,
                "degrees": deg,
                "pixels": {k: (v / per_pixel if k != "n" else v) for k, v in deg.items()},
            }
        return result

    # Sampled actions come from the learner's generator: the session seeds it from ``seed`` for
    # the evaluation and gives the learner its own state back afterwards.
    with _trial_session(learner, bank, distances, renderer, shift_m, seed, bar,
                        shift_iterations, yoked_pursuit) as env_for:
        result = run(env_for)
    result["policy"] = policy
    return result


USAGE = """usage: python -m aectorch.evaluate checkpoint=<file> out=<file.json> [key=value ...]

Evaluate a trained checkpoint (train.py's checkpoint.pt) frozen and greedy: every texture at
every distance runs one trial, then the earlier models' vergence test.

keys:
  checkpoint=<file>      the checkpoint (required)
  out=<file.json>        where to write the result (required)
  textures=<folder>      held-out images (default: the default test bank, 40 procedural
                         textures disjoint from the default training set)
  renderer=torch|pyrender                    (default: torch)
  depths=[1.0,2.0,3.0]   distances in metres (default: 1.0 to 3.0 in 0.1 m steps)
  batch_size=<int>       environments at once (default: 256)
  seed=<int>             seeds the vergence test's offsets (default: 0)
  figure=<file.png>      also draw the evaluation figure
  progress=true|false    show a progress bar (default: true)
  policy=greedy|sampled  argmax actions (the protocol; default) or actions sampled from the
                         policies as in training, to see what greediness costs

Errors print one "error: ..." line and exit with status 2.
"""

_KEYS = ("checkpoint", "out", "textures", "renderer", "depths", "batch_size", "seed", "figure", "progress",
         "policy")


def _parse(argv: Sequence[str]) -> dict:

    args = parse_key_values(argv, _KEYS, required=("checkpoint", "out"),
                            paths=("checkpoint", "out", "textures", "figure"))
    renderer = args.setdefault("renderer", "torch")
    if renderer not in RENDERERS:
        raise UsageError(f"renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    depths = args.setdefault("depths", list(DEFAULT_DISTANCES_M))
    if isinstance(depths, (int, float)) and not isinstance(depths, bool):
        depths = args["depths"] = [depths]
    if (not isinstance(depths, list) or not depths
            or any(isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) or d <= 0
                   for d in depths)):
        raise UsageError(f"depths must be a list of distances > 0 in metres such as [1.0,2.0], got {depths!r}")
    for key, default, minimum in (("batch_size", 256, 1), ("seed", 0, 0)):
        value = args.setdefault(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise UsageError(f"{key} must be an int >= {minimum}, got {value!r}")
    policy = args.setdefault("policy", "greedy")
    if policy not in POLICIES:
        raise UsageError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    progress = args.setdefault("progress", True)
    if not isinstance(progress, bool):
        raise UsageError(f"progress must be true or false, got {progress!r}")
    textures = args.get("textures")
    if textures is not None and not os.path.isdir(textures):
        raise UsageError(f"textures: no such folder {textures!r}")
    if not os.path.isfile(args["checkpoint"]):
        raise UsageError(f"checkpoint: no such file {args['checkpoint']!r}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.evaluate checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run_main(argv, USAGE, _evaluate)


def _evaluate(argv: list[str]) -> int:
    args = _parse(argv)
    from aectorch.experiment import load_checkpoint, load_learner

    cfg, learner = load_learner(args["checkpoint"])
    iteration = int(load_checkpoint(args["checkpoint"])["iteration"])
    if args.get("textures") is None:
        bank, textures = TextureBank.default("test"), "default test bank"
    else:
        try:
            bank = TextureBank.from_folder(args["textures"], progress=None if args["progress"] else False)
        except (ValueError, OSError) as err:
            raise UsageError(f"textures: {err}") from err
        textures = args["textures"]
    result = evaluate(learner, bank, distances_m=args["depths"], renderer=args["renderer"],
                      batch_size=args["batch_size"], fixation_iterations=cfg.env.fixation_iterations,
                      shift_m=cfg.env.shift_m, shift_iterations=cfg.env.shift_iterations,
                      yoked_pursuit=cfg.env.yoked_pursuit, seed=args["seed"], progress=args["progress"],
                      policy=args["policy"])
    result.update(checkpoint=args["checkpoint"], textures=textures, renderer=args["renderer"], iteration=iteration)
    with open(args["out"], "w") as f:
        json.dump(result, f, indent=2)
        f.write("\n")
    if args.get("figure"):
        from aectorch.figures import plot_evaluation

        plot_evaluation(result, args["figure"])
    rows = [f"{'distance_m':>10} {'pursuit_mae_deg':>16} {'vergence_mae_deg':>17} {'depth_mae_m':>12}"]
    for row in result["per_distance"] + [dict(result, distance_m="all")]:
        d = row["distance_m"]
        rows.append(f"{d if isinstance(d, str) else f'{d:.2f}':>10} {row['pursuit_mae_deg']:>16.4f} "
                    f"{row['vergence_mae_deg']:>17.4f} {row['depth_mae_m']:>12.4f}")
    both = result["fractions"]["both"]
    rows.append(f"fixation ends with pursuit and vergence within {WITHIN_DEG} deg: {both['within']:.1%}; "
                f"either beyond {BEYOND_DEG} deg: {both['beyond']:.1%}")
    if "vergence_test" in result:
        deg = result["vergence_test"]["degrees"]
        rows.append(f"vergence test: RMSE {deg['rmse']:.4f} deg, median {deg['median']:.4f} deg, n {deg['n']}")
    rows.append(f"{result['trials']} trials, checkpoint iteration {iteration}; written to {args['out']}")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
