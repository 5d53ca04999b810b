"""The end of a run: the learned code's read-outs, figures, the perturbation's recovery, depth
calibration, the evaluation and ``summary.json``."""

from __future__ import annotations

import copy
import json
import logging
import signal

import torch
from torch import Tensor

from aectorch.coding.readouts import code_summary
from aectorch.evaluation import adaptation, evaluate, run_trials
from aectorch.framework import MIN_DEPTH_TRIALS, JointLearner
from aectorch.runtime.builders import build_textures, dictionaries, trial_options
from aectorch.runtime.checkpoint import load_checkpoint, restore, save_checkpoint
from aectorch.runtime.config import ExperimentConfig
from aectorch.runtime.loop import _interrupt_on_sigterm
from aectorch.runtime.outputs import CODE_AT_ENDS, RunFolder, json_value
from aectorch.runs import checkpoint_source, read_metrics
from aectorch.sim import TextureBank

__all__ = ["calibrate_depth", "calibration_conditions", "finish"]

log = logging.getLogger("aectorch")

#: metrics.jsonl's bookkeeping columns, not the final metrics of ``summary.json``.
_BOOKKEEPING = ("iteration", "env_iterations", "elapsed_s", "roll_left_deg", "roll_right_deg", "perturbations")


def _errors(record: dict) -> list[str]:
    """The keys of ``record`` that are task errors (``<movement>_mae_deg``, ``depth_mae_m``)."""
    return [k for k in record if k.endswith(("_mae_deg", "_mae_m"))]


def finish(run) -> dict:
    """The end of a run (a `TrainingRun` after `TrainingRun.run`): draw the figures, evaluate
    (``best.pt``, calibrated when asked) and write ``summary.json``.

    Ctrl-C or SIGTERM here stops with one line: ``checkpoint.pt`` already holds the finished
    training, and ``train.resume=<run>`` does these steps again without training (each file is
    written whole or not at all, so nothing half-written is left to misread)."""
    previous_sigterm = _interrupt_on_sigterm()
    try:
        return _finish(run)
    except KeyboardInterrupt:
        log.warning("\ninterrupted while finishing the run (figures, depth calibration, evaluation, summary); "
                    "%s holds the finished training; resume with: python train.py train.resume=%s (it does "
                    "the missing steps without training again)", run.folder / "checkpoint.pt", run.folder.path)
        raise
    finally:
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)


def _finish(run) -> dict:
    cfg, folder = run.cfg, run.folder
    total = cfg.train.iterations
    records = read_metrics(folder.metrics_path)
    # The last line (always written at the last iteration) holds the final interval's averages.
    final = {k: v for k, v in (records[-1] if records else {}).items() if k not in _BOOKKEEPING}
    changes = _changes(run.schedule, total)
    labels = [(change + 1, label) for change, _, label in changes]
    summary: dict = {
        "iterations": total,
        "env_iterations": total * cfg.env.num_envs * run.session.get("world_size", 1),
        "train_seconds": run.train_seconds,
        "iterations_per_s": total / max(run.train_seconds, 1e-9),
        "final": {k: json_value(v) for k, v in final.items()},
        "provenance": run.session,
    }
    # The read-outs of the code as training left it (before best.pt is restored for the evaluation),
    # and of its random start: the chance level of each histogram.
    summary["code"] = {name: code_summary(atoms) for name, atoms in dictionaries(run.learner).items()}
    summary["code_initial"] = {name: code_summary(atoms) for name, atoms in run.initial.items()}
    readout = adaptation(records, changes) if changes else None
    figures = _figures(cfg, folder, run.initial, run.learner, labels, (summary["code"], summary["code_initial"]),
                       readout)
    if changes:
        summary["perturbation"] = {
            "roll_deg": cfg.perturbation.roll_deg,
            "events": [{"iteration": event.start + 1, **event.as_dict()} for event in run.schedule.events],
            "plasticity": {"raise_to": cfg.plasticity.raise_to,
                           "floor": {cue: c.encoder.floor for cue, c in cfg.learner.cues.items()}},
            "recovery": readout,
        }
        at_ends = _code_at_ends(folder, run.schedule)
        if at_ends:  # the code as each perturbation left it, read when it ended (a correction)
            summary["perturbation"]["code"] = at_ends
    if run.best["iteration"] is not None:
        summary["best"] = {k: json_value(v) for k, v in run.best.items()}
    if cfg.eval.enabled:
        summary.update(_evaluate(cfg, folder, run.learner, run.env.textures, figures))
    folder.write_json("summary.json", summary)
    return summary


def _code_at_ends(folder: RunFolder, schedule) -> dict:
    """The code's read-outs at the events' ends (`aectorch.runtime.outputs.CODE_AT_ENDS`) of this
    run's schedule: ``{"<label> ends": {"iteration", "code"}}``; empty without an end."""
    path = folder / CODE_AT_ENDS
    if not path.is_file():
        return {}
    ends = {event.end for event in schedule.events if event.end is not None}
    return {label: entry for label, entry in json.loads(path.read_text()).items() if entry["iteration"] in ends}


def _changes(schedule, total: int) -> list[tuple[int, int, str]]:
    """``(iteration, stop, label)`` of every event's start and end: the iteration (0-based) it acts
    from, the next change (or the run's end), the label (``<label> ends`` for an end)."""
    stretches = dict(schedule.stretches(total))
    out = []
    for change in sorted(stretches):
        names = [e.label for e in schedule.starting(change)] + [f"{e.label} ends" for e in schedule.ending(change)]
        out.append((change, stretches[change], " + ".join(names)))
    return out


def _figures(cfg: ExperimentConfig, folder: RunFolder, initial: dict, learner, labels, code, readout=None):
    """Fig. 2 (dictionaries), Fig. 3 (training), Fig. 4 (perturbation, with ``readout``, the
    adaptation read-out) and the code's read-outs (``code``: those of the trained and the initial
    dictionaries); the figures module, or ``None`` when figures are off or cannot be drawn."""
    if not cfg.train.figures:
        return None
    try:
        import aectorch.figures as figures
    except ModuleNotFoundError as err:
        if err.name != "aectorch.figures":
            raise
        log.warning("aectorch.figures is not available: no figures drawn")
        return None
    out = folder / "figures"
    out.mkdir(exist_ok=True)
    records = read_metrics(folder.metrics_path)
    figures.plot_dictionaries(initial, dictionaries(learner), out / "dictionaries.png")
    figures.plot_training(records, out / "training.png", events=labels)
    figures.plot_code(code[0], out / "code.png", initial=code[1])
    if labels:
        figures.plot_perturbation(records, out / "perturbation.png", events=labels, readout=readout)
    return figures


def _evaluate(cfg: ExperimentConfig, folder: RunFolder, learner: JointLearner, train_bank: TextureBank,
              figures) -> dict:
    """Evaluate best.pt (or the last state), after the depth calibration when asked; writes
    evaluation.json and returns the summary's entries."""
    out: dict = {}
    evaluated = "checkpoint.pt"
    if cfg.train.keep_best and (folder / "best.pt").exists():
        evaluated = "best.pt"  # the learner of the best training window
        restore(learner, load_checkpoint(folder / "best.pt")["learner"], folder / "best.pt", "learner")
    done = calibrate_depth(cfg, learner, train_bank) if cfg.train.depth_calibration_trials > 0 else None
    if done is not None:
        out["depth_calibration"] = done
    if done is not None and not done["skipped"]:
        before = "n/a" if done["depth_mae_m_before"] is None else f"{done['depth_mae_m_before']:.4g}"
        log.info("depth calibration: the MLP refitted on %d greedy trials of %d training textures (their depth "
                 "MAE %s -> %.4g m); written to %s", done["trials"], done["textures"], before,
                 done["depth_mae_m_after"], folder / "calibrated.pt")
        stored = load_checkpoint(folder / evaluated)
        stored["learner"] = copy.deepcopy(learner.state_dict())
        stored["depth_calibration"] = {"source": evaluated, **done}
        save_checkpoint(folder / "calibrated.pt", stored)
        evaluated = "calibrated.pt"
    bank = build_textures(cfg.eval.textures, "test", cfg)
    result = evaluate(learner, bank, distances_m=cfg.eval.distances_m, progress=cfg.train.progress,
                      **trial_options(cfg))
    # What it was made from: a report reading it after the folder's checkpoint changed says so.
    result["source"] = checkpoint_source(folder / evaluated, load_checkpoint(folder / evaluated)["iteration"])
    folder.write_json("evaluation.json", result)
    if figures is not None:
        figures.plot_evaluation(result, folder / "figures" / "evaluation.png")
    out["evaluation"] = {k: result[k] for k in (*_errors(result), "trials")}
    out["evaluation"]["checkpoint"] = evaluated
    if "vergence_test" in result:
        out["evaluation"]["vergence_test_rmse_deg"] = result["vergence_test"]["degrees"]["rmse"]
    return out


def calibration_conditions(count: int, num_textures: int, distances: list[float], *,
                           design: str = "spread") -> tuple[Tensor, Tensor]:
    """The ``(texture_index, distance_m)`` of ``count`` depth-calibration trials.

    ``"spread"`` (what ``train.depth_calibration_trials`` runs): trial i shows texture
    i mod ``num_textures`` at ``distances[i mod len(distances)]``. ``"grid"``: the first
    ``count / len(distances)`` textures, each at every distance.
    """
    i = torch.arange(count)
    if design == "spread":
        index = i % num_textures
    elif design == "grid":
        index = i // len(distances)
        if count and int(index.max()) >= num_textures:
            raise ValueError(f"a grid of {count} trials needs {int(index.max()) + 1} textures, got {num_textures}")
    else:
        raise ValueError(f"design must be 'spread' or 'grid', got {design!r}")
    return index, torch.tensor(distances, dtype=torch.float64)[i % len(distances)]


def calibrate_depth(cfg: ExperimentConfig, learner: JointLearner, bank: TextureBank) -> dict:
    """``train.depth_calibration_trials``: refit ``learner``'s depth MLP on its greedy trials.

    ``cfg.train.depth_calibration_trials`` greedy, frozen trials on the training textures
    ``bank`` (trial i: texture i mod T, distance i mod the number of ``cfg.env.distances_m``;
    :func:`aectorch.evaluation.run_trials`), then :meth:`JointLearner.calibrate_depth` refits the
    MLP on their final eye angles. Returns what it did (JSON-ready): the trials, the depth MAE on
    them before and after, and the fit's epochs and stop reason.
    """
    count = cfg.train.depth_calibration_trials
    if count < MIN_DEPTH_TRIALS:
        log.warning("depth calibration skipped: %d trials, fewer than the %d a fit needs", count, MIN_DEPTH_TRIALS)
        return {"trials": count, "skipped": True}
    distances = [float(d) for d in cfg.env.distances_m]
    conditions = calibration_conditions(count, len(bank), distances)
    trials = run_trials(learner, bank, distances_m=distances, seed=cfg.seed, conditions=conditions,
                        progress="depth calibration" if cfg.train.progress else False, **trial_options(cfg))
    before = trials["depth_error_m"].abs().mean().item()
    fit = learner.calibrate_depth(trials["q_deg"], trials["distance_m"], seed=cfg.seed)
    after = (learner.predict_depth(trials["q_deg"]).cpu().double() - trials["distance_m"]).abs().mean().item()
    return {"trials": count, "textures": min(count, len(bank)), "skipped": False,
            "depth_mae_m_before": json_value(before), "depth_mae_m_after": json_value(after),
            "epochs": int(fit.epochs), "stop": str(fit.stop_reason)}
