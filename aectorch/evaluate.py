"""``python -m aectorch.evaluate``: evaluate a checkpoint written by ``train.py`` (see ``--help``).

A command line, beside ``python -m aectorch.record`` and ``python -m aectorch.visualize``: it sits
above the runtime (it reads checkpoints through it); the library it runs, `aectorch.evaluation`,
sits below the runtime, which runs it at the end of training.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

from omegaconf import MISSING

from aectorch._checks import check_int, check_real
from aectorch.choices import Policy, Readout, RendererName
from aectorch.evaluation import BEYOND_DEG, EVAL_BATCH_SIZE, WITHIN_DEG, evaluate
from aectorch.evaluation.stereo_pairs import START_KINDS, Scoring, coding_reward, evaluate_pairs, stereo_policy
from aectorch.evaluation.trials import TRACKING_SKIP, run_tracking, tracking_by_speed, tracking_rows
from aectorch.baselines import Matcher
from aectorch.figures import plot_evaluation, plot_tracking
from aectorch.runtime.checkpoint import load_checkpoint, load_learner
from aectorch.runtime.command import check_checkpoint_file, check_output_file, run
from aectorch.runtime.outputs import note_output, write_json
from aectorch.runs import checkpoint_source
from aectorch.sim import DEFAULT_DISTANCES_M, PAN_RANGE_DEG, TextureBank, check_oculomotor_range, resolve_protocol
from aectorch.sim.stereo_pairs import read_pairs

__all__ = ["EvaluateConfig", "main"]

#: Fixation points per stereo pair (``pairs=``).
PAIR_FIXATIONS = 300


@dataclass
class EvaluateConfig:
    """Evaluate a trained checkpoint (train.py's checkpoint.pt) frozen and greedy: every texture at
    every distance runs one trial, then the earlier models' vergence test.

    Args:
        checkpoint: the checkpoint, a file.
        out: where to write the result, a .json file.
        textures: a folder of held-out images (default: the default test bank, 40 procedural
            textures disjoint from the default training set).
        renderer: torch or pyrender (default: the run's, env.renderer).
        depths: distances in metres.
        batch_size: environments at once.
        seed: seeds the vergence test's offsets.
        figure: also draw the evaluation figure into this .png file.
        progress: show a progress bar.
        policy: greedy (each cue's greedy increment, see readout: the protocol) or sampled
            (actions sampled from the policies as in training, to see what greediness costs).
        readout: mean or argmax, the greedy increment of every cue: the policy's mean increment,
            or the most probable action's (default: the run's, learner.cues.<cue>.readout, whose
            own default is mean; preset=paper's is argmax).
        tracking: a moving object's test instead of the paper's: the object's sideways speeds,
            degrees per iteration (e.g. [0,0.5,1]); every texture x depth x speed runs one trial
            (aectorch.evaluation.run_tracking), and the result holds the tracking errors per
            speed and per trial.
        depth_speed: with tracking, the object's speed in depth, metres per iteration (negative:
            approaching); an error without tracking, where it would do nothing.
        skip: with tracking, each fixation's first this many iterations are left out of the errors
            (an error without tracking, where it would do nothing).
        vergence_range_deg: [low, high], the oculomotor vergence range of the trials (default:
            the run's, env.vergence_range_deg): e.g. a run trained without the range evaluated
            within it.
        pairs: a folder of rectified stereo photographs with ground-truth disparity, a pair's
            folder or a folder of them (Middlebury's layout: im0.png, im1.png, disp0.pfm; or the
            plain one: left.*, right.*, disparity.npy): instead of the paper's test, the stereo
            cue (frozen, greedy) and the classical matcher fixate points of each pair for a
            fixation's iterations, from the protocol's start vergence and from the vergence
            test's (the optimum +-2 deg); the result holds each fixation's final error in eye
            pixels (aectorch.evaluation.stereo_pairs). A plain folder without disparity.npy
            (e.g. a LeRobot dataset's two cameras, scripts/lerobot_pairs.py) is a pair without
            ground truth: the protocol's start only, the vergence searched over search_deg,
            scored by the stereo cue's coding reward, the fixation's stability and its agreement
            with the matcher. Not with textures or tracking.
        pair_scale: with pairs, the photo pixels one eye pixel spans (1, 2, ...).
        fixations: with pairs, the fixation points per pair (fewer where fewer have a known
            disparity and texture).
        search_deg: with pairs, [low, high]: the vergence range searched on a pair without
            ground truth, degrees (default [-2, 8], about -9 to +36 eye px; within the vergence
            range): its points' windows lie inside both photos over all of it.
    """

    checkpoint: str = MISSING
    out: str = MISSING
    textures: Optional[str] = None
    renderer: Optional[RendererName] = None
    depths: list[float] = field(default_factory=lambda: list(DEFAULT_DISTANCES_M))
    batch_size: int = EVAL_BATCH_SIZE
    seed: int = 0
    figure: Optional[str] = None
    progress: bool = True
    policy: Policy = Policy.greedy
    readout: Optional[Readout] = None
    tracking: Optional[list[float]] = None
    depth_speed: float = 0.0
    skip: int = TRACKING_SKIP
    vergence_range_deg: Optional[list[float]] = None
    pairs: Optional[str] = None
    pair_scale: int = 1
    fixations: int = PAIR_FIXATIONS
    search_deg: Optional[list[float]] = None

    def __post_init__(self) -> None:
        if not self.depths:
            raise ValueError("depths must be a list of distances > 0 in metres such as [1.0,2.0], got []")
        for depth in self.depths:
            check_real(depth, "depths", above=0.0, unit="metres")
        check_int(self.batch_size, "batch_size", minimum=1)
        check_int(self.seed, "seed", minimum=0)
        check_int(self.skip, "skip", minimum=0)
        check_real(self.depth_speed, "depth_speed", unit="metres per iteration")
        if self.tracking is not None:
            if not self.tracking:
                raise ValueError("tracking must be a list of speeds >= 0 such as [0,0.5,1], got []")
            for speed in self.tracking:
                check_real(speed, "tracking", minimum=0.0, unit="degrees per iteration")
        if self.vergence_range_deg is not None:
            self.vergence_range_deg = list(check_oculomotor_range(PAN_RANGE_DEG, self.vergence_range_deg)[1])
        if self.tracking is None and (self.depth_speed != 0.0 or self.skip != TRACKING_SKIP):
            given = "depth_speed" if self.depth_speed != 0.0 else "skip"
            raise ValueError(f"{given} acts only in the tracking test: give tracking=[speeds] (e.g. "
                             f"tracking=[0,0.5,1]) too, or leave {given} out")
        if self.textures is not None and not os.path.isdir(self.textures):
            raise ValueError(f"textures: no such folder {self.textures!r}")
        self._check_pairs()
        check_checkpoint_file(self.checkpoint)
        # The outputs before the trials: a path that cannot be written fails now, not after them.
        check_output_file(self.out, "out", (".json",))
        if self.figure is not None:
            check_output_file(self.figure, "figure", (".png", ".pdf", ".svg"))

    def _check_pairs(self) -> None:
        check_int(self.pair_scale, "pair_scale", minimum=1)
        check_int(self.fixations, "fixations", minimum=1)
        if self.pairs is None:
            for name, default in (("pair_scale", 1), ("fixations", PAIR_FIXATIONS), ("search_deg", None)):
                if getattr(self, name) != default:
                    raise ValueError(f"{name} acts only on stereo pairs: give pairs=FOLDER too, or leave {name} out")
            return
        if self.search_deg is not None:
            if len(self.search_deg) != 2:
                raise ValueError(f"search_deg must be [low, high] in degrees, got {list(self.search_deg)}")
            low, high = (check_real(v, "search_deg", unit="degrees") for v in self.search_deg)
            if not low < high:
                raise ValueError(f"search_deg must be [low, high] with low < high, got {list(self.search_deg)}")
        for other in ("textures", "tracking", "figure"):
            if getattr(self, other) is not None:
                raise ValueError(f"pairs and {other} exclude each other: the pairs are the evaluation's images "
                                 f"(give one of them)")
        if not os.path.isdir(self.pairs):
            raise ValueError(f"pairs: no such folder {self.pairs!r} (a folder of stereo pairs)")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m aectorch.evaluate checkpoint=... out=... [key=value ...]`` (see ``--help``)."""
    return run(argv, EvaluateConfig, "aectorch.evaluate", _evaluate)


def _evaluate(args: EvaluateConfig) -> int:
    pairs = None if args.pairs is None else _read_pairs(args.pairs)  # a bad folder fails before the checkpoint loads
    payload = load_checkpoint(args.checkpoint)
    cfg, learner = load_learner(args.checkpoint, payload=payload)
    iteration = int(payload["iteration"])
    if args.readout is not None:
        for cue in learner.cues.values():
            cue.config.readout = Readout(args.readout)  # type: ignore[union-attr]  # a CueLearner
    vergence_range = None if args.vergence_range_deg is None else tuple(args.vergence_range_deg)
    protocol = resolve_protocol(cfg.env.protocol, renderer=args.renderer, vergence_range_deg=vergence_range)
    if pairs is not None:
        return _pairs(args, pairs, cfg, learner, protocol, iteration)
    if args.textures is None:
        bank, textures = TextureBank.default("test"), "default test bank"
    else:
        try:
            bank = TextureBank.from_folder(args.textures, progress=None if args.progress else False)
        except (ValueError, OSError) as err:
            raise ValueError(f"textures: {err}") from err
        textures = args.textures
    if args.tracking is not None:
        return _tracking(args, learner, bank, textures, protocol, iteration)
    result = evaluate(learner, bank, distances_m=list(args.depths), protocol=protocol, batch_size=args.batch_size,
                      seed=args.seed, progress=args.progress, policy=args.policy)
    result.update(checkpoint=args.checkpoint, textures=textures, renderer=str(protocol.renderer),
                  pan_range_deg=list(protocol.pan_range_deg), vergence_range_deg=list(protocol.vergence_range_deg),
                  iteration=iteration, source=checkpoint_source(args.checkpoint, iteration))
    _write(args.out, result)
    if args.figure:
        plot_evaluation(result, args.figure)
        note_output(args.figure)
    keys = [k for k in result if k.endswith("_mae_deg")] + ["depth_mae_m"]  # every eye movement's, then depth
    rows = [f"{'distance_m':>10} " + " ".join(f"{k:>{len(k) + 1}}" for k in keys)]
    for row in result["per_distance"] + [dict(result, distance_m="all")]:
        d = row["distance_m"]
        rows.append(f"{d if isinstance(d, str) else f'{d:.2f}':>10} "
                    + " ".join(f"{row[k]:>{len(k) + 1}.4f}" for k in keys))
    both = result["fractions"]["both"]
    rows.append(f"fixation ends with every eye movement within {WITHIN_DEG} deg: {both['within']:.1%}; "
                f"either beyond {BEYOND_DEG} deg: {both['beyond']:.1%}")
    last = result["last5"]
    rows.append("mean of each fixation's last 5 iterations: "
                + ", ".join(f"{k} {v:.4f}" for k, v in last.items() if k.endswith("_mae_deg"))
                + f"; every eye movement within {WITHIN_DEG} deg: {last['fractions']['both']['within']:.1%}")
    if "vergence_test" in result:
        deg = result["vergence_test"]["degrees"]
        test = result["vergence_test"]
        rows.append(f"vergence test: RMSE {deg['rmse']:.4f} deg, median {deg['median']:.4f} deg, n {deg['n']}, "
                    f"largest end {test['max_abs_deg']:.3f} deg, {test['beyond_1deg']:.1%} beyond 1 deg")
    rows.append(f"{result['trials']} trials, checkpoint iteration {iteration}; written to {args.out}")
    print("\n".join(rows))
    return 0


def _write(out: str, result: dict) -> None:
    """The result, whole or not at all; a run folder lists it as an output of its checkpoint (so
    that ``train.overwrite`` deletes it with the run)."""
    write_json(out, result)
    note_output(out)


def _read_pairs(folder: str) -> list:
    try:
        return read_pairs(folder)
    except (ValueError, OSError) as err:
        raise ValueError(f"pairs: {err}") from err


def _pairs(args: EvaluateConfig, pairs, cfg, learner, protocol, iteration: int) -> int:
    """The stereo pairs' evaluation (``pairs=FOLDER``): the learner's stereo cue and the matcher
    with its actions, from both kinds of start; its JSON and table."""
    cue = learner.cues["stereo"]
    matcher = Matcher(actions_deg=cue.config.actions_deg, scales=cue.config.scales)
    policies = {"learner": stereo_policy(learner), "matcher": lambda observation, world: matcher.increment_deg(observation)}
    scoring = Scoring(reward=coding_reward(learner), reference="matcher")
    if args.search_deg is not None:
        scoring = Scoring(scoring.reward, scoring.reference, (args.search_deg[0], args.search_deg[1]))
    spread = cfg.env.vergence_start_spread_deg
    start = (cfg.env.vergence_start_deg - spread, cfg.env.vergence_start_deg + spread)
    try:
        result = evaluate_pairs(policies, pairs, scales=[s.name for s in cue.encoder.scales], pair_scale=args.pair_scale,
                                fixations=args.fixations, steps=protocol.fixation_iterations, seed=args.seed,
                                start_vergence_deg=start, vergence_range_deg=protocol.vergence_range_deg,
                                scoring=scoring, batch_size=args.batch_size, progress=args.progress)
    except ValueError as err:
        raise ValueError(f"pairs: {err}") from err
    result.update(checkpoint=args.checkpoint, folder=args.pairs, iteration=iteration, matcher_actions_deg=list(
        cue.config.actions_deg), source=checkpoint_source(args.checkpoint, iteration))
    _write(args.out, result)
    rows = [f"{'policy':<12} {'start':<14} {'median |error| px':>18} {'within 1 px':>12} {'beyond 5 px':>12} "
            f"{'smooth median':>14} {'edge median':>12} {'visible median':>15} {'visible beyond 5 px':>20}"] \
        if result["summary"] else []
    for name, kinds in result["summary"].items():
        for kind in START_KINDS:
            s = kinds[kind]
            rows.append(f"{name:<12} {kind:<14} {s['all']['median_abs_px']:>18.3f} {s['all']['within_1px']:>12.1%} "
                        f"{s['all']['beyond_5px']:>12.1%} {s['smooth']['median_abs_px']:>14.3f} "
                        f"{s['edge']['median_abs_px']:>12.3f} {s['visible']['median_abs_px']:>15.3f} "
                        f"{s['visible']['beyond_5px']:>20.1%}")
    rows += _truthless_table(result)
    fixations = ", ".join(f"{p['name']} {p['fixations']}" for p in result["pairs"])
    rows.append(f"fixation points: {fixations}; pair_scale {args.pair_scale}, {result['steps']} iterations each; "
                f"checkpoint iteration {iteration}; written to {args.out}")
    print("\n".join(rows))
    return 0


def _truthless_table(result: dict) -> list[str]:
    """The table of the pairs without ground truth (none when every pair has it)."""
    if "without_ground_truth" not in result:
        return []
    part = result["without_ground_truth"]
    rows = [f"without ground truth ({', '.join(part['pairs'])}): the protocol's start only, searched over "
            f"{part['search_deg']} deg",
            f"{'policy':<12} {'median reward':>14} {'median sd px':>13} {'stable':>7} {'median |vs matcher| px':>23} "
            f"{'within 1 px':>12} {'beyond 5 px':>12} {'at the limit':>13}"]
    for name, kinds in part["summary"].items():
        s = kinds["protocol"]
        if name == "no_movement":
            rows.append(f"{name:<12} {s['median_reward']:>14.4f}  (the starts' reward)")
            continue
        agreement = (f"{s['median_agreement_px']:>23.3f} {s['agree_within_1px']:>12.1%} {s['agree_beyond_5px']:>12.1%}"
                     if name != part["reference"] else " " * 49)
        rows.append(f"{name:<12} {s['median_reward']:>14.4f} {s['median_stability_px']:>13.3f} {s['stable']:>7.1%} "
                    f"{agreement} {s['at_limit']:>13.1%}")
    return rows


def _tracking(args: EvaluateConfig, learner, bank: TextureBank, textures: str, protocol, iteration: int) -> int:
    """The moving object's test (``tracking=[...]``): its JSON, figure and table."""
    trials = run_tracking(learner, bank, speeds_deg=list(args.tracking),  # type: ignore[arg-type]  # set here
                          depth_speed_m=args.depth_speed,
                          distances_m=list(args.depths), protocol=protocol, skip=args.skip, batch_size=args.batch_size,
                          seed=args.seed, policy=args.policy, progress=args.progress)
    per_speed = tracking_by_speed(trials)
    result: dict[str, Any] = {
        "tracking": {"skip": args.skip, "depth_speed_m": args.depth_speed, "per_speed": per_speed,
                     "per_trial": tracking_rows(trials, bank.names)},
        "checkpoint": args.checkpoint, "textures": textures, "renderer": str(protocol.renderer),
        "iteration": iteration, "policy": str(args.policy),
        "source": checkpoint_source(args.checkpoint, iteration)}
    _write(args.out, result)
    if args.figure:
        plot_tracking([per_speed], args.figure)
        note_output(args.figure)
    keys = [key for key in per_speed[0] if key.endswith("_tracking_deg")]
    rows = [f"{'speed_deg':>10} " + " ".join(f"{k:>{len(k) + 1}}" for k in keys)]
    rows += [f"{row['speed_deg']:>10.2f} " + " ".join(f"{row[k]:>{len(k) + 1}.4f}" for k in keys) for row in per_speed]
    rows.append(f"mean |error| after each fixation's first {args.skip} iterations, depth speed {args.depth_speed:g} "
                f"m per iteration; {len(result['tracking']['per_trial'])} trials, checkpoint iteration {iteration}; "
                f"written to {args.out}")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
