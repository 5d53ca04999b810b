"""Tests for aectorch.control.actor_critic: NaturalActorCritic (Bhatnagar et al. 2009, algorithm 3).

Oracles: a plain float64 numpy loop written from the equations (one environment at a time, the
explicit matrix psi psi^T, statistics recomputed from all features seen), the batched rule applied
to that loop, a contextual bandit whose best action depends on the features, and a 1-D angle-error
task whose optimal greedy policy is known.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aectorch.control import (
    PAPER_ACTIONS_DEG,
    ActorCriticConfig,
    ActOutput,
    NaturalActorCritic,
    UpdateOutput,
)

torch.set_num_threads(1)
PAPER_FORM = ActorCriticConfig.paper_form()


def paper_nac(num_features, actions_deg=PAPER_ACTIONS_DEG, config=None, **options):
    """The agent in the paper-faithful form with the paper's actions (the oracles' setting) unless told."""
    return NaturalActorCritic(num_features, actions_deg, PAPER_FORM if config is None else config, **options)

F64 = torch.float64
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# --------------------------------------------------------------------------- reference
def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max())
    return e / e.sum()


def _reference(cfg: ActorCriticConfig, theta, v, transitions):
    """Algorithm 3 as a per-step, per-environment float64 loop, with the documented batched rule.

    Each environment takes the sequential step from the shared state; J, v, w become the mean of
    the per-environment results over the environments that update, and the actor steps with the
    mean w. With one environment this is the sequential algorithm. Returns the final state and
    the TD errors of every step.
    """
    theta = np.array(theta, dtype=np.float64)
    v = np.array(v, dtype=np.float64)
    w = np.zeros_like(theta)
    j = 0.0
    seen: list[np.ndarray] = []
    num_actions = theta.shape[0]
    alpha_w = cfg.alpha_v if cfg.alpha_w is None else cfg.alpha_w
    temp = cfg.temperature
    deltas = []
    for f, a, r, f2, first in transitions:
        if cfg.normalize_features:
            hist = np.array(seen) if seen else np.zeros((0, f.shape[1]))
            mean = hist.mean(0) if len(hist) > 0 else np.zeros(f.shape[1])
            var = hist.var(0, ddof=1) if len(hist) > 1 else np.ones(f.shape[1])
            norm = lambda x: (x - mean) / np.sqrt(var + cfg.normalize_eps)  # noqa: E731
        else:
            norm = lambda x: x  # noqa: E731
        if cfg.feature_norm is not None:
            norm = (lambda inner: lambda x: inner(x) * cfg.feature_norm / np.linalg.norm(inner(x)))(norm)
        js, vs, ws, step_deltas = [], [], [], []
        for b in range(f.shape[0]):
            x, x2 = norm(f[b]), norm(f2[b])
            j_b = (1 - cfg.xi) * j + cfg.xi * r[b]
            delta = r[b] - j_b + cfg.critic_discount * (v @ x2) - v @ x
            pi = _softmax(theta @ x / temp)
            e_a = np.eye(num_actions)[a[b]]
            psi = np.outer(e_a - pi, x).ravel() / temp
            fisher = np.outer(psi, psi)  # the paper's psi psi^T, formed on purpose
            w_b = w.ravel() + alpha_w * (delta * psi - fisher @ w.ravel())
            step_deltas.append(delta)
            if first is None or not first[b]:
                js.append(j_b)
                vs.append(v + cfg.alpha_v * delta * x)
                ws.append(w_b.reshape(w.shape))
        deltas.append(np.array(step_deltas))
        if js:
            j = float(np.mean(js))
            v = np.mean(vs, axis=0)
            w = np.mean(ws, axis=0)
            theta = (1 - cfg.alpha_theta * cfg.weight_decay) * theta + cfg.alpha_theta * w
            if cfg.projection == "ball":
                theta = theta * min(1.0, cfg.theta_bound / np.linalg.norm(theta))
            elif cfg.projection == "box":
                theta = np.clip(theta, -cfg.theta_bound, cfg.theta_bound)
        seen.extend(f[b] for b in range(f.shape[0]) if first is None or not first[b])
    return dict(theta=theta, v=v, w=w, j=j, deltas=np.array(deltas), seen=np.array(seen))


def _recording(batch: int, steps: int, num_features: int, seed: int, masked: bool):
    """A recorded sequence: chained features (s' of one step is s of the next), actions, rewards."""
    rng = np.random.default_rng(seed)
    feats = rng.uniform(0.0, 1.0, size=(steps + 1, batch, num_features)) / math.sqrt(num_features)
    feats[:, :, 0] += 0.5  # a non-zero mean for the z-scoring to remove
    actions = rng.integers(0, len(PAPER_ACTIONS_DEG), size=(steps, batch))
    rewards = -rng.uniform(0.0, 1.0, size=(steps, batch))
    firsts = rng.uniform(size=(steps, batch)) < 0.3 if masked else [None] * steps
    if masked:
        firsts[2] = True  # one step where no environment learns
    return [(feats[t], actions[t], rewards[t], feats[t + 1], firsts[t]) for t in range(steps)]


VARIANTS = {
    "paper": {},
    "ball binds": dict(theta_bound=1.6, alpha_theta=0.5),
    "box": dict(projection="box", theta_bound=0.42, alpha_theta=0.5),
    "discounted V(s')": dict(critic_discount=0.5),
    "weight decay": dict(projection="none", weight_decay=0.03, alpha_theta=0.4),
    "separate alpha_w": dict(alpha_w=0.05),
    "first step": {},
    "z-scoring": dict(normalize_features=True, alpha_v=0.02, alpha_w=0.02),
    "temperature": dict(temperature=0.5),
    "fixed feature norm": dict(normalize_features=True, feature_norm=0.7, alpha_v=0.05, alpha_w=0.05),
    "all options": dict(
        critic_discount=0.4, projection="none", weight_decay=0.02, alpha_w=0.1,
        normalize_features=True, temperature=2.0, alpha_v=0.02, alpha_theta=0.3,
    ),
}


@pytest.mark.parametrize("batch", [1, 4])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_matches_per_step_reference(variant, batch):
    num_features, steps = 5, 40
    masked = variant in ("first step", "all options")
    agent = paper_nac(num_features, generator=_gen(1), dtype=F64, **VARIANTS[variant])
    theta0 = agent.actor_weight.numpy().copy()
    v0 = agent.critic_weight.numpy().copy()
    data = _recording(batch, steps, num_features, seed=2, masked=masked)
    deltas = []
    for f, a, r, f2, first in data:
        out = agent.update(
            torch.from_numpy(f), torch.from_numpy(a), torch.from_numpy(r), torch.from_numpy(f2),
            None if first is None else torch.from_numpy(first),
        )
        deltas.append(out.td_error.numpy())
        np.testing.assert_allclose(out.average_reward.numpy(), agent.average_reward.numpy())
    ref = _reference(agent.config, theta0, v0, data)
    tol = dict(rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.array(deltas), ref["deltas"], **tol)
    np.testing.assert_allclose(agent.actor_weight.numpy(), ref["theta"], **tol)
    np.testing.assert_allclose(agent.critic_weight.numpy(), ref["v"], **tol)
    np.testing.assert_allclose(agent.advantage_weight.numpy(), ref["w"], **tol)
    np.testing.assert_allclose(agent.average_reward.item(), ref["j"], **tol)
    # The learner moved, so the comparison is not of two initial states.
    assert np.abs(ref["w"]).max() > 1e-3 and np.abs(ref["theta"] - theta0).max() > 1e-3
    if variant == "ball binds":
        np.testing.assert_allclose(np.linalg.norm(ref["theta"]), 1.6)
    if variant == "box":
        assert np.isclose(np.abs(ref["theta"]), 0.42).sum() >= 3
    if agent.config.normalize_features:
        seen = ref["seen"]
        assert agent.feature_count.item() == len(seen)
        np.testing.assert_allclose(agent.feature_mean.numpy(), seen.mean(0), **tol)
        np.testing.assert_allclose(agent.feature_m2.numpy(), seen.var(0) * len(seen), **tol)


def test_identical_environments_give_the_sequential_step():
    """B copies of one environment: the mean of B equal updates is the sequential update.

    (Not with z-scoring: its statistics count every copy, and B equal samples have no variance.)
    """
    single = paper_nac(6, generator=_gen(3), dtype=F64, critic_discount=0.7, alpha_w=0.2)
    batched = copy.deepcopy(single)
    for f, a, r, f2, _ in _recording(1, 25, 6, seed=4, masked=False):
        args = [torch.from_numpy(x) for x in (f, a, r, f2)]
        out1 = single.update(*args)
        out5 = batched.update(*[x.expand(5, *x.shape[1:]) for x in args])
        torch.testing.assert_close(out5.td_error, out1.td_error.expand(5), rtol=0, atol=1e-12)
    for name, tensor in single.state_dict().items():
        torch.testing.assert_close(batched.state_dict()[name], tensor, rtol=0, atol=1e-12, msg=name)


def test_all_first_steps_change_nothing():
    agent = paper_nac(4, generator=_gen(5), dtype=F64, normalize_features=True)
    f, a, r, f2, _ = _recording(3, 1, 4, seed=6, masked=False)[0]
    before = copy.deepcopy(agent.state_dict())
    out = agent.update(
        torch.from_numpy(f), torch.from_numpy(a), torch.from_numpy(r), torch.from_numpy(f2),
        torch.ones(3, dtype=torch.bool),
    )
    assert not out.updated.any()
    for name, tensor in before.items():
        assert torch.equal(agent.state_dict()[name], tensor), name


# --------------------------------------------------------------------------- learning tasks
def test_contextual_bandit_finds_the_best_arm_of_each_context():
    """Three contexts, noisy rewards; the best of the 7 arms differs per context."""
    g = _gen(0)
    means = torch.tensor(
        [
            [0.0, 0.2, 0.5, 0.75, 0.5, 0.2, 0.0],
            [0.75, 0.5, 0.2, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.2, 0.2, 0.5, 0.75],
        ],
        dtype=F64,
    )
    num_contexts, batch = means.shape[0], 16
    best = means.argmax(1)

    def contexts():
        c = torch.randint(num_contexts, (batch,), generator=g)
        noise = torch.randn(batch, num_contexts, generator=g, dtype=F64)
        f = torch.eye(num_contexts, dtype=F64)[c] + 0.1 * noise
        return c, f

    agent = paper_nac(num_contexts, generator=g, dtype=F64)
    eye = torch.eye(num_contexts, dtype=F64)
    assert not torch.equal(agent.act(eye, greedy=True).actions, best)  # the task is not solved at start
    c, f = contexts()
    for _ in range(300):
        out = agent.act(f, generator=g)
        r = means[c, out.actions] + 0.5 * torch.randn(batch, generator=g, dtype=F64)
        c_next, f_next = contexts()
        agent.update(f, out.actions, r, f_next)
        c, f = c_next, f_next
    assert torch.equal(agent.act(eye, greedy=True).actions, best)
    assert agent(eye)[torch.arange(num_contexts), best].min() > 0.5
    assert 0.5 < agent.average_reward.item() < 0.8


def _population_code(error, centers, g, width=0.05, noise=0.02):
    f = torch.exp(-0.5 * ((error[:, None] - centers) / width) ** 2)
    return f + noise * torch.randn(f.shape, generator=g, dtype=f.dtype)


def test_angle_error_toy_greedy_policy_ends_within_the_smallest_action():
    """Features: Gaussian tuning curves over the error; reward -|error|; actions move the eye.

    Fixations of 10 steps start from errors uniform in [-1, 1] degrees; after training, the greedy
    policy must bring every error of a grid (offset from the action lattice) within 0.05 degrees.
    """
    g = _gen(0)
    batch, span, horizon = 32, 1.0, 10
    centers = torch.arange(-1.2, 1.2 + 1e-9, 0.05, dtype=F64)
    agent = paper_nac(len(centers), generator=g, dtype=F64)

    def greedy_final_error(steps=30):
        e = torch.linspace(-span, span, 41, dtype=F64) + 0.013
        for _ in range(steps):
            e = e - agent.act(_population_code(e, centers, g), greedy=True).increments_deg
        return e.abs().max().item()

    assert greedy_final_error() > 0.5
    for t in range(1000):
        if t % horizon == 0:
            e = (2 * torch.rand(batch, generator=g, dtype=F64) - 1) * span
        f = _population_code(e, centers, g)
        out = agent.act(f, generator=g)
        e_next = (e - out.increments_deg).clamp(-1.2, 1.2)
        agent.update(f, out.actions, -e_next.abs(), _population_code(e_next, centers, g))
        e = e_next
    assert greedy_final_error() <= 0.05 + 1e-9


# --------------------------------------------------------------------------- act
def test_act_outputs_and_greedy_ties_take_the_first_action():
    agent = paper_nac(3, actor_init=0.0)  # all logits equal
    out = agent.act(torch.rand(5, 3), greedy=True)
    assert isinstance(out, ActOutput)
    assert out.actions.dtype == torch.int64
    assert torch.equal(out.actions, torch.zeros(5, dtype=torch.int64))
    torch.testing.assert_close(out.increments_deg, torch.full((5,), PAPER_ACTIONS_DEG[0]))
    torch.testing.assert_close(out.log_prob, torch.full((5,), -math.log(7)))
    torch.testing.assert_close(out.entropy, torch.full((5,), math.log(7)))


def test_sampling_follows_the_policy_and_is_reproducible():
    agent = paper_nac(4, generator=_gen(7), dtype=F64, actor_init=2.0)
    f = torch.rand(1, 4, generator=_gen(8), dtype=F64).expand(40000, 4)
    out = agent.act(f, generator=_gen(9))
    probs = agent(f[:1])[0]
    freq = torch.bincount(out.actions, minlength=7).to(F64) / len(out.actions)
    assert (freq - probs).abs().max() < 0.01
    torch.testing.assert_close(out.log_prob, probs.log()[out.actions])
    torch.testing.assert_close(out.increments_deg, agent.actions_deg[out.actions])
    assert torch.equal(agent.act(f[:50], generator=_gen(9)).actions, out.actions[:50])
    assert not torch.equal(agent.act(f[:50], generator=_gen(10)).actions, out.actions[:50])


def test_zero_probability_actions_are_never_sampled():
    agent = paper_nac(1, actions_deg=(-1.0, 0.0, 1.0), actor_init=0.0, dtype=F64)
    agent.actor_weight.copy_(torch.tensor([[-1e4], [0.0], [-1e4]], dtype=F64))
    out = agent.act(torch.ones(1000, 1, dtype=F64), generator=_gen(0))
    assert torch.equal(out.actions, torch.ones(1000, dtype=torch.int64))


def test_test_temperature_sharpens_the_policy():
    agent = paper_nac(4, generator=_gen(11))
    f = torch.rand(8, 4, generator=_gen(12))
    hot = agent.act(f, temperature=1.0, generator=_gen(0))
    cold = agent.act(f, temperature=0.1, generator=_gen(0))
    assert (cold.entropy < hot.entropy).all()
    greedy = agent.act(f, greedy=True, temperature=0.1)
    torch.testing.assert_close(greedy.log_prob, agent(f, temperature=0.1).max(-1).values.log())
    assert torch.equal(greedy.actions, agent(f).argmax(-1))


@settings(max_examples=25, deadline=None)
@given(
    batch=st.integers(1, 5),
    num_features=st.integers(1, 6),
    temperature=st.floats(0.05, 5.0),
    seed=st.integers(0, 2**16),
)
def test_policy_is_a_distribution(batch, num_features, temperature, seed):
    agent = paper_nac(
        num_features, generator=_gen(seed), actor_init=3.0, temperature=temperature
    )
    f = torch.randn(batch, num_features, generator=_gen(seed + 1)) * 3
    probs = agent(f)
    assert probs.shape == (batch, 7) and (probs >= 0).all()
    torch.testing.assert_close(probs.sum(-1), torch.ones(batch))
    out = agent.act(f, generator=_gen(seed + 2))
    assert ((out.entropy >= -1e-6) & (out.entropy <= math.log(7) + 1e-6)).all()
    assert ((out.actions >= 0) & (out.actions < 7)).all()


# --------------------------------------------------------------------------- module behaviour
def test_state_dict_round_trip_continues_identically():
    make = lambda seed: paper_nac(  # noqa: E731
        5, generator=_gen(seed), dtype=F64, normalize_features=True
    )
    agent = make(13)
    data = _recording(3, 20, 5, seed=14, masked=True)
    tensors = [[None if x is None else torch.from_numpy(x) for x in step] for step in data]
    for step in tensors[:10]:
        agent.update(*step)
    state = agent.state_dict()
    assert {"actor_weight", "critic_weight", "advantage_weight", "average_reward", "feature_count",
            "feature_mean", "feature_m2", "actions_deg"} <= set(state)
    clone = make(99)
    clone.load_state_dict(state)
    for step in tensors[10:]:
        a, b = agent.update(*step), clone.update(*step)
        assert torch.equal(a.td_error, b.td_error)
    f = torch.from_numpy(data[-1][3])
    assert torch.equal(agent.act(f, generator=_gen(0)).actions, clone.act(f, generator=_gen(0)).actions)
    assert agent.feature_count.item() == clone.feature_count.item() > 0


def test_update_output_fields():
    agent = paper_nac(5, generator=_gen(15), dtype=F64)
    f, a, r, f2, _ = _recording(3, 1, 5, seed=16, masked=False)[0]
    ft, at, rt, f2t = (torch.from_numpy(x) for x in (f, a, r, f2))
    v, w_before = agent.critic_weight.clone(), agent.advantage_weight.clone()
    logp = torch.log_softmax(ft @ agent.actor_weight.t(), -1)
    out = agent.update(ft, at, rt, f2t)
    assert isinstance(out, UpdateOutput)
    torch.testing.assert_close(out.value, ft @ v)
    torch.testing.assert_close(out.next_value, f2t @ v)
    torch.testing.assert_close(out.entropy, -(logp.exp() * logp).sum(-1))
    assert torch.equal(out.advantage, torch.zeros(3, dtype=F64))  # w starts at zero
    assert out.average_reward.shape == () and out.updated.all()
    assert not torch.equal(agent.advantage_weight, w_before)


def test_inputs_are_cast_to_the_module_dtype():
    agent = paper_nac(3, generator=_gen(17))
    f = torch.rand(2, 3, dtype=F64)
    actions, rewards = torch.tensor([0, 6], dtype=torch.int32), torch.tensor([-0.5, -0.1], dtype=F64)
    out = agent.update(f, actions, rewards, f)
    assert out.td_error.dtype == torch.float32
    assert agent.act(f).increments_deg.dtype == torch.float32
    assert paper_nac(3, dtype=F64).act(f.float()).log_prob.dtype == F64


def test_generator_seeds_the_initial_weights():
    a, b = paper_nac(8, generator=_gen(0)), paper_nac(8, generator=_gen(0))
    assert torch.equal(a.actor_weight, b.actor_weight) and torch.equal(a.critic_weight, b.critic_weight)
    assert a.actor_weight.abs().max() <= 0.4 and a.critic_weight.abs().max() <= 0.05
    assert a.actor_weight.abs().max() > 0.2  # uniform over +-0.4, not a constant
    assert not torch.equal(a.actor_weight, paper_nac(8, generator=_gen(1)).actor_weight)
    assert not any(p.requires_grad for p in a.parameters())


def test_config_object_and_keyword_overrides():
    cfg = ActorCriticConfig(alpha_v=0.1)
    agent = paper_nac(2, config=cfg, xi=0.5)
    assert agent.config.alpha_v == 0.1 and agent.config.xi == 0.5 and cfg.xi == 0.01
    assert agent.config.step_w == 0.1
    assert ActorCriticConfig() == NaturalActorCritic(2).config
    assert "num_actions=7" in repr(agent)


def test_update_and_act_compile_without_graph_breaks():
    """fullgraph under aot_eager (functionalised in-place updates, as inductor sees them)."""
    agent = paper_nac(4, generator=_gen(18), dtype=F64, normalize_features=True)
    reference = copy.deepcopy(agent)
    torch._dynamo.reset()
    update = torch.compile(agent.update, backend="aot_eager", fullgraph=True)
    act = torch.compile(agent.act, backend="aot_eager", fullgraph=True)
    for f, a, r, f2, first in _recording(3, 3, 4, seed=19, masked=True):
        args = [torch.from_numpy(x) for x in (f, a, r, f2, first)]
        out, ref = update(*args), reference.update(*args)
        torch.testing.assert_close(out.td_error, ref.td_error, rtol=0, atol=1e-12)
        greedy = reference.act(args[0], greedy=True).actions
        assert torch.equal(act(args[0], greedy=True).actions, greedy)
    for name, tensor in reference.state_dict().items():
        torch.testing.assert_close(agent.state_dict()[name], tensor, rtol=0, atol=1e-12, msg=name)
    # Sampling with uniforms drawn outside (a Generator argument cannot be traced).
    f = torch.rand(6, 4, generator=_gen(20), dtype=F64)
    u = torch.rand(6, generator=_gen(21), dtype=F64)
    assert torch.equal(act(f, uniform=u).actions, reference.act(f, uniform=u).actions)
    same = reference.act(f, generator=_gen(21)).actions  # draws the same u
    assert torch.equal(reference.act(f, uniform=u).actions, same)


@needs_cuda
def test_cuda_matches_cpu():
    cpu = paper_nac(5, generator=_gen(20), dtype=F64)
    gpu = copy.deepcopy(cpu).cuda()
    for f, a, r, f2, first in _recording(4, 10, 5, seed=21, masked=True):
        args = [torch.from_numpy(x) for x in (f, a, r, f2, first)]
        cpu.update(*args)
        gpu.update(*[x.cuda() for x in args])
    torch.testing.assert_close(gpu.actor_weight.cpu(), cpu.actor_weight)
    with pytest.raises(ValueError, match="features must be on the module's device"):
        gpu.act(torch.rand(1, 5, dtype=F64))


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(alpha_v=0.0), "alpha_v must be a finite float > 0"),
        (dict(alpha_w=-1.0), "alpha_w must be None or a finite float > 0"),
        (dict(xi=0.0), r"xi must be a float in \(0, 1\]"),
        (dict(critic_discount=1.5), r"critic_discount must be a float in \[0, 1\]"),
        (dict(temperature=float("nan")), "temperature must be a finite float > 0"),
        (dict(projection="sphere"), "projection must be one of 'ball', 'box', 'none'"),
        (dict(theta_bound=0), "theta_bound must be a finite float > 0"),
        (dict(weight_decay=-0.1), "weight_decay must be a finite float >= 0"),
        (dict(alpha_theta=0.5, weight_decay=3.0), "alpha_theta \\* weight_decay must be <= 1"),
        (dict(normalize_features=1), "normalize_features must be true or false"),
        (dict(feature_norm=0.0), "feature_norm must be None or a finite float > 0"),
    ],
)
def test_config_rejects_impossible_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ActorCriticConfig(**kwargs)
    with pytest.raises(ValueError, match=match):
        paper_nac(2, **kwargs)


def test_constructor_rejects_bad_arguments():
    with pytest.raises(ValueError, match="num_features must be an int >= 1, got 0"):
        NaturalActorCritic(0)
    with pytest.raises(ValueError, match="actions_deg must be a non-empty sequence"):
        NaturalActorCritic(2, actions_deg=())
    with pytest.raises(TypeError, match="unexpected keyword argument.*'alpha'"):
        NaturalActorCritic(2, alpha=0.1)
    with pytest.raises(TypeError, match="config must be an ActorCriticConfig"):
        NaturalActorCritic(2, config={"alpha_v": 0.1})


def test_inputs_are_validated_with_the_argument_named():
    agent = paper_nac(3)
    f, a, r = torch.rand(2, 3), torch.tensor([0, 1]), torch.tensor([-1.0, 0.0])
    act, update = agent.act, agent.update
    cases = [
        (lambda: act(torch.rand(2, 4)), ValueError, r"features must have shape \[B, 3\], got \(2, 4\)"),
        (lambda: act(torch.rand(3)), ValueError, r"features must have shape \[B, 3\], got \(3,\)"),
        (lambda: act(torch.ones(2, 3, dtype=torch.int64)), TypeError, "features must be a floating-point"),
        (lambda: act(f, temperature=0.0), ValueError, "temperature must be a finite float > 0"),
        (lambda: act(f, uniform=torch.rand(3)), ValueError, r"uniform must have shape \[2\]"),
        (lambda: act(torch.full((2, 3), float("nan"))), ValueError, "features contains non-finite"),
        (lambda: update(f, a, r, torch.rand(2, 2)), ValueError, r"next_features must have shape \[B, 3\]"),
        (lambda: update(f, a, r, torch.rand(3, 3)), ValueError, "next_features must have the batch size"),
        (lambda: update(f, a.float(), r, f), TypeError, "actions must be an integer tensor"),
        (lambda: update(f, a[:1], r, f), ValueError, r"actions must have shape \[2\]"),
        (lambda: update(f, torch.tensor([0, 7]), r, f), ValueError, r"actions must be indices in \[0, 7\)"),
        (lambda: update(f, a, r[:, None], f), ValueError, r"rewards must have shape \[2\]"),
        (lambda: update(f, a, torch.tensor([0, 1]), f), TypeError, "rewards must be a floating-point"),
        (lambda: update(f, a, torch.tensor([float("inf"), 0]), f), ValueError, "rewards contains non-finite"),
        (lambda: update(f, a, r, f, torch.tensor([0, 1])), TypeError, "first_step must be a bool tensor"),
        (lambda: update(f, a, r, f, torch.tensor([True])), ValueError, r"first_step must have shape \[2\]"),
        (lambda: update(f.numpy(), a, r, f), TypeError, "features must be a torch.Tensor"),
    ]
    for call, error, match in cases:
        with pytest.raises(error, match=match):
            call()


def test_a_normalize_window_follows_drifting_features_and_none_remembers_everything():
    # Features whose distribution jumps halfway: with a window of 200 samples the z-scoring's
    # statistics are those of the new distribution a few windows later; without one they are
    # those of all samples alike (the mixture's mean and variance).
    gen = torch.Generator().manual_seed(0)
    data = [torch.randn(20, 3, generator=gen, dtype=F64) * (1.0 if t < 100 else 2.0) + (0.0 if t < 100 else 4.0)
            for t in range(200)]
    agents = {w: paper_nac(3, actions_deg=PAPER_ACTIONS_DEG, dtype=F64, normalize_features=True,
                                    normalize_window=w) for w in (None, 200)}
    for f in data:
        for agent in agents.values():
            agent.update(f, torch.zeros(20, dtype=torch.long), torch.zeros(20, dtype=F64), f)
    everything = torch.cat(data)
    plain = agents[None]
    assert plain.feature_count.item() == 4000
    torch.testing.assert_close(plain.feature_mean, everything.mean(0))
    torch.testing.assert_close(plain.feature_m2 / 3999, everything.var(0))
    windowed = agents[200]
    assert windowed.feature_count.item() == 200
    torch.testing.assert_close(windowed.feature_mean, torch.full((3,), 4.0, dtype=F64), atol=0.3, rtol=0)
    torch.testing.assert_close(windowed.feature_m2 / 199, torch.full((3,), 4.0, dtype=F64), atol=1.0, rtol=0)
    with pytest.raises(ValueError, match="normalize_window must be None or an int >= 2"):
        ActorCriticConfig(normalize_window=1)


def _one_update(agent, seed=0, batch=1):
    g = torch.Generator().manual_seed(seed)
    f, f2 = torch.rand(2, batch, agent.num_features, generator=g, dtype=torch.float64).unbind(0)
    actions = torch.randint(agent.num_actions, (batch,), generator=g)
    before = {k: v.clone() for k, v in agent.state_dict().items()}
    agent.update(f, actions, -torch.rand(batch, generator=g, dtype=torch.float64), f2)
    return {k: agent.state_dict()[k] - before[k] for k in ("critic_weight", "advantage_weight", "actor_weight")}


def test_batch_reference_scales_a_small_batch_to_per_transition_steps():
    def make(**kw):
        return paper_nac(6, dtype=torch.float64, generator=torch.Generator().manual_seed(0),
                         alpha_v=0.1, alpha_theta=0.5, **kw)
    full, quarter = _one_update(make()), _one_update(make(batch_reference=4))
    for key in ("critic_weight", "advantage_weight"):
        torch.testing.assert_close(quarter[key], full[key] / 4)
    # the actor takes a quarter step along the new w, itself a quarter step from w = 0
    torch.testing.assert_close(quarter["actor_weight"], full["actor_weight"] / 16)
    # a batch as large as the reference (or larger) takes the full step on its mean
    torch.testing.assert_close(_one_update(make(batch_reference=4), batch=4)["critic_weight"],
                               _one_update(make(), batch=4)["critic_weight"])
    with pytest.raises(ValueError, match="batch_reference"):
        ActorCriticConfig(batch_reference=0)


@pytest.mark.parametrize("power", [1.0, 2.0])
def test_actor_decay_slows_only_the_actor(power):
    def make(**kw):
        return paper_nac(6, dtype=torch.float64, generator=torch.Generator().manual_seed(0),
                         **{"alpha_v": 0.1, "alpha_theta": 0.5, **kw})
    decayed = make(actor_decay=2.0, actor_decay_power=power)
    for _ in range(3):
        _one_update(decayed)
    assert float(decayed.step_count) == 3.0
    reference = make(alpha_theta=0.5 * (2.0 / 5.0) ** power)  # the 4th step: t = 3
    reference.load_state_dict(decayed.state_dict())
    a, b = _one_update(decayed, seed=7), _one_update(reference, seed=7)
    torch.testing.assert_close(a["actor_weight"], b["actor_weight"])
    torch.testing.assert_close(a["critic_weight"], b["critic_weight"])
    # (checkpoints from before the step count existed: aectorch.runtime.migrations, tests/runtime/test_migrations.py)


def test_normalize_samples_freezes_the_statistics():
    agent = paper_nac(6, dtype=torch.float64, normalize_features=True, normalize_samples=4)
    for seed in range(2):
        _one_update(agent, seed=seed, batch=3)
    frozen = (agent.feature_count.clone(), agent.feature_mean.clone(), agent.feature_m2.clone())
    assert int(frozen[0]) == 6
    _one_update(agent, seed=5, batch=3)
    for before, after in zip(frozen, (agent.feature_count, agent.feature_mean, agent.feature_m2)):
        assert torch.equal(before, after)
    with pytest.raises(ValueError, match="normalize_samples"):
        ActorCriticConfig(normalize_samples=1)
