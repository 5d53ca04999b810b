"""The training loop and its extras as callbacks: log, keep the best state, checkpoint, stop cleanly.

:class:`TrainingRun` holds one process's part of a run (its shard of the environments, the
learner, the metrics) and the run folder, and runs the loop: each iteration the callbacks'
``before_iteration``, the learner's iteration (``watch``: what a callback wants to see of the
observations), the metrics, then the callbacks' ``after_iteration``. What a run does besides
learning is a :class:`Callback` each (:func:`default_callbacks`): the perturbation events
(:class:`Perturbations`), the LeRobot recording (:class:`Recording`), the caller's function
(:class:`EveryIteration`), the watchdog (:class:`WatchdogCheck`), ``metrics.jsonl`` and
TensorBoard (:class:`MetricsLog`), the code's read-outs (:class:`CodeReadouts`), ``best.pt`` (:class:`BestState`), ``checkpoint.pt``
(:class:`Checkpoints`) and the progress bar (:class:`Progress`).

Interruptions, without copying the learner's state every iteration:

* Ctrl-C and SIGTERM are deferred to the end of the iteration under way (:class:`_DeferredStop`):
  the loop then writes a checkpoint of that completed iteration and raises ``KeyboardInterrupt``;
  the resume is bit-identical to an uninterrupted run. A second signal interrupts at once, like
  any other exception.
* Any other exception (the watchdog, an error inside an iteration or a callback) leaves the last
  ``checkpoint.pt`` written, every ``train.checkpoint_every`` iterations after the watchdog has
  passed it, hence healthy (a fresh run that stops before its first one writes iteration 0's).
"""

from __future__ import annotations

import contextlib
import copy
import gc
import json
import logging
import signal
import threading
import time
from typing import Callable, Sequence

import torch

from aectorch.coding.readouts import code_summary
from aectorch.framework import IterationRecord, Shard
from aectorch.framework.batch_state import gather_rows, take_rows
from aectorch.runtime.builders import build_env, build_learner, compile_hot_path, dictionaries, set_threads
from aectorch.runtime.checkpoint import CHECKPOINT_FORMAT, restore, save_checkpoint
from aectorch.runtime.config import ExperimentConfig, to_container
from aectorch.runtime.metrics import TrainingMetrics
from aectorch.runtime.outputs import CODE_AT_ENDS, RunFolder, WriteFailed
from aectorch.runtime.perturbations import Schedule
from aectorch.runtime.provenance import provenance
from aectorch.runtime.watchdog import Watchdog, WatchdogError

__all__ = ["BestState", "Callback", "Checkpoints", "CodeReadouts", "EveryIteration", "MetricsLog", "Perturbations", "Progress",
           "Recording", "TrainingRun", "WatchdogCheck", "default_callbacks"]

log = logging.getLogger("aectorch")


@contextlib.contextmanager
def frozen_heap():
    """Within the block, Python's cyclic garbage collector leaves alone every object that existed
    at its start (``gc.freeze``): the learner, the environment, torch's and TorchRL's modules, the
    configuration. An iteration allocates enough small Python objects to start a collection every
    few iterations, and each collection of the oldest generation walked all of them. Objects made
    inside the block are collected as usual; the frozen ones are handed back to the collector at
    the end (``gc.unfreeze``)."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _sigterm(signum, frame):
    raise KeyboardInterrupt(f"terminated by signal {signum}")


def _interrupt_on_sigterm():
    """Make SIGTERM interrupt at once like Ctrl-C does (while a run finishes: `aectorch.runtime.finish`);
    returns the previous handler (``None`` when not in the main thread, where handlers cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _sigterm)


class _DeferredStop:
    """While the loop runs, SIGINT (Ctrl-C) and SIGTERM (``kill``, ``timeout``, a batch scheduler)
    only set :attr:`signum`; the loop stops at the end of the iteration under way. A second
    signal raises ``KeyboardInterrupt`` at once. Handlers can only be set in the main thread;
    elsewhere signals act as before."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self.previous: dict | None = None

    def _handle(self, signum, frame):
        if self.signum is not None:
            raise KeyboardInterrupt(f"terminated by signal {signum} (a second one)")
        self.signum = signum

    def __enter__(self) -> "_DeferredStop":
        if threading.current_thread() is threading.main_thread():
            self.previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        if self.previous is not None:
            for sig, handler in self.previous.items():
                signal.signal(sig, handler)


class Callback:
    """A part of the training loop besides learning; every hook does nothing unless overridden.

    Attributes:
        watch: ``None``, or ``watch(cue, observation)``, passed to `JointLearner.iteration` (the
            observation then holds the whole window too).
    """

    watch: Callable[[str, dict], None] | None = None

    def on_start(self, run: "TrainingRun") -> None:
        """Before the first iteration of this session."""

    def before_iteration(self, run: "TrainingRun", iteration: int) -> None:
        """Before learner iteration ``iteration`` (0-based) runs."""

    def after_iteration(self, run: "TrainingRun", done: int, record: IterationRecord) -> None:
        """After ``done`` iterations (1-based) and the metrics' update; ``record`` is the whole batch's."""

    def on_interrupt(self, run: "TrainingRun", err: BaseException) -> None:
        """The loop is left by ``err`` (which then propagates)."""

    def on_end(self, run: "TrainingRun") -> None:
        """After the loop, however it ended."""


class Perturbations(Callback):
    """The perturbation events (``run.schedule``, `aectorch.runtime.perturbations.Schedule`): before
    every iteration the environment gets the optics of the events acting then (only when they
    changed: a resumed environment has its own already), and at an event's start or end, with
    ``plasticity.raise_to``, the learner's decayed rates are raised again. At an event's end (a
    correction) the code as the perturbation left it is read out (`code_summary` of each
    dictionary) into the run folder's `aectorch.runtime.outputs.CODE_AT_ENDS`, keyed ``"<label>
    ends"``, which ``summary.json`` reports (``perturbation.code``) beside the code at the end."""

    def before_iteration(self, run, iteration):
        schedule = run.schedule
        if not schedule:
            return
        if schedule.ending(iteration) and run.folder.main:
            _record_code_at_end(run, iteration)
        optics = schedule.optics_at(iteration)
        if optics != run.env.optics:
            run.env.set_optics(optics)
        for event in schedule.starting(iteration):
            log.info("iteration %d: %s", iteration, event.label)
        for event in schedule.ending(iteration):
            log.info("iteration %d: %s ends", iteration, event.label)
        raise_to = run.cfg.plasticity.raise_to
        if raise_to is not None and iteration in schedule.changes:
            rates = run.learner.raise_plasticity(raise_to)
            log.info("iteration %d: plasticity raised to %s of the starting rates: %s", iteration, raise_to, rates)


def _record_code_at_end(run, iteration: int) -> None:
    """The code's read-outs before ``iteration``, where events end, added to `CODE_AT_ENDS`
    (a resumed run rewrites the entry of an end it trains through again)."""
    path = run.folder / CODE_AT_ENDS
    entries = json.loads(path.read_text()) if path.is_file() else {}
    label = " + ".join(f"{event.label} ends" for event in run.schedule.ending(iteration))
    entries[label] = {"iteration": iteration,
                      "code": {name: code_summary(atoms) for name, atoms in dictionaries(run.learner).items()}}
    run.folder.write_json(CODE_AT_ENDS, entries)


class Recording(Callback):
    """``record.lerobot``: the training recorded as a LeRobotDataset (main process only)."""

    def __init__(self, root: str, envs: int) -> None:
        self.root, self.envs, self.recorder = root, envs, None

    def on_start(self, run):
        from aectorch.integrations.lerobot import LeRobotRecorder

        self.recorder = LeRobotRecorder(self.root, run.env, envs=self.envs)
        self.watch = self.recorder.watch

    def after_iteration(self, run, done, record):
        self.recorder.after_iteration(record)

    def on_end(self, run):
        if self.recorder is not None:
            self.recorder.close()  # the episodes saved so far stay a valid dataset


class EveryIteration(Callback):
    """A function ``fn(done, record)`` called after every iteration (`run_experiment`'s ``callback``)."""

    def __init__(self, fn: Callable[[int, IterationRecord], None]) -> None:
        self.fn = fn

    def after_iteration(self, run, done, record):
        self.fn(done, record)


class WatchdogCheck(Callback):
    """The health checks after every iteration (`Watchdog`); in mode ``stop`` a problem raises, and
    ``checkpoint.pt`` keeps the last one written (the watchdog passed it)."""

    def after_iteration(self, run, done, record):
        run.watchdog.check(done, record, run.learner)


class MetricsLog(Callback):
    """A line of ``metrics.jsonl`` (and TensorBoard) every ``train.log_every`` iterations and at
    the last; the line is ``run.line`` for the callbacks after this one (``None`` otherwise)."""

    def on_start(self, run):
        self.file = run.folder.open_metrics()

    def after_iteration(self, run, done, record):
        run.line = None
        if done % run.cfg.train.log_every == 0 or done == run.total:
            roll = run.env.roll_deg[0].tolist()
            run.line = {"iteration": done, "env_iterations": done * run.shard.total, "elapsed_s": run.elapsed(),
                        "roll_left_deg": roll[0], "roll_right_deg": roll[1], **run.metrics.summary()}
            if run.schedule:  # the events that acted in the iteration just done
                run.line["perturbations"] = [event.label for event in run.schedule.active(done - 1)]
            run.folder.log_line(self.file, run.line)

    def on_end(self, run):
        try:
            self.file.close()
        except OSError:  # the line that did not fit was reported (WriteFailed); a resume drops a torn line
            pass
        run.folder.close()


class CodeReadouts(Callback):
    """``train.readout_every``: every that many iterations and at the last, the code is read out
    (`code_summary` of each dictionary) into a line of the run folder's
    `aectorch.runtime.outputs.CODE_READOUTS` (main process only)."""

    def __init__(self, every: int) -> None:
        self.every = every

    def after_iteration(self, run, done, record):
        if run.folder.main and (done % self.every == 0 or done == run.total):
            code = {name: code_summary(atoms) for name, atoms in dictionaries(run.learner).items()}
            run.folder.append_readout({"iteration": done, "code": code})


class BestState(Callback):
    """``train.keep_best``: ``best.pt`` holds the state whose full training window had the lowest
    sum of the eye movements' errors; ``run.best`` is its record."""

    def after_iteration(self, run, done, record):
        if run.line is None or not (run.cfg.train.keep_best and run.metrics.window_full):
            return
        score = run.metrics.window_mae()
        if run.best["score"] is None or score < run.best["score"]:
            run.best.update(iteration=done, score=score,
                            **{k: v for k, v in run.line.items() if k.endswith(("_mae_deg", "_mae_m"))})
            state = run.state()  # on every process: it gathers the environments
            if run.folder.main:
                save_checkpoint(run.folder / "best.pt", run.payload(done, state, run.elapsed()))


class Checkpoints(Callback):
    """``checkpoint.pt`` every ``train.checkpoint_every`` iterations and at the end; on an
    interruption: a deferred signal's completed iteration, else the last written (see the module)."""

    def after_iteration(self, run, done, record):
        if done % run.cfg.train.checkpoint_every == 0 or done == run.total:
            state = run.state()  # on every process: it gathers the environments
            if run.folder.main:
                save_checkpoint(run.folder / "checkpoint.pt", run.payload(done, state, run.elapsed()))
            run.saved = done

    def on_interrupt(self, run, err):
        # A deferred signal stops every process after the same iteration (`TrainingRun._stop_requested`),
        # so all gather its state.
        state = run.state() if run.stopped is not None and run.saved != run.iteration_done else None
        if not run.folder.main:
            return
        path, run_dir = run.folder / "checkpoint.pt", run.folder.path
        if isinstance(err, WriteFailed):  # the disk is full: the last checkpoint written stands (train.py says so)
            return
        if run.stopped is not None:  # a deferred signal, at the end of a completed iteration
            done = run.iteration_done
            if state is not None:
                save_checkpoint(path, run.payload(done, state, run.elapsed()))
        else:
            done = run.saved
            if done == run.start and not run.resumed:  # nothing written yet: the start (iteration 0)
                save_checkpoint(path, run.payload(done, run.start_state, run.elapsed()))
        if isinstance(err, WatchdogError):
            log.error("\n%s\nstopped; %s holds iteration %d, the last checkpoint (checked healthy). Resuming it "
                      "repeats the same computation; watchdog.mode=warn continues past the check: python train.py "
                      "train.resume=%s watchdog.mode=warn", err, path, done, run_dir)
        elif run.stopped is not None or isinstance(err, KeyboardInterrupt):
            log.warning("\ninterrupted after iteration %d of %d; checkpoint written to %s\nresume with: "
                        "python train.py train.resume=%s", done, run.total, path, run_dir)
        else:
            log.error("\nstopped by an error in iteration %d; %s holds iteration %d (the last checkpoint)\n"
                      "resume with: python train.py train.resume=%s", run.iteration_done + 1, path, done, run_dir)


class Progress(Callback):
    """The tqdm bar (``train.progress``, main process), with the training window's errors."""

    def on_start(self, run):
        from tqdm.auto import tqdm

        self.bar = tqdm(total=run.total, initial=run.start, desc="training", unit="it", dynamic_ncols=True)

    def after_iteration(self, run, done, record):
        if run.line is not None:
            self.bar.set_postfix({k.split("_mae_")[0]: f"{v:.3f}" for k, v in run.line.items()
                                  if k.endswith(("_mae_deg", "_mae_m"))}, refresh=False)
        self.bar.update(1)

    def on_end(self, run):
        self.bar.close()


def default_callbacks(cfg: ExperimentConfig, main: bool,
                      fn: Callable[[int, IterationRecord], None] | None = None) -> list[Callback]:
    """The callbacks of a ``train.py`` run, in their order (``fn``: the caller's, after every
    iteration, before the watchdog)."""
    callbacks: list[Callback] = [Perturbations()]
    if cfg.record.lerobot is not None and main:
        callbacks.append(Recording(cfg.record.lerobot, cfg.record.envs))
    if fn is not None:
        callbacks.append(EveryIteration(fn))
    callbacks += [WatchdogCheck(), MetricsLog()]
    if cfg.train.readout_every is not None:
        callbacks.append(CodeReadouts(cfg.train.readout_every))
    callbacks += [BestState(), Checkpoints()]
    if cfg.train.progress and main:
        callbacks.append(Progress())
    return callbacks


class TrainingRun:
    """One process's part of a training run (see the module).

    Args:
        cfg: the run's config (the stored one when ``checkpoint`` is given).
        folder: the run folder.
        shard: this process's slice of the environments (`Shard.single` for one process).
        checkpoint: the state to resume from, or ``None``.
        callbacks: the loop's extras (default: :func:`default_callbacks`).
        groups: the config groups' options the config was composed with (``train.py``'s), which
            ``provenance.json`` records with this session (a resume compares them).

    Attributes:
        env, learner, metrics, watchdog: the run's parts.
        best: the early-stopping record (``iteration``, ``score`` and the window's errors).
        line: the metrics line of this iteration (``None`` when none was written).
        saved: the iteration of the last ``checkpoint.pt`` written (or resumed from).
        stopped: the signal that stops the run at the end of this iteration, or ``None``.
        train_seconds: the training's seconds over all sessions, after :meth:`run`.
    """

    def __init__(self, cfg: ExperimentConfig, folder: RunFolder, shard: Shard, checkpoint: dict | None,
                 callbacks: Sequence[Callback] | None = None, groups: dict[str, str | None] | None = None) -> None:
        self.cfg, self.folder, self.shard = cfg, folder, shard
        self.callbacks = list(default_callbacks(cfg, folder.main) if callbacks is None else callbacks)
        self.total = cfg.train.iterations
        set_threads(cfg.train.threads, shard.world_size)
        self.env = build_env(cfg, shard)
        self.learner = build_learner(cfg, shard=shard)
        #: the perturbation events (`Schedule`), resolved against this session's train.iterations
        self.schedule = Schedule(cfg.events())
        self.metrics = TrainingMetrics.for_learner(
            self.learner, shard.total, window_fixations=cfg.train.metrics_window, window_trials=cfg.train.metrics_window,
            movements=[movement.name for movement in self.env.CUES.values()],
            recent=cfg.train.recent_window if self.schedule else None)
        self.watchdog = Watchdog(cfg.watchdog)
        self.best: dict = {"iteration": None, "score": None}
        self.start, self.initial, self.elapsed_before = 0, None, 0.0
        self.resumed = checkpoint is not None
        if checkpoint is not None:
            self._restore(checkpoint)
        else:
            self.initial = dictionaries(self.learner)
        self.config_dict = to_container(cfg)
        self.session = {**provenance(cfg.env.device), "start_iteration": self.start, "world_size": shard.world_size,
                        **({} if groups is None else {"groups": dict(groups)})}
        folder.start(self.config_dict, self.session, resumed_at=self.start if checkpoint is not None else None,
                     tensorboard=cfg.train.tensorboard)
        self.train_seconds = 0.0
        self.line: dict | None = None
        self._state: tuple[int, dict] | None = None

    def _restore(self, checkpoint: dict) -> None:
        path = self.folder / "checkpoint.pt"
        learner_state, env_state = checkpoint["learner"], checkpoint["env"]
        world = self.shard.world_size
        if isinstance(env_state, list):  # format 3 of several processes: one state per process, in rank order
            if len(env_state) != world:
                raise ValueError(f"the checkpoint {str(path)!r} holds the environments of {len(env_state)} "
                                 f"processes in an earlier layout; resume it with as many (this run has {world})")
            env_state = env_state[self.shard.rank]
        else:  # the whole batch: this process's rows of it
            if int(env_state["num_envs"]) != self.shard.total:
                raise ValueError(f"the checkpoint {str(path)!r} holds {env_state['num_envs']} environments; this run "
                                 f"has {world} process(es) x {self.env.num_envs}: give env.num_envs so that the "
                                 "whole batch stays the same")
            env_state = type(self.env).state_rows(env_state, self.shard.start, self.shard.stop)
            learner_state = take_rows(self.learner, learner_state, self.shard.start, self.shard.stop, self.shard.total)
        restore(self.learner, learner_state, path, "learner")
        restore(self.env, env_state, path, "environment")
        restore(self.metrics, checkpoint["metrics"], path, "metrics")
        if "watchdog" in checkpoint:
            restore(self.watchdog, checkpoint["watchdog"], path, "watchdog")
        if "plasticity" in checkpoint:  # (older checkpoints: a schedule that never reopened)
            self.learner.plasticity.load_state_dict(checkpoint["plasticity"])
        self.start = int(checkpoint["iteration"])
        self.best = dict(checkpoint.get("best") or self.best)
        self.initial = checkpoint["initial_dictionaries"]
        self.elapsed_before = float(checkpoint["elapsed_s"])
        if self.folder.main:
            log.info("resuming %s at iteration %d of %d", self.folder.path, self.start, self.total)

    # -- state -------------------------------------------------------------------------------------
    def state(self) -> dict:
        """The state a checkpoint holds, of the iteration just completed (made at most once per iteration).
        It is the whole batch's, however many processes hold it: the learners of all processes are
        identical but for their environments' entries (`aectorch.framework.batch_state`), which are
        joined in rank order, as are the environments' states (`ActiveDepthEnv.join_states`); so
        another number of processes can resume it."""
        done = self.iteration_done
        if self._state is None or self._state[0] != done:
            envs = self.shard.gather_objects(self.env.state_dict())
            learner = gather_rows(self.learner, self.learner.state_dict(), self.shard.gather_objects, self.env.num_envs)
            self._state = (done, {
                "learner": copy.deepcopy(learner),
                "env": type(self.env).join_states(envs),
                "metrics": self.metrics.state_dict(),
                "watchdog": self.watchdog.state_dict(),
                "plasticity": self.learner.plasticity.state_dict(),  # (made anew: plain numbers, no references)
            })
        return self._state[1]

    def _stop_requested(self, deferred: _DeferredStop) -> bool:
        """Whether a signal asks to stop after this iteration (in any process of a distributed run,
        so that all stop at the same iteration)."""
        flag = deferred.signum is not None
        if self.shard.world_size > 1:
            flag = bool(self.shard.sum(torch.tensor([float(flag)])).item() > 0)
        return flag

    def payload(self, iteration: int, state: dict, elapsed: float) -> dict:
        return {"format": CHECKPOINT_FORMAT, "config": self.config_dict, "iteration": iteration,
                **state, "initial_dictionaries": self.initial, "elapsed_s": elapsed, "best": dict(self.best)}

    # -- the loop ----------------------------------------------------------------------------------
    def run(self) -> float:
        """Train to ``train.iterations``; returns the training's seconds (all sessions)."""
        if self.cfg.train.compile:
            compile_hot_path(self.learner, self.env)
        clock = time.perf_counter()
        self.elapsed = lambda: self.elapsed_before + time.perf_counter() - clock  # noqa: E731
        self.iteration_done = self.saved = self.start
        self.stopped = None
        # What an exception before the first checkpoint leaves (a resumed run has its checkpoint).
        self.start_state = None if self.resumed else self.state()
        started: list[Callback] = []
        deferred = _DeferredStop()
        try:
            with deferred:
                for callback in self.callbacks:
                    callback.on_start(self)
                    started.append(callback)
                watches = [c.watch for c in self.callbacks if c.watch is not None]
                watch = None if not watches else (lambda cue, obs: [w(cue, obs) for w in watches])
                with frozen_heap():
                    for it in range(self.start, self.total):
                        for callback in self.callbacks:
                            callback.before_iteration(self, it)
                        record = self.learner.iteration(self.env, watch=watch,  # type: ignore[arg-type]
                                                        closed=self.learner.closed_cues(it))
                        record = self.shard.gather_record(record)  # every process sees the whole batch's record
                        self.metrics.update(record)
                        for event in self.learner.observe_rewards(it, record):
                            if self.folder.main:
                                log.info("%s", event.message())
                        self.iteration_done = done = it + 1
                        for callback in self.callbacks:
                            callback.after_iteration(self, done, record)
                        if self._stop_requested(deferred):
                            self.stopped = deferred.signum or signal.SIGTERM
                            raise KeyboardInterrupt(f"terminated by signal {self.stopped}")
        except BaseException as err:
            for callback in started:
                callback.on_interrupt(self, err)
            raise
        finally:
            for callback in started:
                callback.on_end(self)
            self.folder.close()
        self.train_seconds = self.elapsed()
        return self.train_seconds
