"""`aectorch.framework.plasticity`: a cue closed by ``learn_until`` reopens when its coding reward
falls (``reopen_drop``), learns for ``reopen_for`` iterations and closes again; the schedule's
state rides in every checkpoint, so a resumed run reopens where the uninterrupted one does."""

from __future__ import annotations

import copy
import logging

import pytest

from aectorch.framework.config import CueConfig
from aectorch.framework.plasticity import Plasticity
from aectorch.runtime import load_checkpoint, run_experiment

from tests.runtime.test_train import _assert_same_state, _cfg, textures  # noqa: F401  (shared fixture)


def _schedule(rewards, **config):
    """Feed ``rewards`` (one per iteration) to a stereo cue's schedule; returns which iterations
    were closed ("x") or learned (".") and the reopenings."""
    plasticity = Plasticity({"stereo": CueConfig(**config), "parallax": CueConfig()})
    marks = []
    for it, reward in enumerate(rewards):
        closed = plasticity.closed(it)
        assert "parallax" not in closed  # a cue without learn_until always learns
        marks.append("x" if "stereo" in closed else ".")
        plasticity.observe(it, {"stereo": reward, "parallax": -1.0})
    return "".join(marks), plasticity


def test_a_closed_cue_reopens_when_its_reward_falls_and_closes_again_with_a_new_level():
    # closed at 10; its level is the mean of iterations 10-14 (-1.0); the reward falls to -1.5 at
    # 40; at 41 the window's mean (-1.2) is 20 % below the level: learning from 42 for 20 iterations,
    # closed again at 62 with the new level -1.5, which the same reward never reopens.
    rewards = [-1.0] * 40 + [-1.5] * 60
    marks, plasticity = _schedule(rewards, learn_until=10, reopen_drop=0.1, reopen_window=5, reopen_for=20)
    assert marks == "." * 10 + "x" * 32 + "." * 20 + "x" * 38
    (event,) = plasticity.reopenings
    assert (event.iteration, event.until, event.baseline) == (41, 62, -1.0)
    assert event.level == pytest.approx(-1.2)
    assert "20 % below" in event.message() and "from iteration 42 to 62" in event.message()


def test_a_drop_within_the_threshold_or_without_reopen_drop_keeps_the_cue_closed():
    rewards = [-1.0] * 40 + [-1.09] * 60  # 9 % below the level
    assert _schedule(rewards, learn_until=10, reopen_drop=0.1, reopen_window=5)[0] == "." * 10 + "x" * 90
    rewards = [-1.0] * 40 + [-3.0] * 60
    marks, plasticity = _schedule(rewards, learn_until=10)  # learn_until alone: closed for good
    assert marks == "." * 10 + "x" * 90 and plasticity.reopenings == []


def test_the_schedule_state_round_trip_continues_identically():
    rewards = [-1.0] * 40 + [-1.5] * 30 + [-3.0] * 30
    config = dict(learn_until=10, reopen_drop=0.1, reopen_window=5, reopen_for=20)
    whole, _ = _schedule(rewards, **config)
    first = Plasticity({"stereo": CueConfig(**config)})
    for it in range(45):  # stopped in the middle of the first reopening
        first.observe(it, {"stereo": rewards[it]})
    second = Plasticity({"stereo": CueConfig(**config)})
    second.load_state_dict(copy.deepcopy(first.state_dict()))
    rest = ""
    for it in range(45, 100):
        rest += "x" if second.closed(it) else "."
        second.observe(it, {"stereo": rewards[it]})
    assert rest == whole[45:] and len(second.reopenings) == 2


@pytest.mark.parametrize("bad, match", [
    (dict(reopen_drop=0.1), r"cue.reopen_drop reopens a cue closed by cue.learn_until, which is null"),
    (dict(learn_until=5, reopen_drop=0.0), r"cue.reopen_drop must be"),
    (dict(learn_until=5, reopen_drop=0.1, reopen_window=0), r"cue.reopen_window must be"),
    (dict(learn_until=5, reopen_drop=0.1, reopen_for=0), r"cue.reopen_for must be"),
])
def test_bad_reopening_settings_are_refused_naming_the_field(bad, match):
    with pytest.raises(ValueError, match=match):
        CueConfig(**bad)


@pytest.mark.integration
def test_a_resumed_run_reopens_and_learns_as_the_uninterrupted_one(tmp_path, textures, caplog):
    # A threshold so small that any fall of the reward reopens the stereo cue, for 2 iterations.
    settings = ["train.iterations=14", "train.checkpoint_every=4", "learner.cues.stereo.learn_until=3",
                "learner.cues.stereo.reopen_drop=1e-9", "learner.cues.stereo.reopen_window=1",
                "learner.cues.stereo.reopen_for=2"]
    whole = tmp_path / "whole"
    caplog.set_level(logging.INFO, logger="aectorch")
    run_experiment(_cfg(textures, *settings), whole)
    assert "stereo: the coding reward fell" in caplog.text and "it learns again from iteration" in caplog.text
    expected = load_checkpoint(whole / "checkpoint.pt")
    reopened = [r["iteration"] for r in expected["plasticity"]["reopenings"]]
    assert any(it >= 8 for it in reopened), f"no reopening after the checkpoint (at {reopened}): the test proves nothing"

    def fail(done, record):
        if done == 10:
            raise RuntimeError("stopped for the test")

    part = tmp_path / "part"
    with pytest.raises(RuntimeError, match="stopped for the test"):
        run_experiment(_cfg(textures, *settings), part, callback=fail)
    assert load_checkpoint(part / "checkpoint.pt")["iteration"] == 8
    run_experiment(_cfg(textures, *settings, f"train.resume={part}"), part)
    resumed = load_checkpoint(part / "checkpoint.pt")
    assert resumed["plasticity"] == expected["plasticity"]
    _assert_same_state(resumed["learner"], expected["learner"], "learner")
    assert all(r["until"] == r["iteration"] + 3 for r in expected["plasticity"]["reopenings"])
