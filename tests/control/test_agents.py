"""The Agent protocol and its second agent, PPO (aectorch.control.ppo).

Oracles: Stable-Baselines3's rollout buffer for the generalised advantage estimates (an
implementation no one here wrote, fed the same values and rewards), a contextual task whose best
action is known, and exact replays for checkpoints and the symmetry.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from aectorch.control import (
    AGENTS, PPO, ActorCriticConfig, Agent, NaturalActorCritic, PPOConfig, Transitions, make_agent, sample_actions,
)

torch.set_num_threads(1)
ACTIONS = (-0.2, -0.1, 0.0, 0.1, 0.2)


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_both_agents_satisfy_the_protocol_and_the_factory_builds_them():
    for name in AGENTS:
        agent = make_agent(name, 6, ACTIONS, generator=_gen())
        assert isinstance(agent, Agent)
        out = agent.act(torch.randn(3, 6, generator=_gen(1)), uniform=torch.rand(3, generator=_gen(2)))
        assert out.actions.shape == (3,)
        torch.testing.assert_close(out.increments_deg, torch.tensor(ACTIONS)[out.actions])
    assert isinstance(make_agent("nac", 6, ACTIONS), NaturalActorCritic)
    assert isinstance(make_agent("ppo", 6, ACTIONS, PPOConfig(epochs=2)), PPO)
    with pytest.raises(ValueError, match="agent must be one of"):
        make_agent("dqn", 6, ACTIONS)


def test_inverse_cdf_sampling_follows_the_probabilities():
    logp = torch.log_softmax(torch.tensor([[0.0, 1.0, 2.0]]), -1).expand(20000, 3)
    u = torch.rand(20000, generator=_gen(3))
    counts = torch.bincount(sample_actions(logp, u), minlength=3).double() / 20000
    torch.testing.assert_close(counts, logp[0].exp().double(), atol=0.01, rtol=0)


def _rollout(b: int, t: int, f: int, boundaries=(), seed: int = 0):
    """Features of a consistent rollout (next state = the following step's state within a
    fixation, a fresh state after each boundary), rewards and the `last` flags."""
    g = _gen(seed)
    states = torch.randn(b, t + 1, f, generator=g, dtype=torch.float64)
    features, next_features = states[:, :-1].clone(), states[:, 1:].clone()
    last = torch.zeros(t, dtype=torch.bool)
    last[-1] = True
    for step in boundaries:  # a new fixation starts after `step`: its next state is not the next step's
        last[step] = True
        next_features[:, step] = torch.randn(b, f, generator=g, dtype=torch.float64)
    rewards = torch.randn(b, t, generator=g, dtype=torch.float64)
    return features, next_features, rewards, last


@pytest.mark.parametrize("boundaries", [(), (4,), (2, 6)])
def test_ppo_advantages_match_stable_baselines3s_rollout_buffer(boundaries):
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer

    b, t, f = 3, 9, 5
    agent = PPO(f, ACTIONS, PPOConfig(discount=0.9, gae_lambda=0.8), generator=_gen(), dtype=torch.float64)
    with torch.no_grad():
        agent.value.weight.copy_(torch.randn(1, f, generator=_gen(4), dtype=torch.float64))
    features, next_features, rewards, last = _rollout(b, t, f, boundaries)
    advantage, target = agent.advantages(features, next_features, rewards, last)

    values = agent.value(agent.normalize(features))[..., 0].detach()
    next_values = agent.value(agent.normalize(next_features))[..., 0].detach()
    buffer = RolloutBuffer(t, spaces.Box(-np.inf, np.inf, (f,)), spaces.Discrete(len(ACTIONS)), device="cpu",
                           gamma=0.9, gae_lambda=0.8, n_envs=b)
    for step in range(t):
        reward = rewards[:, step].clone()
        if step in boundaries:  # SB3's time-limit rule: bootstrap the truncated episode into its reward
            reward += 0.9 * next_values[:, step]
        start = np.full(b, float(step == 0 or (step - 1) in boundaries))
        buffer.add(features[:, step].numpy(), np.zeros((b, 1)), reward.numpy(), start, values[:, step, None],
                   torch.zeros(b))
    buffer.compute_returns_and_advantage(last_values=next_values[:, -1, None], dones=np.zeros(b))
    np.testing.assert_allclose(advantage[..., 0].numpy(), buffer.advantages.T, rtol=0, atol=2e-6)  # SB3 stores float32
    np.testing.assert_allclose(target[..., 0].numpy(), buffer.returns.T, rtol=0, atol=2e-6)  # SB3 stores float32


def _bandit(agent, steps: int, seed: int, batch: int = 16) -> float:
    """A contextual task: the features say which action is right (+0.1 deg or -0.1 deg); the reward
    is 1 for it and 0 otherwise; fixations of 5 steps. Returns the greedy policy's accuracy."""
    g = _gen(seed)
    right = torch.tensor([ACTIONS.index(-0.1), ACTIONS.index(0.1)])

    def observe(n):
        side = torch.randint(0, 2, (n,), generator=g)
        f = torch.nn.functional.one_hot(side, 2).double() + 0.1 * torch.randn(n, 2, generator=g, dtype=torch.float64)
        return f, side

    f, side = observe(batch)
    for step in range(steps):
        act = agent.act(f, uniform=torch.rand(batch, generator=g, dtype=torch.float64))
        reward = (act.actions == right[side]).double()
        f_next, side_next = observe(batch)
        agent.learn(Transitions(f, act.actions, reward, f_next, last=step % 5 == 4))
        f, side = f_next, side_next
    test, test_side = observe(1000)
    return float((agent.act(test, greedy=True).actions == right[test_side]).double().mean())


def test_ppo_learns_a_contextual_task_that_a_fixed_policy_cannot_solve():
    agent = PPO(2, ACTIONS, PPOConfig(lr=0.03, discount=0.0, entropy_coef=0.0), generator=_gen(5),
                dtype=torch.float64)
    before = float(_bandit(copy.deepcopy(agent), 0, seed=6))
    assert before < 0.7  # about one action in two by chance (the initial policy is near uniform)
    assert _bandit(agent, 400, seed=6) > 0.95


def test_ppo_updates_once_per_rollout_of_fixations():
    agent = PPO(3, ACTIONS, PPOConfig(fixations=2), generator=_gen())
    f = torch.randn(4, 3, generator=_gen(1))
    flags = []
    for step in range(6):
        act = agent.act(f, uniform=torch.rand(4, generator=_gen(step)))
        flags.append(agent.learn(Transitions(f, act.actions, torch.ones(4), f, last=step in (1, 3, 5))).updated)
    assert flags == [False, False, False, True, False, False]


def test_a_ppo_agent_restored_mid_rollout_learns_exactly_as_the_original():
    def steps(agent, first, count, generator):
        f = torch.randn(4, 3, generator=generator)
        for step in range(first, first + count):
            act = agent.act(f, uniform=torch.rand(4, generator=generator))
            f_next = torch.randn(4, 3, generator=generator)
            agent.learn(Transitions(f, act.actions, torch.randn(4, generator=generator), f_next, last=step % 4 == 3))
            f = f_next

    agent = PPO(3, ACTIONS, generator=_gen(7))
    data = _gen(8)
    steps(agent, 0, 6, data)  # one update, then half a rollout
    saved, data_state = copy.deepcopy(agent.state_dict()), data.get_state()
    twin = PPO(3, ACTIONS, generator=_gen(7))
    twin.load_state_dict(saved)
    twin.generator.set_state(agent.generator.get_state())
    steps(agent, 6, 6, data)
    data.set_state(data_state)
    steps(twin, 6, 6, data)
    for (name, a), b in zip(agent.state_dict().items(), twin.state_dict().values()):
        if isinstance(a, torch.Tensor):
            assert torch.equal(a, b), name


def test_a_symmetrized_agent_gives_the_transformed_state_the_negated_actions_probabilities():
    permutation = torch.tensor([1, 0, 3, 2])
    negation = torch.tensor([len(ACTIONS) - 1 - i for i in range(len(ACTIONS))])
    f = torch.randn(5, 4, generator=_gen(9), dtype=torch.float64)
    for agent in (PPO(4, ACTIONS, PPOConfig(actor_init=1.0), generator=_gen(), dtype=torch.float64),
                  NaturalActorCritic(4, ACTIONS, ActorCriticConfig(normalize_features=False, feature_norm=None,
                                                                   actor_init=1.0), generator=_gen(), dtype=torch.float64)):
        agent.symmetrize_(permutation, negation)
        logp = agent.log_policy(f) if isinstance(agent, PPO) else agent(f).log()
        logp_t = agent.log_policy(f[:, permutation]) if isinstance(agent, PPO) else agent(f[:, permutation]).log()
        torch.testing.assert_close(logp_t, logp[:, negation])


def test_ppo_lr_decays_by_the_updates_made():
    agent = PPO(3, ACTIONS, PPOConfig(lr=0.01, lr_decay=2.0), generator=_gen())
    constant = PPO(3, ACTIONS, PPOConfig(lr=0.01), generator=_gen())
    f = torch.randn(4, 3, generator=_gen(1))
    rates = []
    for step in range(3):
        for a in (agent, constant):
            act = a.act(f, uniform=torch.rand(4, generator=_gen(step)))
            a.learn(Transitions(f, act.actions, torch.randn(4, generator=_gen(step)), f, last=True))
        rates.append((agent.optimizer.param_groups[0]["lr"], constant.optimizer.param_groups[0]["lr"]))
    assert rates == [(0.01, 0.01), (pytest.approx(0.01 * 2 / 3), 0.01), (pytest.approx(0.005), 0.01)]
    assert not torch.equal(agent.policy.weight, constant.policy.weight)  # the first update alike, then not


def test_ppo_weight_decay_shrinks_the_policy_weights_alone():
    decayed = PPO(3, ACTIONS, PPOConfig(lr=0.01, weight_decay=5.0, actor_init=1.0), generator=_gen())
    plain = PPO(3, ACTIONS, PPOConfig(lr=0.01, actor_init=1.0), generator=_gen())
    assert type(plain.optimizer) is torch.optim.Adam  # no decay: plain Adam over one group, as before
    f = torch.randn(8, 3, generator=_gen(1))
    for step in range(4):
        for a in (decayed, plain):
            act = a.act(f, uniform=torch.rand(8, generator=_gen(step)))
            a.learn(Transitions(f, act.actions, torch.randn(8, generator=_gen(step)), f, last=True))
    # only the policy's weight matrix decays; its bias and the value function do not
    groups = {id(p): g["weight_decay"] for g in decayed.optimizer.param_groups for p in g["params"]}
    assert groups == {id(decayed.policy.weight): 5.0, id(decayed.policy.bias): 0.0,
                      id(decayed.value.weight): 0.0, id(decayed.value.bias): 0.0}
    # the policy's weights shrink by about (1 - lr * decay) per Adam step (4 updates of 4 x 4 steps)
    ratio = float(decayed.policy.weight.norm() / plain.policy.weight.norm())
    assert ratio < 0.6


def test_ppo_logit_penalty_softens_a_saturated_policy_where_the_entropy_bonus_does_not():
    # A policy that has put all its mass on one action (logits 20 apart), and rewards of noise that
    # favour no action. The entropy bonus's gradient vanishes there (-p (log p + H) in each logit)
    # and drowns in the noise; the penalty on the centred logits pulls them together.
    f = torch.randn(16, 3, generator=_gen(1))
    spreads = {}
    for name, options in (("entropy", {}), ("penalty", dict(logit_penalty=0.1))):
        agent = PPO(3, ACTIONS, PPOConfig(lr=0.05, entropy_coef=0.05, feature_norm=None, **options), generator=_gen())
        with torch.no_grad():
            agent.policy.weight.zero_()
            agent.policy.bias.copy_(torch.linspace(-10, 10, len(ACTIONS)))
        for step in range(8):
            act = agent.act(f, uniform=torch.rand(16, generator=_gen(step)))
            agent.learn(Transitions(f, act.actions, torch.randn(16, generator=_gen(100 + step)), f, last=True))
        logits = agent.log_policy(f)
        spreads[name] = float((logits.max(-1).values - logits.min(-1).values).mean())
    assert spreads["penalty"] < 0.7 * spreads["entropy"], spreads


def test_ppo_config_rejects_bad_values():
    for field, value in (("lr", 0), ("epochs", 0), ("discount", 1.5), ("gae_lambda", -0.1), ("hidden", -1),
                         ("clip", -0.2), ("feature_norm", 0), ("lr_decay", 0), ("weight_decay", -1),
                         ("logit_penalty", -0.1)):
        with pytest.raises(ValueError, match=f"PPOConfig.{field} must be"):
            PPOConfig(**{field: value})


def _bits(t: torch.Tensor) -> torch.Tensor:
    t = t.detach().contiguous()
    return t.view({4: torch.int32, 8: torch.int64}[t.element_size()]) if t.dtype.is_floating_point else t


def _stock_loss(agent: PPO):
    """The ClipPPOLoss of commit 4065a9b on ``agent``'s networks: TorchRL's stock wrappers and
    validated categorical distributions."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import ProbabilisticActor, ValueOperator
    from torchrl.objectives import ClipPPOLoss

    cfg = agent.config
    actor = ProbabilisticActor(TensorDictModule(agent.policy, in_keys=["observation"], out_keys=["logits"]),
                               in_keys=["logits"], distribution_class=torch.distributions.Categorical,
                               return_log_prob=True)
    return ClipPPOLoss(actor, ValueOperator(agent.value, in_keys=["observation"]), clip_epsilon=cfg.clip,
                       entropy_coeff=cfg.entropy_coef, critic_coeff=cfg.value_coef, loss_critic_type="l2",
                       normalize_advantage=cfg.normalize_advantage, functional=False, log_explained_variance=False)


def _reference_learn(agent: PPO, t: Transitions) -> torch.Tensor:
    """PPO's learn as first written (commit 4065a9b), on ``agent``'s networks, optimizer, generator
    and buffers: every tensor computed afresh (three z-scorings of the rollout, its TensorDict
    indexed per minibatch, the z-scoring's moments merged under a mask of ones), the loss built
    from TorchRL's stock wrappers (`_stock_loss`, set as ``agent._loss`` by the caller)."""
    from tensordict import TensorDict

    def normalize(f):
        n = agent.feature_count.to(f.dtype)
        var = torch.where(n > 1, agent.feature_m2 / (n - 1).clamp_min(1), torch.ones_like(agent.feature_m2))
        x = (f - agent.feature_mean) / torch.sqrt(var + agent.config.normalize_eps)
        return x * (agent.config.feature_norm / torch.linalg.vector_norm(x, dim=-1, keepdim=True).clamp_min(
            torch.finfo(x.dtype).tiny))

    cfg = agent.config
    with torch.no_grad():
        value = agent.value(normalize(t.features))[:, 0]
        td_error = t.rewards + cfg.discount * agent.value(normalize(t.next_features))[:, 0] - value
    agent._rollout.append(t)
    if not t.last:
        return td_error
    rollout = agent._rollout
    features, actions, rewards, next_features = (torch.stack([s[i] for s in rollout], 1) for i in range(4))
    last = torch.tensor([s.last for s in rollout])
    with torch.no_grad():
        v, nv = agent.value(normalize(features)), agent.value(normalize(next_features))
        done = last[None, :, None].expand_as(v).clone()
        advantage, target = agent._gae(cfg.discount, cfg.gae_lambda, v, nv, rewards[..., None], done,
                                       torch.zeros_like(done))
        x = normalize(features)
        old = torch.log_softmax(agent.policy(x), -1).gather(-1, actions[..., None])[..., 0]
    batch = TensorDict({"observation": x.flatten(0, 1), "action": actions.flatten(), "action_log_prob": old.flatten(),
                        "advantage": advantage.flatten(0, 1), "value_target": target.flatten(0, 1)},
                       batch_size=[actions.numel()])
    parameters = [p for group in agent.optimizer.param_groups for p in group["params"]]
    size = batch.batch_size[0] // cfg.minibatches
    for _ in range(cfg.epochs):
        order = torch.randperm(batch.batch_size[0], generator=agent.generator)
        for start in range(0, size * cfg.minibatches, size):
            losses = agent._loss(batch[order[start:start + size]])
            agent.optimizer.zero_grad(set_to_none=False)
            (losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]).backward()
            torch.nn.utils.clip_grad_norm_(parameters, cfg.max_grad_norm)
            agent.optimizer.step()
    flat = features.flatten(0, 1)
    m = torch.ones(flat.shape[0], 1)
    nb, n = m.sum(), agent.feature_count.to(flat.dtype)
    total = (n + nb).clamp_min(1)
    mean_b = (m * flat).sum(0) / nb.clamp_min(1)
    diff = mean_b - agent.feature_mean
    agent.feature_m2.copy_(agent.feature_m2 + (m * (flat - mean_b).square()).sum(0) + diff.square() * (n * nb / total))
    agent.feature_mean.copy_(agent.feature_mean + diff * (nb / total))
    agent.feature_count += flat.shape[0]
    agent._rollout = []
    return td_error


def test_ppo_learns_bit_for_bit_as_a_plain_reference():
    """The agent's shortcuts (z-scoring once, in memory kept across updates; minibatches as
    slices of each epoch's shuffled copy; the loss's networks without TorchRL's wrappers, its
    distributions unvalidated) change no bit: TD errors, actions, parameters, Adam's state, the
    statistics and the generator as a plain reference's, over fixations of several lengths (the
    kept memory reused smaller and grown) and transitions whose features are and are not the last
    call's next ones."""
    agent = PPO(6, ACTIONS, PPOConfig(epochs=2, minibatches=3), generator=_gen(3))
    reference = copy.deepcopy(agent)
    reference.__dict__["_loss"] = _stock_loss(reference)
    data = _gen(4)
    f = torch.rand(8, 6, generator=data)
    for fixation, length in enumerate((6, 3, 9, 4)):
        for step in range(length):
            if step == 2:  # not the last call's next features
                f = torch.rand(8, 6, generator=data)
            if step == 3:  # the same numbers in another tensor, one zero's sign flipped
                f = f.clone()
                f[0, 0] = -0.0 if _bits(f[0, 0]) == 0 else f[0, 0]
            u = torch.rand(8, generator=data)
            act, ref_act = agent.act(f, uniform=u), reference.act(f, uniform=u)
            assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(act, ref_act))
            f_next = torch.rand(8, 6, generator=data) * (torch.rand(8, 6, generator=data) > 0.3)  # zeros too
            t = Transitions(f, act.actions, torch.randn(8, generator=data), f_next, last=step == length - 1)
            out = agent.learn(t)
            assert torch.equal(_bits(out.td_error), _bits(_reference_learn(reference, t))), (fixation, step)
            f = f_next
        assert out.updated
        state, expected = agent.state_dict(), reference.state_dict()
        for name in state:
            if isinstance(state[name], torch.Tensor):
                assert torch.equal(_bits(state[name]), _bits(expected[name])), (fixation, name)
        moments = [v for s in agent.optimizer.state_dict()["state"].values() for v in s.values()]
        expected_moments = [v for s in reference.optimizer.state_dict()["state"].values() for v in s.values()]
        assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(moments, expected_moments, strict=True))
        assert torch.equal(agent.generator.get_state(), reference.generator.get_state())
