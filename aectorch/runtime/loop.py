"""The training loop: iterate, log, keep the best state, checkpoint, and stop cleanly.

:class:`TrainingRun` holds one process's part of a run (its shard of the environments, the
learner, the metrics and the watchdog) and the run folder. Every completed iteration's state is
kept in memory (``last``), so an interruption (Ctrl-C, SIGTERM, the watchdog, an exception from a
callback) writes a checkpoint of the last completed, healthy iteration before it propagates.
"""

from __future__ import annotations

import copy
import logging
import signal
import threading
import time
from typing import Callable

import torch

from aectorch.framework import IterationRecord, Shard
from aectorch.runtime.builders import build_env, build_learner, compile_hot_path, dictionaries, set_threads
from aectorch.runtime.checkpoint import CHECKPOINT_FORMAT, restore, save_checkpoint
from aectorch.runtime.config import ExperimentConfig, to_container
from aectorch.runtime.metrics import TrainingMetrics
from aectorch.runtime.outputs import RunFolder
from aectorch.runtime.provenance import provenance
from aectorch.runtime.watchdog import Watchdog, WatchdogError

__all__ = ["TrainingRun"]

log = logging.getLogger("aectorch")


def _sigterm(signum, frame):
    raise KeyboardInterrupt(f"terminated by signal {signum}")


def _interrupt_on_sigterm():
    """Make SIGTERM (``kill``, ``timeout``, a batch scheduler) interrupt like Ctrl-C does, so the
    last completed iteration is checkpointed; returns the previous handler (``None`` when not
    in the main thread, where handlers cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _sigterm)


class TrainingRun:
    """One process's part of a training run (see the module).

    Args:
        cfg: the run's config (the stored one when ``checkpoint`` is given).
        folder: the run folder.
        shard: this process's slice of the environments (`Shard.single` for one process).
        checkpoint: the state to resume from, or ``None``.
        callback: called as ``callback(iteration, record)`` after every iteration.
    """

    def __init__(self, cfg: ExperimentConfig, folder: RunFolder, shard: Shard, checkpoint: dict | None,
                 callback: Callable[[int, IterationRecord], None] | None = None) -> None:
        self.cfg, self.folder, self.shard, self.callback = cfg, folder, shard, callback
        self.total = cfg.train.iterations
        set_threads(cfg.train.threads, shard.world_size)
        self.env = build_env(cfg, shard)
        self.learner = build_learner(cfg, shard=shard)
        self.metrics = TrainingMetrics(shard.total, scales=cfg.learner.scales, window_fixations=cfg.train.metrics_window,
                                       window_trials=cfg.train.metrics_window)
        self.watchdog = Watchdog(cfg.watchdog)
        # Early stopping by the training window (`train.keep_best`): the best score and its iteration.
        self.best: dict = {"iteration": None, "score": None}
        self.start, self.initial, self.elapsed_before = 0, None, 0.0
        self.resumed = checkpoint is not None
        if checkpoint is not None:
            self._restore(checkpoint)
        else:
            self.initial = dictionaries(self.learner)
        self.config_dict = to_container(cfg)
        self.session = {**provenance(cfg.env.device), "start_iteration": self.start, "world_size": shard.world_size}
        folder.start(self.config_dict, self.session, resumed_at=self.start if checkpoint is not None else None,
                     tensorboard=cfg.train.tensorboard)
        self.events = cfg.perturbation.events(self.total)
        self.train_seconds = 0.0

    def _restore(self, checkpoint: dict) -> None:
        path = self.folder / "checkpoint.pt"
        restore(self.learner, checkpoint["learner"], path, "learner")
        env_state = checkpoint["env"]
        world = self.shard.world_size
        if world > 1 or isinstance(env_state, list):  # one state per process, in rank order
            if not isinstance(env_state, list) or len(env_state) != world:
                raise ValueError(f"the checkpoint {str(path)!r} holds the environments of "
                                 f"{len(env_state) if isinstance(env_state, list) else 1} process(es); "
                                 f"resume it with as many (this run has {world})")
            env_state = env_state[self.shard.rank]
        restore(self.env, env_state, path, "environment")
        restore(self.metrics, checkpoint["metrics"], path, "metrics")
        if "watchdog" in checkpoint:
            restore(self.watchdog, checkpoint["watchdog"], path, "watchdog")
        self.start = int(checkpoint["iteration"])
        self.best = dict(checkpoint.get("best") or self.best)
        self.initial = checkpoint["initial_dictionaries"]
        self.elapsed_before = float(checkpoint["elapsed_s"])
        if self.folder.main:
            log.info("resuming %s at iteration %d of %d", self.folder.path, self.start, self.total)

    # -- state -------------------------------------------------------------------------------------
    def state(self) -> dict:
        """The state a checkpoint holds. The learners of all processes are identical; the
        environments are each process's own (one process's checkpoint holds its state itself)."""
        envs = self.shard.gather_objects(self.env.state_dict())
        return {
            "learner": copy.deepcopy(self.learner.state_dict()),
            "env": envs[0] if len(envs) == 1 else envs,
            "metrics": self.metrics.state_dict(),
            "watchdog": self.watchdog.state_dict(),
        }

    def payload(self, iteration: int, state: dict, elapsed: float) -> dict:
        return {"format": CHECKPOINT_FORMAT, "config": self.config_dict, "iteration": iteration,
                **state, "initial_dictionaries": self.initial, "elapsed_s": elapsed, "best": dict(self.best)}

    # -- the loop ----------------------------------------------------------------------------------
    def run(self) -> float:
        """Train to ``train.iterations``; returns the training's seconds (all sessions)."""
        cfg, main = self.cfg, self.folder.main
        if cfg.train.compile:
            compile_hot_path(self.learner, self.env)
        recorder, stepped = None, self.env  # the environment the learner steps (observed when recording)
        if cfg.record.lerobot is not None and main:
            from aectorch.integrations.lerobot import LeRobotRecorder

            recorder = LeRobotRecorder(cfg.record.lerobot, self.env, envs=cfg.record.envs)
            stepped = recorder.wrap(self.env)
        bar = None
        if cfg.train.progress and main:
            from tqdm.auto import tqdm

            bar = tqdm(total=self.total, initial=self.start, desc="training", unit="it", dynamic_ncols=True)
        clock = time.perf_counter()
        self.elapsed = lambda: self.elapsed_before + time.perf_counter() - clock  # noqa: E731
        self.last = (self.start, self.state())  # the last completed (healthy) iteration
        previous_sigterm = _interrupt_on_sigterm()
        try:
            with self.folder.open_metrics() as file:
                for it in range(self.start, self.total):
                    self._iteration(it, stepped, recorder, file, bar)
        except BaseException as err:
            self._interrupted(err)
            raise
        finally:
            if recorder is not None:
                recorder.close()  # the episodes saved so far stay a valid dataset
            if previous_sigterm is not None:
                signal.signal(signal.SIGTERM, previous_sigterm)
            if bar is not None:
                bar.close()
            self.folder.close()
        return self.elapsed()

    def _iteration(self, it: int, stepped, recorder, file, bar) -> None:
        for when, roll, label in self.events:
            if it == when:
                self.env.set_roll(torch.tensor(roll))
                log.info("iteration %d: %s by %s deg", it, label, self.cfg.perturbation.roll_deg)
        record = self.learner.iteration(stepped)
        if recorder is not None:
            recorder.after_iteration(record)
        record = self.shard.gather_record(record)  # every process sees the whole batch's record
        self.metrics.update(record)
        done = it + 1
        if self.callback is not None:
            self.callback(done, record)
        self.watchdog.check(done, record, self.learner)  # raises in mode "stop": `last` is healthy
        line = None
        if done % self.cfg.train.log_every == 0 or done == self.total:
            line = self._log(done, file, bar)
        state = self.state()
        if line is not None:
            self._keep_best(done, line, state)
        if self.folder.main and (done % self.cfg.train.checkpoint_every == 0 or done == self.total):
            save_checkpoint(self.folder / "checkpoint.pt", self.payload(done, state, self.elapsed()))
        self.last = (done, state)
        if bar is not None:
            bar.update(1)

    def _log(self, done: int, file, bar) -> dict:
        roll = self.env.roll_deg[0].tolist()
        line = {"iteration": done, "env_iterations": done * self.shard.total, "elapsed_s": self.elapsed(),
                "roll_left_deg": roll[0], "roll_right_deg": roll[1], **self.metrics.summary()}
        self.folder.log_line(file, line)
        if bar is not None:
            bar.set_postfix(pursuit=f"{line['pursuit_mae_deg']:.3f}", vergence=f"{line['vergence_mae_deg']:.3f}",
                            depth=f"{line['depth_mae_m']:.3f}", refresh=False)
        return line

    def _keep_best(self, done: int, line: dict, state: dict) -> None:
        """``train.keep_best``: write best.pt when the full training window's score is the lowest."""
        if not (self.cfg.train.keep_best and self.metrics.window_full):
            return
        score = line["pursuit_mae_deg"] + line["vergence_mae_deg"]
        if self.best["score"] is None or score < self.best["score"]:
            self.best.update(iteration=done, score=score, pursuit_mae_deg=line["pursuit_mae_deg"],
                             vergence_mae_deg=line["vergence_mae_deg"], depth_mae_m=line["depth_mae_m"])
            if self.folder.main:
                save_checkpoint(self.folder / "best.pt", self.payload(done, state, self.elapsed()))

    def _interrupted(self, err: BaseException) -> None:
        """Checkpoint the last completed iteration and say how to go on."""
        done, state = self.last
        if not self.folder.main:
            return
        if done > self.start or not self.resumed:
            save_checkpoint(self.folder / "checkpoint.pt", self.payload(done, state, self.elapsed()))
        path, run_dir = self.folder / "checkpoint.pt", self.folder.path
        if isinstance(err, WatchdogError):
            log.error("\n%s\nstopped; %s holds iteration %d, the last healthy one. Resuming it repeats the same "
                      "computation; watchdog.mode=warn continues past the check: python train.py "
                      "train.resume=%s watchdog.mode=warn", err, path, done, run_dir)
        else:
            log.warning("\ninterrupted after iteration %d of %d; checkpoint written to %s\nresume with: "
                        "python train.py train.resume=%s", done, self.total, path, run_dir)
