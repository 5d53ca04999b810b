"""aectorch.profiling: stage times of the training loop (exclusive, nested, off by default)."""

from __future__ import annotations

import time

import pytest
import torch

from aectorch.coding import EncoderConfig
from aectorch.framework import JointLearner, LearnerConfig, default_cues
from aectorch.profiling import StageTimer, stage
from aectorch.sim import ActiveDepthEnv, TrialProtocol

torch.set_num_threads(1)


def test_nested_stages_are_charged_exclusive_time():
    with StageTimer() as timer:
        with stage("outer"):
            time.sleep(0.02)
            with stage("inner"):
                time.sleep(0.05)
    assert timer.calls == {"outer": 1, "inner": 1}
    assert 0.045 <= timer.seconds["inner"] < 0.2
    assert 0.015 <= timer.seconds["outer"] < 0.045  # the inner 50 ms are not charged twice
    assert timer.total() == pytest.approx(timer.seconds["outer"] + timer.seconds["inner"])


def test_stages_cost_nothing_without_a_timer_and_timers_nest():
    with stage("ignored"):
        pass
    with StageTimer() as outer:
        with StageTimer() as inner:
            with stage("a"):
                pass
        with stage("b"):
            pass
    assert set(inner.seconds) == {"a"} and set(outer.seconds) == {"b"}


def test_learner_iterations_cover_every_stage_including_depth():
    env = ActiveDepthEnv(4, protocol=TrialProtocol(fixation_iterations=1), textures=torch.rand(3, 64, 64), seed=0)
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32)), depth_every_trials=8),
                           generator=torch.Generator().manual_seed(0))
    with StageTimer() as timer:
        for _ in range(6):  # 3 trials of 4 environments: the depth MLP is fitted once
            learner.iteration(env)
    assert set(timer.seconds) == {"render", "encode", "rl", "dictionary", "env", "depth", "metrics"}
    assert timer.calls["render"] == 12 and timer.calls["encode"] == 12 and timer.calls["depth"] == 3
    assert all(seconds > 0 for seconds in timer.seconds.values())
