"""Run the paper's experiment: train a `JointLearner` in `ActiveDepthEnv`, log, checkpoint, evaluate.

:func:`run_experiment` is what ``train.py`` calls with a validated :class:`ExperimentConfig`
and a run folder. It writes into the folder

- ``config.yaml``: the resolved config;
- ``provenance.json``: the aectorch, torch and Python versions, the git commit, device, CPU and
  host of the run, one entry per session (the first run and every resume; `aectorch.provenance`);
- ``metrics.jsonl``: one JSON line every ``train.log_every`` iterations (`aectorch.metrics`);
- ``tb/``: the same scalars as TensorBoard events;
- ``checkpoint.pt``: every ``train.checkpoint_every`` iterations, at the end and when
  interrupted (atomic: a temporary file in the same folder replaces the old one);
- ``figures/``: Fig. 2 (dictionaries), Fig. 3 (training), Fig. 4 (perturbation, when one is
  configured) and the evaluation figure (`aectorch.figures`);
- ``evaluation.json``: `aectorch.evaluate.evaluate` on held-out textures;
- ``summary.json``: final metrics, evaluation headline numbers, timing, perturbation recovery.

A run continues in place from its checkpoint (``train.resume=<run folder>``) and ends
bit-identical to an uninterrupted one (the learner's, the environments' and the metrics' state,
random generators included, are in the checkpoint).
"""

from __future__ import annotations

import copy
import json
import math
import os
import signal
import sys
import threading
import tempfile
import time
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from aectorch.config import ExperimentConfig, to_container, to_experiment_config, validate_resources
from aectorch.framework import _MIN_DEPTH_TRIALS, IterationRecord, JointLearner
from aectorch.metrics import CUES, TrainingMetrics
from aectorch.provenance import provenance
from aectorch.sim import ActiveDepthEnv, TextureBank
from aectorch.watchdog import Watchdog, WatchdogError

__all__ = [
    "CHECKPOINT_FORMAT",
    "build_env",
    "build_learner",
    "build_textures",
    "dictionaries",
    "checkpoint_config",
    "load_checkpoint",
    "load_learner",
    "restore",
    "resume_config",
    "run_experiment",
    "save_checkpoint",
]

CHECKPOINT_FORMAT = 1
#: Keys of ``train`` kept from the command line when a run is resumed (and the whole ``watchdog``
#: and ``record`` sections, which change nothing that is learned); everything else is the run's own.
RESUME_KEYS = ("iterations", "progress", "resume")


# -- building ------------------------------------------------------------------------------------
def set_threads(threads: int, processes: int = 1) -> None:
    """``train.threads``: N >= 1 gives torch and the fused kernels N threads each; 0 gives the fused
    kernels (render, pursuit) every core of this process's share and torch's own operations one
    (they are too small to pay for a second thread: docs/performance.md)."""
    from aectorch.coding import native

    torch.set_num_threads(threads or 1)
    native.set_threads(threads or available_threads(processes))


def available_threads(processes: int = 1) -> int:
    """``train.threads=0``: the cores this process may use, shared among ``processes`` (>= 1)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    return max(1, cores // max(1, processes))



def build_textures(folder: str | None, split: str, cfg: ExperimentConfig) -> TextureBank:
    """``TextureBank.from_folder(folder)``, or ``TextureBank.default(split)`` when ``folder`` is None."""
    kwargs = dict(dtype=cfg.env.torch_dtype)
    if folder is None:
        return TextureBank.default(split, **kwargs)
    return TextureBank.from_folder(folder, progress=None if cfg.train.progress else False, **kwargs)


def trial_options(cfg: ExperimentConfig) -> dict:
    """The keyword arguments of `aectorch.evaluate.evaluate` and `run_trials` that ``cfg`` sets.

    The renderer, the fixation length and the body shift of the run's environments, and the
    evaluation's batch size: what the end of `run_experiment` evaluates with.
    """
    return dict(renderer=cfg.env.renderer, batch_size=cfg.eval.batch_size,
                fixation_iterations=cfg.env.fixation_iterations, shift_m=cfg.env.shift_m,
                shift_iterations=cfg.env.shift_iterations, yoked_pursuit=cfg.env.yoked_pursuit)


def _start(value: float, spread: float) -> float | tuple[float, float]:
    """A start angle for `ActiveDepthEnv`: the value, or the range ``value +- spread``."""
    return (value - spread, value + spread) if spread > 0 else value


def build_env(cfg: ExperimentConfig, shard=None) -> ActiveDepthEnv:
    """The training environments of ``cfg.env``, seeded from ``cfg.seed`` (this rank's slice of the
    whole batch under `aectorch.distributed`)."""
    e = cfg.env
    return ActiveDepthEnv(
        e.num_envs,
        textures=build_textures(e.textures, "train", cfg),
        renderer=e.renderer,
        distances_m=e.distances_m,
        fixation_iterations=e.fixation_iterations,
        shift_m=e.shift_m,
        shift_iterations=e.shift_iterations,
        yoked_pursuit=e.yoked_pursuit,
        pursuit_start_deg=_start(e.pursuit_start_deg, e.pursuit_start_spread_deg),
        vergence_start_deg=_start(e.vergence_start_deg, e.vergence_start_spread_deg),
        seed=cfg.seed,
        device=e.device,
        dtype=e.torch_dtype,
        batch_slice=None if shard is None else (shard.start, shard.total),
    )


def build_learner(cfg: ExperimentConfig, device: str | torch.device | None = None, shard=None) -> JointLearner:
    """A fresh :class:`JointLearner` of ``cfg.learner``, its generator seeded from ``cfg.seed``."""
    return JointLearner(
        cfg.learner,
        generator=torch.Generator().manual_seed(cfg.seed),
        dtype=cfg.env.torch_dtype,
        device=cfg.env.device if device is None else device,
        shard=shard,
    )


def dictionaries(learner: JointLearner) -> dict[str, torch.Tensor]:
    """Copies of the learner's dictionaries ``{"parallax/coarse": atoms [P, N], ...}`` on the CPU."""
    return {
        f"{cue}/{name}": d.atoms.detach().cpu().clone()
        for cue in CUES
        for name, d in getattr(learner, cue).dictionaries.items()
    }


def _compile(learner: JointLearner, env: ActiveDepthEnv | None = None) -> None:
    # The hot path: both encoders (patch extraction, pursuit, pooling, errors) and the torch
    # renderer (about 20 elementwise passes per pixel in eager mode, fused when compiled).
    for cue in CUES:
        getattr(learner, cue).compile()
    if env is not None and isinstance(env.renderer, torch.nn.Module):
        env.renderer.compile(dynamic=False)


# -- checkpoints -----------------------------------------------------------------------------------
def save_checkpoint(path: str | os.PathLike, payload: dict) -> None:
    """Write ``payload`` with ``torch.save`` atomically (temporary file, fsync, ``os.replace``)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read a checkpoint written by :func:`save_checkpoint`; ``ValueError`` naming the path if it
    is missing, unreadable or not an aectorch checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no checkpoint at {str(path)!r}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:
        raise ValueError(f"cannot read the checkpoint {str(path)!r}: {type(err).__name__}: {err}") from err
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{str(path)!r} is not an aectorch checkpoint (format {CHECKPOINT_FORMAT})")
    return payload


def checkpoint_config(payload: dict, path: str | os.PathLike) -> ExperimentConfig:
    """The validated config stored in a checkpoint; ``ValueError`` naming ``path`` if this version
    of aectorch cannot read it."""
    # The watchdog and the recording change nothing that is learned and come from the command line
    # on resume, so a checkpoint from a version with other watchdog options still loads.
    stored = {k: v for k, v in payload["config"].items() if k not in ("watchdog", "record")}
    # Checkpoints from before `learner.symmetry` existed learned without the symmetries.
    if isinstance(stored.get("learner"), dict) and "symmetry" not in stored["learner"]:
        stored["learner"] = {**stored["learner"], "symmetry": []}
    # Checkpoints from before the body movement's profile existed shifted at once, one eye pursuing.
    if isinstance(stored.get("env"), dict) and "shift_iterations" not in stored["env"]:
        stored["env"] = {**stored["env"], "shift_iterations": 1, "yoked_pursuit": False}
    # Checkpoints from before `learner.render_scales` existed reduced whole crops with the pyramid.
    if isinstance(stored.get("learner"), dict) and "render_scales" not in stored["learner"]:
        stored["learner"] = {**stored["learner"], "render_scales": False}
    try:
        return to_experiment_config(stored)
    except Exception as err:  # unknown keys, wrong types, impossible values
        raise ValueError(f"the checkpoint {str(path)!r} holds a config this aectorch cannot use "
                         f"({type(err).__name__}: {str(err).strip().splitlines()[0]})") from err


def restore(target, state: dict, path: str | os.PathLike, what: str) -> None:
    """``target.load_state_dict(state)``; ``ValueError`` naming ``path`` when they do not fit."""
    try:
        target.load_state_dict(state)
    except Exception as err:  # missing/unexpected keys, shape mismatches
        raise ValueError(f"the {what} state in {str(path)!r} does not fit its config "
                         f"({type(err).__name__}: {str(err).strip().splitlines()[0]}); was it written "
                         "by an incompatible aectorch version?") from err


def load_learner(checkpoint_path: str | os.PathLike, device=None) -> tuple[ExperimentConfig, JointLearner]:
    """The config and the trained learner of a checkpoint (on ``device``, default the run's)."""
    payload = load_checkpoint(checkpoint_path)
    cfg = checkpoint_config(payload, checkpoint_path)
    learner = build_learner(cfg, device=device)
    restore(learner, payload["learner"], checkpoint_path, "learner")
    return cfg, learner


def resume_config(cfg: ExperimentConfig, checkpoint: dict) -> ExperimentConfig:
    """The stored config of ``checkpoint`` with ``train.iterations/progress/resume`` of ``cfg``."""
    where = Path(cfg.train.resume) / "checkpoint.pt" if cfg.train.resume else "the checkpoint"
    stored = to_container(checkpoint_config(checkpoint, where))
    for key in RESUME_KEYS:
        stored["train"][key] = getattr(cfg.train, key)
    mine = to_container(cfg)
    stored["watchdog"], stored["record"] = mine["watchdog"], mine["record"]
    return to_experiment_config(stored)


# -- the run -------------------------------------------------------------------------------------
def _json_value(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else value
    return value


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2, allow_nan=True) + "\n")


def _truncate_metrics(path: Path, iteration: int) -> None:
    """Keep the lines up to the checkpoint's iteration; a line torn by a kill mid-write is dropped."""
    if not path.exists():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # only the last line can be torn, and it is after the checkpoint
        if record["iteration"] <= iteration:
            kept.append(line)
    path.write_text("".join(line + "\n" for line in kept))


def _state(learner, env, metrics, watchdog, shard=None) -> dict:
    # Under torch.distributed the learners are identical; the environments are each rank's own.
    return {
        "learner": copy.deepcopy(learner.state_dict()),
        "env": env.state_dict() if shard is None else shard.gather_objects(env.state_dict()),
        "metrics": metrics.state_dict(),
        "watchdog": watchdog.state_dict(),
    }


def _sigterm(signum, frame):
    raise KeyboardInterrupt(f"terminated by signal {signum}")


def _interrupt_on_sigterm():
    """Make SIGTERM (``kill``, ``timeout``, a batch scheduler) interrupt like Ctrl-C does, so the
    last completed iteration is checkpointed; returns the previous handler (``None`` when not
    in the main thread, where handlers cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _sigterm)


def run_experiment(
    cfg: ExperimentConfig,
    run_dir: str | os.PathLike,
    *,
    callback: Callable[[int, IterationRecord], None] | None = None,
) -> dict:
    """Train, log, checkpoint, draw and evaluate; returns the final summary (``summary.json``).

    Args:
        cfg: the experiment. With ``cfg.train.resume`` set, the run continues in that folder
            (``run_dir`` is ignored) with its stored config (see :func:`resume_config`).
        run_dir: the run folder (created if needed).
        callback: called as ``callback(iteration, record)`` after every learner iteration
            (1-based count of completed iterations); an exception it raises interrupts the run
            like Ctrl-C does (a checkpoint of the last completed iteration is written first).
    """
    checkpoint = None
    if cfg.train.resume is not None:  # the stored config decides everything, from here on
        checkpoint = load_checkpoint(Path(cfg.train.resume) / "checkpoint.pt")
        cfg = resume_config(cfg, checkpoint)
    validate_resources(cfg)
    previous = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled())
    if cfg.train.deterministic:
        if torch.device(cfg.env.device).type == "cuda":
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # cuBLAS's condition for it
        torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        return _run(cfg, run_dir, callback, checkpoint)
    finally:  # a process-wide switch: leave it as the caller had it
        torch.use_deterministic_algorithms(previous[0], warn_only=previous[1])


def _run(cfg: ExperimentConfig, run_dir, callback, checkpoint: dict | None) -> dict:
    from aectorch import distributed

    shard = distributed.setup(cfg.env.num_envs, cfg.env.device)
    try:
        return _train(cfg, run_dir, callback, shard, checkpoint)
    finally:
        distributed.teardown()


def _train(cfg: ExperimentConfig, run_dir, callback, shard, checkpoint: dict | None) -> dict:
    """The run; ``cfg`` is already the stored config when ``checkpoint`` (the resumed state) is given."""
    from omegaconf import OmegaConf

    main = shard is None or shard.is_main  # the process that writes the run folder
    # Early stopping by the training window (`train.keep_best`): the best score and its iteration.
    best: dict = {"iteration": None, "score": None}
    if checkpoint is not None:
        run_dir = Path(cfg.train.resume)
    batch = cfg.env.num_envs if shard is None else shard.total
    set_threads(cfg.train.threads, 1 if shard is None else shard.world_size)
    run_dir = Path(run_dir)
    if main:
        run_dir.mkdir(parents=True, exist_ok=True)
    total = cfg.train.iterations

    env = build_env(cfg, shard)
    learner = build_learner(cfg, shard=shard)
    metrics = TrainingMetrics(batch, scales=cfg.learner.scales, window_fixations=cfg.train.metrics_window,
                              window_trials=cfg.train.metrics_window)
    watchdog = Watchdog(cfg.watchdog)
    if checkpoint is not None:
        path = run_dir / "checkpoint.pt"
        restore(learner, checkpoint["learner"], path, "learner")
        env_state = checkpoint["env"]
        if shard is not None or isinstance(env_state, list):
            world = 1 if shard is None else shard.world_size
            if not isinstance(env_state, list) or len(env_state) != world:
                raise ValueError(f"the checkpoint {str(path)!r} holds the environments of "
                                 f"{len(env_state) if isinstance(env_state, list) else 1} process(es); "
                                 f"resume it with as many (this run has {world})")
            env_state = env_state[0 if shard is None else shard.rank]
        restore(env, env_state, path, "environment")
        restore(metrics, checkpoint["metrics"], path, "metrics")
        if "watchdog" in checkpoint:
            restore(watchdog, checkpoint["watchdog"], path, "watchdog")
        start = int(checkpoint["iteration"])
        best = dict(checkpoint.get("best") or best)
        initial = checkpoint["initial_dictionaries"]
        elapsed_before = float(checkpoint["elapsed_s"])
        if main:
            print(f"resuming {run_dir} at iteration {start} of {total}", file=sys.stderr)
    else:
        start, initial, elapsed_before = 0, dictionaries(learner), 0.0
    config_dict = to_container(cfg)
    session = {**provenance(cfg.env.device), "start_iteration": start,
               "world_size": 1 if shard is None else shard.world_size}
    metrics_path = run_dir / "metrics.jsonl"
    if main:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(OmegaConf.create(config_dict)))
        provenance_path = run_dir / "provenance.json"
        sessions = json.loads(provenance_path.read_text())["sessions"] if checkpoint is not None \
            and provenance_path.exists() else []
        _write_json(provenance_path, {"sessions": sessions + [session]})
        if checkpoint is None:
            metrics_path.write_text("")
        else:
            _truncate_metrics(metrics_path, start)
    writer = None
    if cfg.train.tensorboard and main:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(log_dir=str(run_dir / "tb"), purge_step=start + 1 if start else None)
    if cfg.train.compile:
        _compile(learner, env)
    events = cfg.perturbation.events(total)
    recorder, stepped = None, env  # the environment the learner steps (observed when recording)
    if cfg.record.lerobot is not None and main:
        from aectorch.integrations.lerobot import LeRobotRecorder

        recorder = LeRobotRecorder(cfg.record.lerobot, env, envs=cfg.record.envs)
        stepped = recorder.wrap(env)

    def payload(iteration: int, state: dict, elapsed: float) -> dict:
        return {"format": CHECKPOINT_FORMAT, "config": config_dict, "iteration": iteration,
                **state, "initial_dictionaries": initial, "elapsed_s": elapsed, "best": dict(best)}

    bar = None
    if cfg.train.progress and main:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=start, desc="training", unit="it", dynamic_ncols=True)
    clock = time.perf_counter()
    elapsed = lambda: elapsed_before + time.perf_counter() - clock  # noqa: E731
    last = (start, _state(learner, env, metrics, watchdog, shard))  # the last completed (healthy) iteration
    it = start
    previous_sigterm = _interrupt_on_sigterm()
    try:
        with (metrics_path if main else Path(os.devnull)).open("a") as log:
            for it in range(start, total):
                for when, roll, label in events:
                    if it == when:
                        env.set_roll(torch.tensor(roll))
                        if bar is not None:
                            bar.write(f"iteration {it}: {label} by {cfg.perturbation.roll_deg} deg")
                record = learner.iteration(stepped)
                if recorder is not None:
                    recorder.after_iteration(record)
                if shard is not None:  # every rank sees the whole batch's record
                    record = shard.gather_record(record)
                metrics.update(record)
                done = it + 1
                if callback is not None:
                    callback(done, record)
                watchdog.check(done, record, learner)  # raises in mode "stop": `last` is healthy
                logged = done % cfg.train.log_every == 0 or done == total
                if logged:
                    roll = env.roll_deg[0].tolist()
                    line = {"iteration": done, "env_iterations": done * batch,
                            "elapsed_s": elapsed(), "roll_left_deg": roll[0], "roll_right_deg": roll[1],
                            **metrics.summary()}
                    log.write(json.dumps({k: _json_value(v) for k, v in line.items()}) + "\n")
                    log.flush()
                    if writer is not None:
                        for key, value in line.items():
                            if key != "iteration" and value is not None and math.isfinite(value):
                                writer.add_scalar(key, value, done)
                    if bar is not None:
                        bar.set_postfix(pursuit=f"{line['pursuit_mae_deg']:.3f}",
                                        vergence=f"{line['vergence_mae_deg']:.3f}",
                                        depth=f"{line['depth_mae_m']:.3f}", refresh=False)
                state = _state(learner, env, metrics, watchdog, shard)
                if logged and cfg.train.keep_best and metrics.window_full:
                    score = line["pursuit_mae_deg"] + line["vergence_mae_deg"]
                    if best["score"] is None or score < best["score"]:
                        best.update(iteration=done, score=score, pursuit_mae_deg=line["pursuit_mae_deg"],
                                    vergence_mae_deg=line["vergence_mae_deg"], depth_mae_m=line["depth_mae_m"])
                        if main:
                            save_checkpoint(run_dir / "best.pt", payload(done, state, elapsed()))
                if main and (done % cfg.train.checkpoint_every == 0 or done == total):
                    save_checkpoint(run_dir / "checkpoint.pt", payload(done, state, elapsed()))
                last = (done, state)
                if bar is not None:
                    bar.update(1)
    except BaseException as err:
        done, state = last
        if not main:
            raise
        if done > start or checkpoint is None:
            save_checkpoint(run_dir / "checkpoint.pt", payload(done, state, elapsed()))
        if isinstance(err, WatchdogError):
            print(
                f"\n{err}\nstopped; {run_dir / 'checkpoint.pt'} holds iteration {done}, the last healthy "
                f"one. Resuming it repeats the same computation; watchdog.mode=warn continues past the "
                f"check: python train.py train.resume={run_dir} watchdog.mode=warn",
                file=sys.stderr,
            )
        else:
            print(
                f"\ninterrupted after iteration {done} of {total}; checkpoint written to "
                f"{run_dir / 'checkpoint.pt'}\nresume with: python train.py train.resume={run_dir}",
                file=sys.stderr,
            )
        raise
    finally:
        if recorder is not None:
            recorder.close()  # the episodes saved so far stay a valid dataset
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.close()
    train_seconds = elapsed()
    if not main:
        return {}
    return _finish(cfg, run_dir, learner, env, initial, events, train_seconds, session, best)


def _finish(cfg, run_dir: Path, learner, env, initial, events, train_seconds, session: dict,
            best: dict) -> dict:
    total = cfg.train.iterations
    records = _read_lines(run_dir / "metrics.jsonl")
    # The last line (always written at the last iteration) holds the final interval's averages.
    bookkeeping = ("iteration", "env_iterations", "elapsed_s", "roll_left_deg", "roll_right_deg")
    final = {k: v for k, v in (records[-1] if records else {}).items() if k not in bookkeeping}
    labels = [(when + 1, label) for when, _, label in events]
    world = session.get("world_size", 1)
    summary: dict = {
        "iterations": total,
        "env_iterations": total * cfg.env.num_envs * world,
        "train_seconds": train_seconds,
        "iterations_per_s": total / max(train_seconds, 1e-9),
        "final": {k: _json_value(v) for k, v in final.items()},
        "provenance": session,
    }
    figures = None
    if cfg.train.figures:
        try:
            import aectorch.figures as figures
        except ModuleNotFoundError as err:
            if err.name != "aectorch.figures":
                raise
            print("aectorch.figures is not available: no figures drawn", file=sys.stderr)
    if figures is not None:
        folder = run_dir / "figures"
        folder.mkdir(exist_ok=True)
        records = figures.read_metrics(run_dir / "metrics.jsonl")
        figures.plot_dictionaries(initial, dictionaries(learner), folder / "dictionaries.png")
        figures.plot_training(records, folder / "training.png", events=labels)
        if events:
            figures.plot_perturbation(records, folder / "perturbation.png", events=labels)
    if events:
        recovery = {}
        recover = getattr(figures, "recovery", None) if figures is not None else None
        for when, label in labels:
            if recover is not None:
                recovery[label] = {key: recover(records, key, when)
                                   for key in ("pursuit_mae_deg", "vergence_mae_deg")}
        summary["perturbation"] = {"roll_deg": cfg.perturbation.roll_deg,
                                   "events": [{"iteration": w, "label": lab} for w, lab in labels],
                                   "recovery": recovery}
    close = getattr(env.renderer, "close", None)
    if close is not None:
        close()
    if best["iteration"] is not None:
        summary["best"] = {k: _json_value(v) for k, v in best.items()}
    if cfg.eval.enabled:
        from aectorch.evaluate import evaluate

        evaluated = "checkpoint.pt"
        if cfg.train.keep_best and (run_dir / "best.pt").exists():
            evaluated = "best.pt"  # the learner of the best training window
            restore(learner, load_checkpoint(run_dir / "best.pt")["learner"], run_dir / "best.pt", "learner")
        done = calibrate_depth(cfg, learner, env.textures) if cfg.train.depth_calibration_trials > 0 else None
        if done is not None:
            summary["depth_calibration"] = done
        if done is not None and not done["skipped"]:
            before = "n/a" if done["depth_mae_m_before"] is None else f"{done['depth_mae_m_before']:.4g}"
            print(f"depth calibration: the MLP refitted on {done['trials']} greedy trials of "
                  f"{done['textures']} training textures (their depth MAE {before} -> "
                  f"{done['depth_mae_m_after']:.4g} m); written to {run_dir / 'calibrated.pt'}")
            stored = load_checkpoint(run_dir / evaluated)
            stored["learner"] = copy.deepcopy(learner.state_dict())
            stored["depth_calibration"] = {"source": evaluated, **done}
            save_checkpoint(run_dir / "calibrated.pt", stored)
            evaluated = "calibrated.pt"

        bank = build_textures(cfg.eval.textures, "test", cfg)
        result = evaluate(learner, bank, distances_m=cfg.eval.distances_m, progress=cfg.train.progress,
                          **trial_options(cfg))
        _write_json(run_dir / "evaluation.json", result)
        if figures is not None:
            figures.plot_evaluation(result, run_dir / "figures" / "evaluation.png")
        summary["evaluation"] = {k: result[k] for k in ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m", "trials")}
        summary["evaluation"]["checkpoint"] = evaluated
        if "vergence_test" in result:
            summary["evaluation"]["vergence_test_rmse_deg"] = result["vergence_test"]["degrees"]["rmse"]
    _write_json(run_dir / "summary.json", summary)
    _print_table(summary, run_dir)
    return summary


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
    :func:`aectorch.evaluate.run_trials`), then :meth:`JointLearner.calibrate_depth` refits the
    MLP on their final eye angles. Returns what it did (JSON-ready): the trials, the depth MAE on
    them before and after, and the fit's epochs and stop reason.
    """
    from aectorch.evaluate import run_trials

    count = cfg.train.depth_calibration_trials
    if count < _MIN_DEPTH_TRIALS:
        print(f"depth calibration skipped: {count} trials, fewer than the {_MIN_DEPTH_TRIALS} a fit needs",
              file=sys.stderr)
        return {"trials": count, "skipped": True}
    distances = [float(d) for d in cfg.env.distances_m]
    conditions = calibration_conditions(count, len(bank), distances)
    trials = run_trials(learner, bank, distances_m=distances, seed=cfg.seed, conditions=conditions,
                        progress="depth calibration" if cfg.train.progress else False, **trial_options(cfg))
    before = trials["depth_error_m"].abs().mean().item()
    fit = learner.calibrate_depth(trials["q_deg"], trials["distance_m"], seed=cfg.seed)
    after = (learner.predict_depth(trials["q_deg"]).cpu().double() - trials["distance_m"]).abs().mean().item()
    return {"trials": count, "textures": min(count, len(bank)), "skipped": False,
            "depth_mae_m_before": _json_value(before), "depth_mae_m_after": _json_value(after),
            "epochs": int(fit.epochs), "stop": str(fit.stop_reason)}


def _read_lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _print_table(summary: dict, run_dir: Path) -> None:
    def fmt(v):
        return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"

    final, evaluation = summary["final"], summary.get("evaluation", {})
    rows = [("", "training (window)", "evaluation")]
    for key in ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m"):
        rows.append((key, fmt(final.get(key)), fmt(evaluation.get(key))))
    lines = [f"{a:<18}{b:>18}{c:>14}" for a, b, c in rows]
    rate = summary["iterations_per_s"]
    lines.append(f"{summary['iterations']} iterations in {summary['train_seconds']:.1f} s"
                 + (f" ({rate:.2f} it/s)" if rate else "") + f"; run folder: {run_dir}")
    print("\n".join(lines))
