"""JointLearner: the schedule of the paper's framework over ActiveDepthEnv."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch

from aectorch.coding import EncoderConfig
from aectorch.control import PPO, ActorCriticConfig, NaturalActorCritic
from aectorch.framework import CueConfig, JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TrialProtocol
from tests.framework.torsion import Torsion

torch.set_num_threads(1)


def make(num_envs=2, h=2, *, encoder=None, cue=None, **learner):
    """An environment and a learner of 32 atoms per dictionary, with the natural actor-critic (most
    tests here are of its updates); ``encoder`` and ``cue``: fields of every cue's `EncoderConfig`
    and `CueConfig`, ``learner``: of `LearnerConfig`."""
    env = ActiveDepthEnv(num_envs, protocol=TrialProtocol(fixation_iterations=h),
                         textures=torch.rand(4, 64, 64, generator=torch.Generator().manual_seed(1)), seed=0)
    cues = default_cues(encoder=EncoderConfig(**{"num_atoms": 32, **(encoder or {})}), **{"agent": "nac", **(cue or {})})
    learner = JointLearner(LearnerConfig(cues=cues, **learner), generator=torch.Generator().manual_seed(0))
    return env, learner


def test_iteration_records_both_cues_and_the_ground_truth():
    env, learner = make(cue=dict(scales=("coarse", "fine")))  # the paper's two scales
    record = learner.iteration(env)
    for cue in (record.parallax, record.stereo):
        assert cue.reward.shape == (2,) and cue.errors.shape == (2, 2)
        assert torch.allclose(cue.reward, -cue.errors.sum(1))
        assert cue.td_error is None  # nothing to learn from on the very first step
        assert cue.actions.shape == (2,) and cue.entropy.shape == (2,)
    assert record.pursuit_error_deg.shape == (2,) and not record.fixation_end
    assert list(record.cues) == ["parallax", "stereo"] and list(record.errors_deg) == ["pursuit", "vergence"]
    assert record.stereo is record.cues["stereo"] and record.vergence_error_deg is record.errors_deg["vergence"]
    record = learner.iteration(env)
    assert record.parallax.td_error.shape == (2,) and record.fixation_end


@pytest.mark.parametrize("scales, newest, dim", [
    (None, "full", 200),                          # the default: wide, coarse, fine, full
    (("wide", "coarse", "fine"), "wide", 72),    # without the full-resolution scale
])
def test_every_scale_gets_a_dictionary_a_reward_term_and_features(scales, newest, dim):
    env, learner = make() if scales is None else make(cue=dict(scales=scales))
    if scales is None:
        assert learner.config.cues["stereo"].scales == ("wide", "coarse", "fine", "full")
    n = len(learner.config.cues["stereo"].scales)
    for _ in range(2):
        record = learner.iteration(env)
    for cue in (record.parallax, record.stereo):
        assert cue.errors.shape == (2, n) and torch.allclose(cue.reward, -cue.errors.sum(1))
        assert torch.isfinite(cue.td_error).all()
    for encoder in (learner.parallax.encoder, learner.stereo.encoder):  # 32 atoms per scale
        assert encoder.num_features == 32 * n and encoder.dictionaries[newest].atoms.shape[0] == dim


def test_no_learning_across_a_fixation_boundary():
    env, learner = make(h=2)
    records = [learner.iteration(env) for _ in range(4)]
    assert [r.fixation_end for r in records] == [False, True, False, True]
    assert records[2].parallax.td_error is None and records[2].stereo.td_error is None
    assert records[3].stereo.td_error is not None


def test_trials_feed_the_depth_mlp_honestly():
    env, learner = make(num_envs=4, h=1, depth_every_trials=12)
    predictions, retrained = [], []
    for _ in range(8):  # 4 trials x 4 environments
        record = learner.iteration(env)
        if record.trial_end:
            predictions.append(record.depth_prediction_m)
            retrained.append(record.depth_retrained)
            assert record.q_deg.shape == (4, 4) and record.distance_m.shape == (4,)
    assert retrained == [False, False, True, False]
    assert torch.isnan(predictions[0]).all() and torch.isnan(predictions[2]).all()
    assert torch.isfinite(predictions[3]).all()  # predicted by the MLP trained on earlier trials
    assert learner.depth_inputs.shape == (16, 4) and learner.trials_seen == 16


def _geometry_q(distance: torch.Tensor, noise: float, seed: int) -> torch.Tensor:
    # q1..q4 of perfect fixations (pursuit of the 0.1 m shift, vergence of the 0.06 m baseline), plus noise.
    pursuit = torch.rad2deg(torch.atan(0.1 / distance))
    vergence = torch.rad2deg(2 * torch.atan(0.03 / distance))
    q = torch.stack((-pursuit, vergence, pursuit, vergence), -1)
    return q + noise * torch.randn(q.shape, generator=torch.Generator().manual_seed(seed), dtype=q.dtype)


def test_calibrate_depth_refits_on_the_given_trials_only():
    env, learner = make(num_envs=4, h=1, depth_every_trials=12)
    for _ in range(8):  # the MLP is fitted once during training, on 12 trials
        learner.iteration(env)
    stored = (learner.depth_inputs.clone(), learner.depth_targets.clone(), learner.trials_seen)
    distance = 1 + 2 * torch.rand(200, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    q = _geometry_q(distance, 0.01, seed=3)
    learner.calibrate_depth(q, distance, seed=0)
    fresh = 1 + 2 * torch.rand(100, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    error = (learner.predict_depth(_geometry_q(fresh, 0.01, seed=5)).double() - fresh).abs().mean()
    assert error < 0.05  # the geometry's depth, learned from the calibration trials alone
    assert torch.equal(learner.depth_inputs, stored[0]) and torch.equal(learner.depth_targets, stored[1])
    assert learner.trials_seen == stored[2]
    with pytest.raises(ValueError, match="q_deg"):
        learner.calibrate_depth(q[:, :3], distance)
    with pytest.raises(ValueError, match="distance_m"):
        learner.calibrate_depth(q, distance[:-1])
    with pytest.raises(ValueError, match="at least 10"):
        learner.calibrate_depth(q[:5], distance[:5])
    with pytest.raises(ValueError, match="finite"):
        learner.calibrate_depth(torch.full((20, 4), float("nan")), distance[:20])


def test_learn_false_freezes_everything():
    env, learner = make()
    learner.iteration(env)
    before = copy.deepcopy(learner.state_dict())
    for _ in range(3):
        learner.iteration(env, learn=False, greedy=True)
    after = learner.state_dict()
    for key, value in before.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, after[key]), key


def test_learning_moves_dictionaries_and_policies():
    env, learner = make()
    before = copy.deepcopy(learner.state_dict())
    for _ in range(3):
        learner.iteration(env)
    after = learner.state_dict()
    for key in ("cues.parallax.encoder.dictionaries.coarse.atoms", "cues.stereo.encoder.dictionaries.fine.atoms",
                "cues.parallax.agent.actor_weight", "cues.stereo.agent.critic_weight"):
        assert not torch.equal(before[key], after[key]), key


def test_a_cue_whose_plasticity_has_closed_learns_nothing_while_the_others_learn():
    env, learner = make(cue={"learn_until": 2})
    assert learner.closed_cues(1) == () and learner.closed_cues(2) == ("parallax", "stereo")
    learner.config.cues["stereo"].learn_until = None  # only the parallax cue closes
    learner.cues["stereo"].config.learn_until = None
    assert learner.closed_cues(5) == ("parallax",)
    learner.iteration(env, closed=learner.closed_cues(0))
    before = copy.deepcopy(learner.state_dict())
    for it in range(2, 5):
        record = learner.iteration(env, closed=learner.closed_cues(it))
        assert record.cues["parallax"].td_error is None
    after = learner.state_dict()
    for key, value in before.items():
        if isinstance(value, torch.Tensor) and key.startswith("cues.parallax."):
            assert torch.equal(value, after[key]), key  # the dictionaries, the agent, its statistics
    assert not torch.equal(before["cues.stereo.encoder.dictionaries.fine.atoms"],
                           after["cues.stereo.encoder.dictionaries.fine.atoms"])
    assert not torch.equal(before["cues.stereo.agent.actor_weight"], after["cues.stereo.agent.actor_weight"])
    with pytest.raises(ValueError, match="cue.learn_until must be"):
        CueConfig(learn_until=-1)


def test_state_dict_round_trip_continues_identically():
    env, learner = make()
    for _ in range(3):
        learner.iteration(env)
    state = copy.deepcopy(learner.state_dict())
    env_copy = copy.deepcopy(env)
    _, twin = make()
    twin.load_state_dict(state)
    a = [learner.iteration(env).stereo.td_error for _ in range(2)]
    b = [twin.iteration(env_copy).stereo.td_error for _ in range(2)]
    for x, y in zip(a, b):
        torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="encoder.algorithm"):
        EncoderConfig(algorithm="lasso")
    with pytest.raises(ValueError, match="cue.scales"):
        CueConfig(scales=("medium",))
    with pytest.raises(ValueError, match="cue.agent"):
        CueConfig(agent="dqn")
    with pytest.raises(ValueError, match="depth_every_trials"):
        LearnerConfig(depth_every_trials=0)
    with pytest.raises(ValueError, match=r"learner.active_cues must be a non-empty list of distinct cues from \['parallax', 'stereo'\]"):
        LearnerConfig(active_cues=["vergence"])


@pytest.mark.parametrize("reward", ["coding", "improvement", "scaled"])
def test_the_actor_critics_learn_from_the_configured_reward(reward):
    # With the critic at 0 and J = 0, the first TD error is (1 - xi) times the reward learned from:
    # R(s') for "coding", R(s') - R(s) for "improvement", that over its root mean square for
    # "scaled" (the first batch's own).
    control = ActorCriticConfig(critic_init=0.0, critic_discount=0.5)
    env, learner = make(h=3, cue=dict(reward=reward, nac=control))
    first = learner.iteration(env)
    second = learner.iteration(env)
    for cue_first, cue_second in ((first.parallax, second.parallax), (first.stereo, second.stereo)):
        learned = cue_second.reward - (cue_first.reward if reward != "coding" else 0.0)
        if reward == "scaled":
            learned = learned / learned.double().square().mean().add(1e-12).sqrt().to(learned.dtype)
        torch.testing.assert_close(cue_second.td_error, (1 - control.xi) * learned)
    scales = [name for name in learner.state_dict() if "reward_scale" in name]
    assert bool(scales) == (reward == "scaled")  # its running scale is in the checkpoint


@pytest.mark.parametrize("reward", ["coding", "improvement"])
def test_the_motor_cost_charges_the_increment_that_led_to_the_reward(reward):
    # As above, the first TD error is (1 - xi) times what is learned from: now minus cost * |a|.
    control = ActorCriticConfig(critic_init=0.0, critic_discount=0.5)
    env, learner = make(h=3, cue=dict(reward=reward, nac=control, motor_cost=0.25))
    first = learner.iteration(env)
    second = learner.iteration(env)
    assert bool((first.stereo.increments_deg != 0).any())
    for cue_first, cue_second in ((first.parallax, second.parallax), (first.stereo, second.stereo)):
        learned = cue_second.reward - (cue_first.reward if reward == "improvement" else 0.0)
        learned = learned - 0.25 * cue_first.increments_deg.abs()
        torch.testing.assert_close(cue_second.td_error, (1 - control.xi) * learned)
    with pytest.raises(ValueError, match="cue.motor_cost must be a finite number >= 0"):
        CueConfig(motor_cost=-0.1)


def test_unit_features_reach_the_actor_critics_normalised():
    control = ActorCriticConfig(normalize_features=True)
    env, learner = make(h=3, cue=dict(features="unit", feature_scale=2.0, nac=control, symmetry=None))
    with torch.no_grad():
        pooled = learner.parallax.encoder(env.observe("parallax", learner.parallax.encoder.scales)).features
    learner.iteration(env)
    learner.iteration(env)  # learns from the first transition: its features join the statistics
    expected = 2.0 * pooled / pooled.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(learner.parallax.agent.feature_mean, expected.mean(0))


def test_cue_config_rejects_unknown_reward_and_features():
    with pytest.raises(ValueError, match="cue.reward"):
        CueConfig(reward="bonus")
    with pytest.raises(ValueError, match="cue.features"):
        CueConfig(features="raw")


def test_the_symmetric_cues_learn_equivariant_policies():
    # The pursuit policy of the mirrored parallax features, and the vergence policy of the swapped
    # stereo features, are the policies with every action negated, and the critics give both the
    # same value: after learning too.
    env, learner = make(num_envs=3, h=4)
    assert [c.symmetry for c in learner.config.cues.values()] == ["mirror", "swap"]
    for _ in range(6):
        learner.iteration(env)
    actions = learner.parallax.agent.actions_deg
    negate = (actions[None, :] == -actions[:, None]).int().argmax(-1)
    assert torch.equal(actions[negate], -actions)
    with torch.no_grad():
        for name, cue in learner.cues.items():
            encoder, agent = cue.encoder, cue.agent
            f = encoder(env.observe(name)).features * cue.config.feature_scale
            fm = f[:, encoder.feature_permutation]
            assert not torch.allclose(fm, f, rtol=1e-2)  # the transformed features do differ
            probs = agent(f)
            torch.testing.assert_close(agent(fm), probs[:, negate])
            torch.testing.assert_close(agent.value(fm), agent.value(f))
            assert not torch.allclose(probs, probs[:, negate], rtol=1e-3)  # and the policy prefers a direction


def test_symmetry_config_is_validated():
    with pytest.raises(ValueError, match="cue.symmetry"):
        CueConfig(symmetry="motion")
    with pytest.raises(ValueError, match="actions_deg must be symmetric"):
        CueConfig(actions_deg=(-1.0, 0.0, 0.5), symmetry="swap")
    CueConfig(actions_deg=(-1.0, 0.0, 0.5))
    with pytest.raises(ValueError, match="num_atoms must be even"):
        CueConfig(encoder=EncoderConfig(num_atoms=33), symmetry="mirror")


@pytest.mark.parametrize("num_envs", [1, 4])
def test_small_batches_train_with_the_default_steps(num_envs):
    """B = 1 (the paper's sequential algorithm) and B = 4 with the default learner and world: the
    TD errors stay far below the watchdog's limit and the policies keep exploring. With the
    defaults until 2026-12-02 (z-scored features of any norm, every update's full step on the mean
    of its B transitions) B = 1's first z-scores, from a handful of samples, are huge and its
    critic diverges within a few dozen iterations."""
    from aectorch.runtime.watchdog import WatchdogConfig

    limit = WatchdogConfig().td_error_max

    def run(control):
        env = ActiveDepthEnv(num_envs, protocol=TrialProtocol(shift_iterations=20, yoked_pursuit=True), seed=0)
        learner = JointLearner(LearnerConfig(cues=default_cues(nac=control, agent="nac")),
                               generator=torch.Generator().manual_seed(0))
        worst, entropy = 0.0, []
        for _ in range(60):
            record = learner.iteration(env)
            for cue in (record.parallax, record.stereo):
                if cue.td_error is not None:
                    worst = max(worst, float(cue.td_error.abs().max()))
                entropy.append(float(cue.entropy.mean()))
        return worst, min(entropy)

    control = ActorCriticConfig()
    assert control.batch_reference is not None
    worst, entropy = run(control)
    assert worst < limit / 10 and entropy > 1.0, (worst, entropy)
    if num_envs == 1:
        import dataclasses

        worst, _ = run(dataclasses.replace(control, batch_reference=None, feature_norm=None))
        assert worst > limit, worst


def test_centred_patches_make_the_parallax_features_exactly_mirror_equivariant():
    """The symmetry learns from mirrored transitions with the features permuted: with centred
    sampling those are the features of the mirrored images; with the classic reduce they are not."""
    gen = torch.Generator().manual_seed(1)
    first, second = torch.nn.functional.avg_pool2d(torch.rand(2, 3, 132, 132, generator=gen), 5, 1).unbind(0)
    gaps = {}
    for centred in (False, True):
        cues = default_cues(encoder=EncoderConfig(centred=centred))
        encoder = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0)).parallax.encoder
        with torch.no_grad():
            f = encoder(first, second).features
            mirrored = encoder(first.flip(-1), second.flip(-1)).features
        gaps[centred] = float(((mirrored - f[:, encoder.feature_permutation]).norm(dim=1) / f.norm(dim=1)).max())
    assert gaps[True] < 1e-4 and gaps[False] > 0.1, gaps
    with pytest.raises(ValueError, match="encoder.centred"):
        EncoderConfig(centred="yes")


def test_dictionary_rate_decays_and_resumes():
    env, learner = make(encoder=dict(decay=2.0, decay_power=2.0))
    config = learner.parallax.encoder.config
    assert config.rate(0) == pytest.approx(0.1) and config.rate(2) == pytest.approx(0.025)
    before = learner.parallax.encoder.dictionaries["fine"].atoms.clone()
    learner.iteration(env)
    assert learner.dictionary_steps == {"parallax": 1, "stereo": 1}
    assert learner.parallax.encoder.rate() == pytest.approx(0.1 * (2 / 3) ** 2)
    assert not torch.equal(before, learner.parallax.encoder.dictionaries["fine"].atoms)
    twin = make(encoder=dict(decay=2.0, decay_power=2.0))[1]
    twin.load_state_dict(learner.state_dict())
    assert twin.dictionary_steps == {"parallax": 1, "stereo": 1}
    with pytest.raises(ValueError, match="encoder.decay"):
        EncoderConfig(decay=0)


def test_one_process_shard_state_names_and_buffer_dtype():
    """A Shard of world size > 1 must come from the process group; the learner's state is named by
    its modules (the cues as data); loaded depth buffers keep the learner's dtype."""
    from aectorch.framework import Shard

    with pytest.raises(ValueError, match="ProcessGroupShard"):
        Shard(rank=0, world_size=2, start=0, stop=2, total=4)
    _, learner = make(encoder=dict(num_atoms=16))
    assert {"cues.parallax.encoder.dictionaries.fine.atoms", "cues.parallax.agent.actor_weight",
            "depth_learner.inputs", "cues.stereo._extra_state"} <= set(learner.state_dict())
    state = learner.state_dict()
    del state["depth_learner.inputs"]
    assert learner.load_state_dict(state, strict=False).missing_keys == ["depth_learner.inputs"]
    wide = JointLearner(learner.config, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    state = learner.state_dict()
    state["depth_learner.inputs"], state["depth_learner.targets"] = torch.ones(3, 4), torch.ones(3)
    wide.load_state_dict(state)
    assert wide.depth_inputs.dtype == torch.float64 and wide.depth_inputs.shape == (3, 4)


# -- cues and agents as data --------------------------------------------------------------------------
@pytest.mark.parametrize("active, held", [(["stereo"], "pursuit"), (["parallax"], "vergence")])
def test_a_learner_of_one_cue_has_the_environment_hold_the_other_at_its_optimum(active, held):
    env, learner = make(h=3, active_cues=active)
    assert list(learner.cues) == active
    records = [learner.iteration(env) for _ in range(4)]
    for record in records:
        assert list(record.cues) == active
        assert float(record.errors_deg[held].abs().max()) < 1e-4  # held, while the learned one moves
    assert float(records[-1].errors_deg[{"pursuit": "vergence", "vergence": "pursuit"}[held]].abs().max()) > 1e-3
    assert not any(key.startswith(f"cues.{'parallax' if active == ['stereo'] else 'stereo'}")
                   for key in learner.state_dict())


def test_each_cue_builds_the_agent_its_config_names():
    env, learner = make(h=3)
    assert all(isinstance(c.agent, NaturalActorCritic) for c in learner.cues.values())
    assert all(isinstance(c.agent, PPO) for c in JointLearner(LearnerConfig()).cues.values())  # the default
    cues = default_cues(encoder=EncoderConfig(num_atoms=16), agent="nac")
    cues["stereo"] = CueConfig(agent="ppo", symmetry="swap", encoder=EncoderConfig(num_atoms=16))
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    assert isinstance(learner.stereo.agent, PPO) and isinstance(learner.parallax.agent, NaturalActorCritic)
    before = copy.deepcopy(learner.stereo.agent.state_dict())
    updated = [learner.iteration(env).stereo.td_error for _ in range(3)]
    assert updated[0] is None and updated[1].shape == (2,)
    after = learner.stereo.agent.state_dict()  # PPO learned at the fixation's end (iteration 3)
    assert not torch.equal(before["policy.weight"], after["policy.weight"])


def test_a_learner_with_a_cue_the_environment_lacks_says_so():
    cues = {**default_cues(encoder=EncoderConfig(num_atoms=16)), "accommodation": CueConfig(encoder=EncoderConfig(num_atoms=16))}
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    env, _ = make()
    with pytest.raises(ValueError, match=r"the environment has no cue \['accommodation'\]"):
        learner.iteration(env)


def test_a_cues_agent_sees_its_proprioception_after_its_code():
    cues = default_cues(encoder=EncoderConfig(num_atoms=16))
    cues["stereo"].proprioception = ("vergence",)
    cues["accommodation"] = CueConfig(encoder=EncoderConfig(num_atoms=16), scales=("fine", "full"),
                                      efficiency="information", proprioception=["vergence", "focus"])
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3, accommodation_start_D=0.5),
                         textures=torch.rand(3, 64, 64), seed=0)
    acc, stereo = learner.accommodation, learner.stereo
    assert acc.agent.num_features == acc.encoder.num_features + 2
    sensed = []
    def watch(cue, _):
        if cue == "accommodation":
            sensed.append(env.proprioception(["vergence", "focus"]))
    for _ in range(3):  # one fixation: PPO learns from its first two steps at its end
        learner.iteration(env, watch=watch)
    assert torch.equal(sensed[0][:, 1], torch.full((2,), 0.5)) and sensed[1][:, 0].abs().min() > 0
    seen = torch.cat(sensed[:2]).double()
    torch.testing.assert_close(acc.agent.feature_mean[-2:].double(), seen.mean(0))
    # z-scored with the code, but not scaled with it to the agent's feature norm
    f = acc.features(torch.rand(2, acc.encoder.num_features), sensed[2])
    x, a = acc.agent.normalize(f), acc.agent
    z = (f[:, -2:] - a.feature_mean[-2:]) / torch.sqrt(a.feature_m2[-2:] / (a.feature_count - 1) + a.config.normalize_eps)
    torch.testing.assert_close(x[:, -2:], z)
    torch.testing.assert_close(torch.linalg.vector_norm(x[:, :-2], dim=-1), torch.full((2,), a.config.feature_norm))
    # The swap symmetry leaves the vergence angle as it is: its column keeps its place, and the
    # symmetric start weighs it alike for each action and its negation.
    n = stereo.encoder.num_features
    assert int(stereo.feature_permutation[-1]) == n and stereo.feature_permutation.numel() == n + 1
    before = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0)).stereo
    w = before.agent.policy.weight[:, -1]
    torch.testing.assert_close(w, w[before.action_negation])
    pooled = torch.rand(2, acc.encoder.num_features)
    with pytest.raises(ValueError, match=r"proprioception must be \[B, 2\]"):
        acc.features(pooled)


def test_an_agent_with_features_none_senses_its_proprioception_alone():
    cues = default_cues(encoder=EncoderConfig(num_atoms=16))
    cues["accommodation"] = CueConfig(encoder=EncoderConfig(num_atoms=16), scales=("fine", "full"), features="none",
                                      efficiency="information", proprioception=["vergence", "focus"])
    cues["stereo"].features, cues["stereo"].proprioception = "none", ("vergence",)  # with the swap symmetry
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3, accommodation_start_D=0.5),
                         textures=torch.rand(3, 64, 64), seed=0)
    acc, stereo = learner.accommodation, learner.stereo
    assert acc.agent.num_features == 2 and stereo.agent.num_features == 1
    assert stereo.feature_permutation.tolist() == [0]
    before = acc.agent.policy.weight.clone()
    for _ in range(3):  # PPO learns at the fixation's end, from the senses alone
        records = learner.iteration(env)
    assert records.accommodation.reward.shape == (2,) and not torch.equal(before, acc.agent.policy.weight)
    sensed = env.proprioception(["vergence", "focus"])
    f = acc.features(torch.rand(2, acc.encoder.num_features), sensed)
    assert torch.equal(f, sensed)  # the code is left out; the senses are z-scored, not scaled to a norm
    z = (f - acc.agent.feature_mean) / torch.sqrt(acc.agent.feature_m2 / (acc.agent.feature_count - 1)
                                                  + acc.agent.config.normalize_eps)
    torch.testing.assert_close(acc.agent.normalize(f), z.to(f.dtype))
    with pytest.raises(ValueError, match="features=none leaves the agent nothing to see"):
        CueConfig(features="none")


def test_a_cues_agent_learns_from_the_efficiency_of_its_reward_scales():
    cues = default_cues(encoder=EncoderConfig(num_atoms=16))
    cues["stereo"].reward_scales = ("full", "fine")
    cues["accommodation"] = CueConfig(encoder=EncoderConfig(num_atoms=16), scales=("fine", "full"), reward_scales=["full"],
                                      efficiency="information", proprioception=["vergence", "focus"])
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=3, accommodation_start_D=0.5),
                         textures=torch.rand(3, 64, 64), seed=0)
    records = learner.iteration(env)
    stereo, parallax, acc = records.stereo, records.parallax, records.accommodation
    names = [s.name for s in learner.stereo.encoder.scales]
    torch.testing.assert_close(stereo.reward, -stereo.errors[:, [names.index("full"), names.index("fine")]].sum(-1))
    torch.testing.assert_close(parallax.reward, -parallax.errors.sum(-1))  # default: every scale
    # the information of the full scale alone: its own term of the two scales' sum
    both = CueConfig(encoder=EncoderConfig(num_atoms=16), scales=("fine", "full"), efficiency="information")
    observation = env.observe("accommodation", learner.accommodation.encoder.scales)
    out = learner.accommodation.encoder.encode(observation)
    learner.accommodation.config = both
    fine_and_full = learner.accommodation._information(observation, out)
    learner.accommodation.config = dataclasses.replace(both, reward_scales=("fine",))
    fine = learner.accommodation._information(observation, out)
    learner.accommodation.config = dataclasses.replace(both, reward_scales=("full",))
    torch.testing.assert_close(learner.accommodation._information(observation, out), fine_and_full - fine)
    assert acc.reward.shape == (2,)
    with pytest.raises(ValueError, match=r"cue.reward_scales must be distinct names of cue.scales"):
        CueConfig(scales=("fine", "full"), reward_scales=["coarse"])


def test_proprioception_is_checked_where_it_is_configured_and_sensed():
    with pytest.raises(ValueError, match="cue.proprioception must be one of"):
        CueConfig(proprioception=["vergance"])
    with pytest.raises(ValueError, match="'pan' changes sign under cue.symmetry=swap"):
        CueConfig(symmetry="swap", proprioception=["pan"])
    with pytest.raises(ValueError, match="must be distinct"):
        CueConfig(proprioception=["focus", "focus"])
    env, _ = make()
    with pytest.raises(ValueError, match="'focus' needs an environment whose eyes accommodate"):
        env.proprioception(["focus"])
    sensed = env.proprioception(["pan", "vergence"])
    assert torch.equal(sensed, torch.stack((env.left_pan_deg, env.vergence_deg), -1))
    env.set_focus(torch.tensor([0.25, 0.75]))
    assert torch.equal(env.proprioception(["focus"])[:, 0], torch.full((env.num_envs,), 0.25))
    with pytest.raises(ValueError, match="'shift' changes sign under cue.symmetry=mirror"):
        CueConfig(symmetry="mirror", proprioception=["shift"])
    # The body's shift since the fixation's start: 0 at the start, then the protocol's ramp, either way.
    assert torch.equal(env.proprioception(["shift"])[:, 0], env.body_shift_m)
    shifts = []
    for _ in range(2 * env.fixation_iterations):
        shifts.append(env.proprioception(["shift"])[0, 0].item())
        env.end_iteration()
    assert max(shifts) == pytest.approx(env.shift_m) and min(shifts) == pytest.approx(-env.shift_m)


# -- adding a cue: its movement, its config, its tests (docs/architecture.md) ------------------------
class TorsionEnv(ActiveDepthEnv):
    """An environment with a third, toy cue: its movement is one new file (tests/framework/torsion.py),
    registered by naming it in `CUES`."""

    CUES = {**ActiveDepthEnv.CUES, "torsion": Torsion}


def test_a_cue_added_by_its_config_and_its_environment_runs_through_learner_metrics_watchdog_and_figures(tmp_path):
    from aectorch.figures import plot_training
    from aectorch.runtime.metrics import TrainingMetrics
    from aectorch.runtime.watchdog import Watchdog, WatchdogConfig

    env = TorsionEnv(2, protocol=TrialProtocol(fixation_iterations=3),
                     textures=torch.rand(4, 64, 64, generator=torch.Generator().manual_seed(1)), seed=0)
    small = EncoderConfig(num_atoms=16)
    cues = {**default_cues(encoder=small), "torsion": CueConfig(encoder=small, agent="ppo")}
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    metrics = TrainingMetrics.for_learner(learner, 2, window_fixations=4, window_trials=4,
                                          movements=[movement.name for movement in env.CUES.values()])
    dog, lines = Watchdog(WatchdogConfig()), []
    for done in range(1, 13):
        record = learner.iteration(env)
        metrics.update(record)
        assert dog.check(done, record, learner) == []
        lines.append({"iteration": done, **metrics.summary()})
    assert list(record.cues) == ["parallax", "stereo", "torsion"] and record.torsion.td_error is not None
    assert {"torsion_mae_deg", "torsion/reward", "torsion/fine/atom_usage"} <= set(lines[-1])
    assert not torch.equal(env.cue("torsion").torsion_deg, torch.ones(2))  # the cue's agent moved it
    assert "torsion_deg" in env.state_dict()  # its state is the batch's
    assert any(key.startswith("cues.torsion.agent.policy") for key in learner.state_dict())
    assert plot_training(lines, tmp_path / "training.png").stat().st_size > 0
    # a learner without the new cue has the environment hold it at its optimum
    held = JointLearner(LearnerConfig(cues=cues, active_cues=["parallax", "stereo"]),
                        generator=torch.Generator().manual_seed(0))
    assert float(held.iteration(env).errors_deg["torsion"].abs().max()) == 0.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("agent", ["ppo", "nac"])
def test_the_default_learner_learns_on_cuda_with_its_cpu_generator(agent):
    """The learner's generator stays on CPU (checkpoints hold its state); its draws reach a CUDA run:
    the actions' uniform numbers are the CPU generator's, moved (a CUDA run once stopped at the
    first action: a CPU generator cannot draw CUDA numbers)."""
    from aectorch.control import draw_uniform

    env = ActiveDepthEnv(4, seed=0, device="cuda")
    learner = JointLearner(LearnerConfig(cues=default_cues(agent=agent)), generator=torch.Generator().manual_seed(0),
                           device="cuda")
    for _ in range(32):  # past the first fixation's end (30 iterations): the agents learn
        record = learner.iteration(env)
    for cue in record.cues.values():
        assert cue.actions.device.type == "cuda" and bool(torch.isfinite(cue.reward).all())
    g, h = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    u = draw_uniform((3, 1), g, torch.zeros(1, device="cuda"))
    assert u.device.type == "cuda" and torch.equal(u.cpu(), torch.rand(3, 1, generator=h))
