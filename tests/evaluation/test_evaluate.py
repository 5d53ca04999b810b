"""aectorch.evaluation: frozen, greedy evaluation over textures x distances."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch

from aectorch.evaluation import evaluate, run_trials, summarise
from aectorch.coding import EncoderConfig
from aectorch.framework import JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol

torch.set_num_threads(1)


def test_summarise_matches_numpy():
    x = torch.randn(101, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    s = summarise(x)
    n = x.numpy()
    assert s["mae"] == pytest.approx(np.abs(n).mean())
    assert s["rmse"] == pytest.approx(np.sqrt((n**2).mean()))
    assert s["median"] == pytest.approx(np.median(n))
    assert s["iqr4"] == pytest.approx(4 * (np.percentile(n, 75) - np.percentile(n, 25)))
    assert summarise(torch.tensor([float("nan")]))["n"] == 0


def test_evaluate_runs_every_texture_at_every_distance_frozen():
    bank = TextureBank(torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32)), depth_every_trials=12),
                           generator=torch.Generator().manual_seed(0))
    env = ActiveDepthEnv(4, protocol=TrialProtocol(fixation_iterations=1), textures=bank, seed=0)
    for _ in range(6):  # three trials of four environments: the depth MLP gets trained
        learner.iteration(env)
    before = copy.deepcopy(learner.state_dict())
    result = evaluate(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0],
                      batch_size=4, steps=3)
    assert result["trials"] == 6 and result["pursuit"]["n"] == 12 and result["vergence"]["n"] == 12
    assert [row["distance_m"] for row in result["per_distance"]] == [1.0, 2.0]
    rows = result["per_texture"]  # every texture has as many trials: their mean is the overall MAE
    assert [row["texture"] for row in rows] == bank.names
    for key in ("pursuit_mae_deg", "vergence_mae_deg", "depth_mae_m"):
        assert np.mean([row[key] for row in rows]) == pytest.approx(result[key])
    assert len({row["pursuit_mae_deg"] for row in rows}) > 1
    assert result["depth"]["n"] == 6 and np.isfinite(result["depth_mae_m"])
    test = result["vergence_test"]
    assert test["degrees"]["n"] == 6
    assert test["pixels"]["rmse"] == pytest.approx(test["degrees"]["rmse"] / env.camera.degrees_per_pixel)
    assert test["max_abs_deg"] >= test["degrees"]["mae"] and 0 <= test["beyond_1deg"] <= 1
    assert (test["beyond_1deg"] > 0) == (test["max_abs_deg"] > 1.0)
    after = learner.state_dict()
    for key, value in before.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, after[key]), key


def test_untrained_greedy_policy_is_far_from_zero_error():
    """A frozen random policy does not fixate: the metric can fail."""
    bank = TextureBank(torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(1)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))), generator=torch.Generator().manual_seed(0))
    result = evaluate(learner, bank, protocol=TrialProtocol(fixation_iterations=3), distances_m=[1.0],
                      vergence_test=False)
    assert result["pursuit_mae_deg"] > 1.0  # at 1 m pursuit needs 5.7 degrees; 3 steps give <= 0.6


def test_evaluate_rejects_bad_arguments():
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))))
    bank = TextureBank(torch.rand(1, 64, 64))
    with pytest.raises(ValueError, match="distances_m"):
        evaluate(learner, bank, distances_m=[0.0])
    with pytest.raises(ValueError, match="batch_size"):
        evaluate(learner, bank, batch_size=0)


def test_sampled_policy_differs_from_greedy_and_leaves_the_learner_as_it_was():
    bank = TextureBank(torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(2)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))), generator=torch.Generator().manual_seed(0))
    before = copy.deepcopy(learner.state_dict())
    generator_before = learner.generator.get_state()
    kwargs = dict(distances_m=[1.0, 2.0], protocol=TrialProtocol(fixation_iterations=3), steps=3)
    greedy = evaluate(learner, bank, **kwargs)
    sampled = evaluate(learner, bank, policy="sampled", **kwargs)
    again = evaluate(learner, bank, policy="sampled", **kwargs)
    assert greedy["policy"] == "greedy" and sampled["policy"] == "sampled"
    assert sampled["pursuit"] != greedy["pursuit"]  # an untrained policy is far from greedy
    assert sampled["pursuit"] == again["pursuit"]  # seeded by ``seed``, not by the learner's state
    after = learner.state_dict()
    assert torch.equal(learner.generator.get_state(), generator_before)
    for key, value in before.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, after[key]), key
    with pytest.raises(ValueError, match="policy must be one of 'greedy', 'sampled'"):
        evaluate(learner, bank, policy="argmax")


def _trained_learner():
    """A small learner after three trials of four environments (its depth MLP fitted), and its bank."""
    bank = TextureBank(torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32)), depth_every_trials=12),
                           generator=torch.Generator().manual_seed(0))
    env = ActiveDepthEnv(4, protocol=TrialProtocol(fixation_iterations=1), textures=bank, seed=0)
    for _ in range(6):
        learner.iteration(env)
    return bank, learner


def test_run_trials_gives_the_trials_evaluate_summarises():
    bank, learner = _trained_learner()
    before = copy.deepcopy(learner.state_dict())
    out = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0], batch_size=4)
    result = evaluate(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0],
                      batch_size=4, vergence_test=False)
    assert out["q_deg"].shape == (6, 4) and out["pursuit_deg"].shape == (6, 2)
    assert out["texture_index"].tolist() == [0, 0, 1, 1, 2, 2] and out["distance_m"].tolist() == [1.0, 2.0] * 3
    assert out["pursuit_deg"].abs().mean().item() == pytest.approx(result["pursuit_mae_deg"])
    assert out["vergence_deg"].abs().mean().item() == pytest.approx(result["vergence_mae_deg"])
    assert out["depth_error_m"].abs().mean().item() == pytest.approx(result["depth_mae_m"])
    # q is the MLP's input: its prediction from q is the trial's distance plus the depth error.
    predicted = learner.predict_depth(out["q_deg"]).double()
    assert torch.allclose(predicted - out["distance_m"], out["depth_error_m"].double(), atol=1e-5)
    after = learner.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before if isinstance(before[k], torch.Tensor))
    with pytest.raises(ValueError, match="policy"):
        run_trials(learner, bank, policy="best")


def test_run_trials_runs_the_given_conditions():
    bank = TextureBank(torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))), generator=torch.Generator().manual_seed(0))
    grid = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0],
                      batch_size=8)
    pick = (torch.tensor([2, 0]), torch.tensor([1.0, 2.0], dtype=torch.float64))
    some = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0],
                      batch_size=8, conditions=pick)
    assert some["texture_index"].tolist() == [2, 0] and some["distance_m"].tolist() == [1.0, 2.0]
    # The same trials as in the grid (texture-major: rows 4 and 1), whatever else is in the batch.
    assert torch.allclose(some["q_deg"], grid["q_deg"][[4, 1]], atol=1e-4)
    with pytest.raises(ValueError, match="among distances_m"):
        run_trials(learner, bank, distances_m=[1.0, 2.0], conditions=(torch.tensor([0]), torch.tensor([1.5])))
    with pytest.raises(ValueError, match="texture indices"):
        run_trials(learner, bank, distances_m=[1.0, 2.0], conditions=(torch.tensor([3]), torch.tensor([1.0])))
    with pytest.raises(ValueError, match="conditions must be"):
        run_trials(learner, bank, distances_m=[1.0, 2.0], conditions=(torch.tensor([0, 1]), torch.tensor([1.0])))


def test_evaluate_writes_one_row_per_trial_and_the_fractions_on_target():
    bank, learner = _trained_learner()
    kwargs = dict(distances_m=[1.0, 2.0], batch_size=4, protocol=TrialProtocol(fixation_iterations=4))
    result = evaluate(learner, bank, vergence_test=False, **kwargs)
    out = run_trials(learner, bank, **kwargs)
    rows = result["per_trial"]
    assert len(rows) == result["trials"] == 6
    assert [(r["texture"], r["distance_m"]) for r in rows] == [(n, d) for n in bank.names for d in (1.0, 2.0)]
    for i, row in enumerate(rows):  # signed, the trial's final state: the second fixation's end
        assert row["pursuit_error_deg"] == pytest.approx(out["pursuit_deg"][i, 1].item())
        assert row["vergence_error_deg"] == pytest.approx(out["vergence_deg"][i, 1].item())
        assert row["depth_error_m"] == pytest.approx(out["depth_error_m"][i].item())
        assert row["pursuit_errors_deg"] == pytest.approx(out["pursuit_deg"][i].tolist())
    assert np.mean([abs(e) for r in rows for e in r["pursuit_errors_deg"]]) == pytest.approx(result["pursuit_mae_deg"])
    p, v = out["pursuit_deg"].abs(), out["vergence_deg"].abs()
    fractions = result["fractions"]
    assert fractions["pursuit"]["within"] == pytest.approx((p <= 0.22).double().mean().item())
    assert fractions["vergence"]["beyond"] == pytest.approx((v > 2.0).double().mean().item())
    assert fractions["both"]["within"] == pytest.approx(((p <= 0.22) & (v <= 0.22)).double().mean().item())
    assert result["per_distance"][0]["fractions"]["both"]["within"] == pytest.approx(
        ((p[::2] <= 0.22) & (v[::2] <= 0.22)).double().mean().item())
    import json

    json.dumps(result)  # JSON-ready


def test_evaluate_follows_the_training_protocol():
    """A learner is evaluated under the body movement and pursuit it trained with: a spread shift
    with yoked pursuit ends fixations elsewhere than an instant one with the left eye alone."""
    bank = TextureBank(torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(0)))
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))), generator=torch.Generator().manual_seed(0))
    kwargs = dict(distances_m=[1.0], batch_size=2)
    instant = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=6, shift_iterations=1,
                                                               yoked_pursuit=False), **kwargs)
    spread = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=6, shift_iterations=6,
                                                              yoked_pursuit=True), **kwargs)
    assert not torch.allclose(instant["vergence_deg"], spread["vergence_deg"])
    with pytest.raises(ValueError, match="shift_iterations"):
        run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=6, shift_iterations=0), **kwargs)


def test_last5_is_the_mean_of_each_fixations_last_five_iterations():
    # An independent record of the same frozen trials: every iteration's errors, by hand.
    from aectorch.evaluation import frozen_iterations

    bank, learner = _trained_learner()
    out = run_trials(learner, bank, protocol=TrialProtocol(fixation_iterations=7), distances_m=[1.5], batch_size=3)
    env = ActiveDepthEnv(3, protocol=TrialProtocol(fixation_iterations=7), textures=bank, distances_m=[1.5], seed=0)
    env.set_trial(torch.arange(3), torch.full((3,), 1.5))
    errors = [r.errors_deg["vergence"] for r in frozen_iterations(learner, env)]
    assert len(errors) == 14
    by_hand = torch.stack([torch.stack(errors[2:7]).mean(0), torch.stack(errors[9:14]).mean(0)], 1)
    torch.testing.assert_close(out["vergence_last5_deg"], by_hand.cpu())
    torch.testing.assert_close(out["vergence_deg"], torch.stack([errors[6], errors[13]], 1).cpu())
    result = evaluate(learner, bank, protocol=TrialProtocol(fixation_iterations=7), distances_m=[1.5], batch_size=3,
                      vergence_test=False)
    row = result["per_trial"][1]
    assert row["vergence_error_last5_deg"] == pytest.approx(by_hand[1, 1].item())
    assert row["vergence_errors_last5_deg"] == pytest.approx(by_hand[1].tolist())
    assert result["last5"]["vergence_mae_deg"] == pytest.approx(by_hand.abs().mean().item())
    assert set(result["last5"]["fractions"]) == {"pursuit", "vergence", "both"}


def test_offset_sweep_reads_the_cues_reward_and_greedy_increment_off_the_optimum(tmp_path):
    from aectorch.evaluation.offsets import capture_range, limit_cycle, offset_summary, offset_sweep

    bank, learner = _trained_learner()
    sweep = offset_sweep(learner, bank, cue="stereo", offsets_deg=[-0.5, 0.0, 0.5], distances_m=[2.0], batch_size=2)
    assert sweep["reward"].shape == sweep["increment_deg"].shape == (3, 3)
    # The same view by hand: the body shifted, the left eye at its optimum, the right 0.5 deg past it.
    env = ActiveDepthEnv(3, protocol=TrialProtocol(shift_iterations=1), textures=bank, distances_m=[2.0], seed=0)
    env.set_trial(torch.arange(3), torch.full((3,), 2.0))
    left = env.optimal_left_pan_deg()
    env.set_pan_deg(torch.stack((left, env.optimal_right_pan_deg(left) + 0.5), -1))
    with torch.no_grad():
        coded = learner.stereo.encoder.encode(env.observe("stereo", learner.stereo.encoder.scales))
    torch.testing.assert_close(sweep["reward"][:, 2], coded.reward.double())
    # The features the agent was given there, and the policy's mean read out of them again.
    kept = offset_sweep(learner, bank, cue="stereo", offsets_deg=[-0.5, 0.0, 0.5], distances_m=[2.0], batch_size=2,
                        features=True)
    assert "features" not in sweep and kept["features"].shape == (3, 3, learner.stereo.encoder.num_features)
    torch.testing.assert_close(kept["features"][:, 2], learner.stereo.features(coded.features).double())
    agent = learner.stereo.agent
    mean = agent.log_policy(kept["features"].to(agent.actions_deg.dtype)).exp() @ agent.actions_deg
    torch.testing.assert_close(mean.double(), kept["expected_increment_deg"])
    summary = offset_summary(sweep)
    assert summary["trials"] == 3 and 0 <= summary["reward_peak_within_px"] <= 1
    from aectorch.report.offsets import plot_offsets

    assert plot_offsets({"stereo": sweep}, tmp_path / "offsets.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="cue must be one the learner learns"):
        offset_sweep(learner, bank, cue="torsion")
    # A bang-bang map (+0.2 at or below the optimum, -0.2 above it) cycles between 0 and 0.2.
    x = torch.linspace(-1, 1, 101, dtype=torch.float64)
    bang = torch.where(x <= 0, 0.2, -0.2)[None].repeat(2, 1)
    assert limit_cycle(x, bang).tolist() == pytest.approx([0.1, 0.1], abs=0.01)
    # Far from the optimum: a map that steps back below it and on away above it (a runaway), as counted.
    far = torch.tensor([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0], dtype=torch.float64)
    runaway = torch.tensor([[0.2, 0.2, 0.2, 0.0, -0.2, 0.2, 0.2], [0.2, -0.01, 0.2, 0.0, -0.2, -0.2, 0.2]])
    flat = torch.zeros(2, 7, dtype=torch.float64)
    sweep = {"offsets_deg": far, "reward": flat, "increment_deg": flat, "expected_increment_deg": runaway}
    summary = offset_summary(sweep)
    # (-0.01 at -2 deg steps away by less than the smallest action: not counted)
    assert summary["away_far_below"] == 0.0 and summary["away_far_above"] == 0.75  # 3 of the 4 beyond 1 deg
    assert math.isnan(offset_summary({**sweep, "offsets_deg": far / 3})["away_far_above"])  # no offset beyond 1 deg
    # The capture range: below, every trial steps back out to -3 deg; above, half step away at +2 deg.
    assert (summary["capture_below_deg"], summary["capture_above_deg"]) == (3.0, 1.0)
    near = offset_summary({**sweep, "offsets_deg": far / 3})  # a sweep within 1 deg reports no capture range
    assert math.isnan(near["capture_below_deg"]) and math.isnan(near["capture_above_deg"])
    assert capture_range(far, torch.zeros(1, 7, dtype=torch.bool)) == (3.0, 3.0)
    assert capture_range(far, torch.ones(1, 7, dtype=torch.bool)) == (0.0, 0.0)
    assert capture_range(far / 3, torch.tensor([[0, 0, 0, 0, 0, 1, 0]], dtype=torch.bool)) == (1.0, 0.0)
    assert all(math.isnan(v) for v in capture_range(far / 10, torch.zeros(1, 7, dtype=torch.bool)))


def test_the_rows_hold_the_texture_statistics_of_each_trials_first_view():
    """A flat texture has no energy at any of the coder's scales and no contrast; a noise texture
    has both, more at the fine scales (white noise) and with four times the energy at double the
    contrast. The statistics are of the view at the trial's start, whatever the learner does."""
    g = torch.Generator().manual_seed(0)
    noise = torch.rand(64, 64, generator=g)
    noise = noise - noise.mean()
    bank = TextureBank(torch.stack((torch.full((64, 64), 0.5), 0.5 + 0.2 * noise, 0.5 + 0.4 * noise)),
                       names=["flat", "noise", "noise x2"])
    learner = JointLearner(LearnerConfig(cues=default_cues(encoder=EncoderConfig(num_atoms=32))),
                           generator=torch.Generator().manual_seed(0))
    result = evaluate(learner, bank, protocol=TrialProtocol(fixation_iterations=2), distances_m=[1.0, 2.0],
                      batch_size=6, vergence_test=False)
    rows = {(r["texture"], r["distance_m"]): r for r in result["per_trial"]}
    keys = ["view_contrast", *(f"view_energy_{s}" for s in ("wide", "coarse", "fine", "full"))]
    for (texture, _), row in rows.items():
        assert all(isinstance(row[k], float) for k in keys), row
        if texture == "flat":
            assert all(abs(row[k]) < 1e-6 for k in keys), row  # float32 rounding
        else:
            assert row["view_contrast"] > 0.02 and all(row[k] > 1e-6 for k in keys[1:]), row
            assert row["view_energy_full"] > row["view_energy_wide"]
    for d in (1.0, 2.0):
        single, double = rows["noise", d], rows["noise x2", d]
        # (the contrast divides by the mean intensity of the part of the texture in view)
        assert double["view_contrast"] == pytest.approx(2 * single["view_contrast"], rel=0.05)
        assert double["view_energy_fine"] == pytest.approx(4 * single["view_energy_fine"], rel=1e-3)
