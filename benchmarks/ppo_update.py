"""Old vs new PPO: the wall time of `PPO._update` and of the per-iteration `learn` + `act`, and
the proof that the new code gives the same bits.

``LegacyPPO`` below is the PPO of commit 4065a9b (``_update``, ``advantages``, ``learn``, ``act``,
``normalize``, the z-scoring helpers and the loss's construction copied verbatim) on the current
class's state, so both run on identical copies of one agent. The workload is the default training
(``ExperimentConfig()``, B = 32, both cues with their symmetry: 64 transitions per iteration,
1152 features, 11 actions), recorded from a real run:

  * the agents' `learn` and `act` calls of one whole fixation (the update at its end), recorded
    for both cues after the first fixation (so the z-scoring statistics are not trivial), and the
    agents' states at its start;
  * ``update``: the fixation's last `learn`, which runs the update (the second of a run), after
    the calls before it (untimed);
  * ``bare_update``: `_update` alone on that rollout set directly (``agent._rollout = ...``, no
    `learn` before it);
  * ``fixation``: the recorded calls replayed in order (each cue's `act` and `learn` calls of the
    fixation's iterations, one update each), per iteration (both cues).

Old and new alternate (``--repeats`` times each, medians), each run on one long-lived agent per
class and cue (as in training, where the agent and the memory it keeps outlive an update) loaded
with the recorded state; after every run the two agents' parameters, Adam state, z-scoring
buffers, generator state, TD errors, actions, log-probabilities and entropies are compared bit
for bit (any difference stops the run). Times are wall and this thread's CPU time (torch runs
on this one thread; CPU time is less disturbed by other work on a shared machine). torch on one
thread (as training's default), OMP_WAIT_POLICY=PASSIVE and OSMesa recommended.

Usage:
    PYOPENGL_PLATFORM=osmesa OMP_WAIT_POLICY=PASSIVE python benchmarks/ppo_update.py [--repeats 40]

Writes a table to stdout and JSON to benchmarks/results/ppo_update.json (--json).
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aectorch.control.agent import ActOutput, LearnOutput, Transitions, entropy, sample_actions  # noqa: E402
from aectorch.control.ppo import PPO  # noqa: E402


# -- the code of 4065a9b, verbatim ------------------------------------------------------------------
def _standardize(features, count, mean, m2, eps, norm=None):
    n = count.to(features.dtype)
    sample_var = m2 / (n - 1).clamp_min(1)
    var = torch.where(n > 1, sample_var, torch.ones_like(sample_var))
    x = (features - mean) / torch.sqrt(var + eps)
    return x if norm is None else _scale_to_norm(x, norm)


def _scale_to_norm(x, norm):
    length = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    return x * (norm / length.clamp_min(torch.finfo(x.dtype).tiny))


def _merge_moments(count, mean, m2, f, mask, reduce, window=None):
    m = mask.to(f.dtype)[:, None]
    nb = reduce(m.sum())
    n = count.to(f.dtype)
    m2_old = m2
    if window is not None:
        n_eff = torch.minimum(n, (window - nb).clamp_min(1))
        m2_old = m2_old * (n_eff / n.clamp_min(1))
        n = n_eff
    total = (n + nb).clamp_min(1)
    mean_b = reduce((m * f).sum(0)) / nb.clamp_min(1)
    m2_b = reduce((m * (f - mean_b).square()).sum(0))
    diff = mean_b - mean
    new_mean = mean + diff * (nb / total)
    new_m2 = m2_old + m2_b + diff.square() * (n * nb / total)
    if window is None:
        new_count = count + reduce(mask.sum())
    else:
        new_count = n.round().to(count.dtype) + reduce(mask.sum())
    return new_count, new_mean, new_m2


def stock_loss(agent: PPO):
    """The ClipPPOLoss of commit 4065a9b on ``agent``'s networks: TorchRL's stock wrappers
    (`TensorDictModule`, `ValueOperator`) and validated categorical distributions."""
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


class LegacyPPO(PPO):
    """`PPO` with the methods and the loss of commit 4065a9b."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.__dict__["_loss"] = stock_loss(self)

    def normalize(self, features):
        return _standardize(features.to(self.feature_mean.dtype), self.feature_count, self.feature_mean,
                            self.feature_m2, self.config.normalize_eps, self.config.feature_norm)

    def log_policy(self, features):
        return torch.log_softmax(self.policy(self.normalize(features)), dim=-1)

    @torch.no_grad()
    def act(self, features, greedy=False, generator=None, *, uniform=None):
        if features.ndim != 2 or features.shape[1] != self.num_features:
            raise ValueError(f"features must have shape [B, {self.num_features}], got {tuple(features.shape)}")
        logp = self.log_policy(features)
        if greedy:
            actions = logp.argmax(dim=-1)
        else:
            if uniform is None:
                uniform = torch.rand(features.shape[0], generator=generator, dtype=logp.dtype, device=logp.device)
            actions = sample_actions(logp, uniform.to(logp.dtype))
        return ActOutput(actions, self.actions_deg[actions], logp.gather(-1, actions[:, None]).squeeze(-1),
                         entropy(logp))

    def learn(self, transitions, *, reduce=None):
        t = transitions
        with torch.no_grad():
            value = self.value(self.normalize(t.features))[:, 0]
            next_value = self.value(self.normalize(t.next_features))[:, 0]
            td_error = t.rewards.to(value) + self.config.discount * next_value - value
        self._rollout.append(Transitions(*(x.detach() for x in t[:4]), last=bool(t.last)))
        if not t.last:
            return LearnOutput(td_error, False)
        self.fixations_seen += 1
        if self.fixations_seen % self.config.fixations:
            return LearnOutput(td_error, False)
        self._update(reduce)
        return LearnOutput(td_error, True)

    @torch.no_grad()
    def advantages(self, features, next_features, rewards, last):
        value = self.value(self.normalize(features))
        next_value = self.value(self.normalize(next_features))
        done = last.to(torch.bool)[None, :, None].expand_as(value).clone()
        return self._gae(self.config.discount, self.config.gae_lambda, value, next_value,
                         rewards.to(value)[..., None], done, torch.zeros_like(done))

    def _update(self, reduce):
        cfg, rollout = self.config, self._rollout
        features = torch.stack([t.features for t in rollout], 1)  # [B, T, F]
        next_features = torch.stack([t.next_features for t in rollout], 1)
        rewards = torch.stack([t.rewards for t in rollout], 1).to(features)
        actions = torch.stack([t.actions for t in rollout], 1)
        last = torch.tensor([t.last for t in rollout], device=features.device)
        advantage, target = self.advantages(features, next_features, rewards, last)
        x = self.normalize(features)
        with torch.no_grad():
            old = torch.log_softmax(self.policy(x), -1).gather(-1, actions[..., None])[..., 0]
        batch = self._tensordict({"observation": x.flatten(0, 1), "action": actions.flatten(), "action_log_prob":
                                  old.flatten(), "advantage": advantage.flatten(0, 1), "value_target":
                                  target.flatten(0, 1)}, batch_size=[actions.numel()])
        parameters = [p for group in self.optimizer.param_groups for p in group["params"]]
        minibatches = min(cfg.minibatches, batch.batch_size[0])
        size = batch.batch_size[0] // minibatches
        for _ in range(cfg.epochs):
            order = torch.randperm(batch.batch_size[0], generator=self.generator).to(features.device)
            for start in range(0, size * minibatches, size):
                losses = self._loss(batch[order[start:start + size]])
                loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                self.optimizer.zero_grad(set_to_none=False)
                loss.backward()
                if reduce is not None:
                    world = reduce(torch.ones((), dtype=loss.dtype, device=loss.device))
                    for p in parameters:
                        p.grad.copy_(reduce(p.grad) / world)
                nn.utils.clip_grad_norm_(parameters, cfg.max_grad_norm)
                self.optimizer.step()
        flat = features.flatten(0, 1)
        stats = _merge_moments(self.feature_count, self.feature_mean, self.feature_m2, flat,
                               torch.ones(flat.shape[0], dtype=torch.bool, device=flat.device),
                               reduce or (lambda t: t))
        for buffer, new in zip((self.feature_count, self.feature_mean, self.feature_m2), stats):
            buffer.copy_(new)
        self._rollout = []


# -- the workload -----------------------------------------------------------------------------------
def record():
    """Run the default training until each PPO agent finished its first fixation, then record both
    agents' `learn`/`act` calls over the next fixation. Returns {cue: (state, calls)}."""
    from aectorch.ops import native
    from aectorch.runtime import build_env, build_learner
    from aectorch.runtime.config import ExperimentConfig

    native.set_threads(2)
    cfg = ExperimentConfig()
    cfg.env.num_envs = 32
    env, learner = build_env(cfg), build_learner(cfg)
    agents = {name: cue.agent for name, cue in learner.cues.items()}
    assert all(isinstance(a, PPO) for a in agents.values()), "the default cues' agents are not PPO"
    while any(a.fixations_seen < 1 for a in agents.values()):
        learner.iteration(env)
    recorded = {}
    for name, agent in agents.items():
        recorded[name] = (snapshot(agent), [])
        calls = recorded[name][1]

        def learn(transitions, *, reduce=None, _agent=agent, _calls=calls, _learn=agent.learn):
            _calls.append(("learn", Transitions(*(x.clone() for x in transitions[:4]), last=transitions.last)))
            return _learn(transitions, reduce=reduce)

        def act(features, greedy=False, generator=None, *, uniform=None, _calls=calls, _act=agent.act):
            assert not greedy and uniform is not None
            _calls.append(("act", features.clone(), uniform.clone()))
            return _act(features, uniform=uniform)

        agent.learn, agent.act = learn, act
    while any(a.fixations_seen < 2 for a in agents.values()):
        learner.iteration(env)
    for agent in agents.values():
        del agent.learn, agent.act
    return recorded


def snapshot(agent: PPO) -> dict:
    return {"state": copy.deepcopy(agent.state_dict()), "generator": agent.generator.get_state(),
            "config": agent.config, "num_features": agent.num_features, "actions": agent.actions_deg.tolist()}


_agents: dict = {}


def restore(cls, snap: dict) -> PPO:
    """The snapshot's state in an agent of ``cls``: one long-lived agent per class and snapshot, as
    in training (where the agent, and any memory it keeps, lives from one update to the next)."""
    key = (cls, id(snap))
    if key not in _agents:
        _agents[key] = cls(snap["num_features"], snap["actions"], snap["config"], generator=torch.Generator())
    agent = _agents[key]
    agent.load_state_dict(copy.deepcopy(snap["state"]))  # the rollout and the fixation count too
    agent.generator.set_state(snap["generator"])
    return agent


def state_of(agent: PPO) -> list[torch.Tensor]:
    """Every number the agent carries: parameters, buffers, Adam state, generator state."""
    out = [t.detach() for t in agent.state_dict().values() if isinstance(t, torch.Tensor)]
    for s in agent.optimizer.state_dict()["state"].values():
        out += [v for v in s.values() if isinstance(v, torch.Tensor)]
    return out + [agent.generator.get_state(), torch.tensor(agent.fixations_seen)]


def bits(t: torch.Tensor) -> torch.Tensor:
    """A tensor's bits (so that -0.0 != 0.0 and NaN == NaN of the same payload)."""
    t = t.detach().contiguous()
    width = {1: torch.uint8, 2: torch.int16, 4: torch.int32, 8: torch.int64}[t.element_size()]
    return t.view(width) if t.dtype.is_floating_point else t


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return len(a) == len(b) and all(x.shape == y.shape and x.dtype == y.dtype and torch.equal(bits(x), bits(y))
                                    for x, y in zip(a, b))


def clock() -> tuple[float, float]:
    return time.perf_counter(), time.thread_time()


def since(start: tuple[float, float]) -> tuple[float, float]:
    """(wall, this thread's CPU) seconds since ``start``: CPU time is less disturbed by other work on
    the machine (torch runs on this one thread)."""
    return time.perf_counter() - start[0], time.thread_time() - start[1]


def run_update(cls, snap, calls):
    """The fixation's calls replayed, the last `learn` (the one that updates) alone timed: returns
    (seconds, agent, outputs)."""
    agent = restore(cls, snap)
    outputs = []
    final = max(i for i, c in enumerate(calls) if c[0] == "learn")
    for i, call in enumerate(calls):
        if i == final:
            start = clock()
            outputs += [agent.learn(call[1]).td_error]
            seconds = since(start)
        elif call[0] == "learn":
            outputs += [agent.learn(call[1]).td_error]
        else:
            outputs += list(agent.act(call[1], uniform=call[2]))
    return seconds, agent, outputs


def run_bare_update(cls, snap, calls):
    """`_update` alone on the fixation's rollout, set directly (no learn before it): returns
    (seconds, agent, outputs)."""
    agent = restore(cls, snap)
    agent._rollout = [c[1] for c in calls if c[0] == "learn"]
    agent.fixations_seen += 1
    start = clock()
    agent._update(None)
    return since(start), agent, []


def run_fixation(cls, snap, calls):
    """The fixation's calls replayed: returns (seconds, agent, outputs)."""
    agent = restore(cls, snap)
    outputs = []
    start = clock()
    for call in calls:
        if call[0] == "learn":
            outputs += [agent.learn(call[1]).td_error]
        else:
            outputs += list(agent.act(call[1], uniform=call[2]))
    return since(start), agent, outputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=40, help="runs of each (old, new) per workload")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (training's default: 1)")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results" / "ppo_update.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    recorded = record()
    # One act per cue and iteration (a fixation's first iteration has no transition to learn).
    iterations = {name: sum(c[0] == "act" for c in calls) for name, (_, calls) in recorded.items()}
    results = {}
    for workload, runner in (("update", run_update), ("bare_update", run_bare_update), ("fixation", run_fixation)):
        times = {(label, kind): [] for label in ("old", "new") for kind in ("wall", "cpu")}
        for r in range(args.repeats + 2):  # two warm-up rounds
            per = {key: 0.0 for key in times}
            order = (("old", LegacyPPO), ("new", PPO)) if r % 2 else (("new", PPO), ("old", LegacyPPO))
            for name, (snap, calls) in recorded.items():
                done = {}
                for label, cls in order:
                    (wall, cpu), agent, outputs = runner(cls, snap, calls)
                    per[label, "wall"] += wall
                    per[label, "cpu"] += cpu
                    done[label] = [t.clone() for t in state_of(agent)] + outputs
                if not same(done["old"], done["new"]):
                    raise SystemExit(f"{workload}, cue {name}: the new code's results differ from the old code's")
            if r >= 2:
                for key in per:
                    times[key].append(per[key])
        scale = 1e3 / (max(iterations.values()) if workload == "fixation" else len(recorded))
        results[workload] = {}
        for kind in ("wall", "cpu"):
            old, new = times["old", kind], times["new", kind]
            results[workload][kind] = {
                "old_median_ms": statistics.median(old) * scale, "new_median_ms": statistics.median(new) * scale,
                "old_quartiles_ms": [q * scale for q in statistics.quantiles(old, n=4)],
                "new_quartiles_ms": [q * scale for q in statistics.quantiles(new, n=4)],
                "ratio_old_over_new_median_of_pairs": statistics.median([o / n for o, n in zip(old, new)])}
    print(f"PPO, default training (B = 32, 64 transitions per iteration, {recorded['parallax'][0]['num_features']} "
          f"features), torch threads = {args.threads}, {args.repeats} interleaved runs each; bit-identical: yes")
    print(f"{'workload (medians, ms)':42s} {'old wall':>9s} {'new wall':>9s} {'ratio':>6s} "
          f"{'old cpu':>9s} {'new cpu':>9s} {'ratio':>6s}")
    labels = {"update": "update (the last learn), per cue", "bare_update": "_update on a set rollout, per cue",
              "fixation": "learn+act+update, per iteration (2 cues)"}
    for workload, label in labels.items():
        w, c = results[workload]["wall"], results[workload]["cpu"]
        print(f"{label:42s} {w['old_median_ms']:9.2f} {w['new_median_ms']:9.2f} "
              f"{w['ratio_old_over_new_median_of_pairs']:6.2f} {c['old_median_ms']:9.2f} {c['new_median_ms']:9.2f} "
              f"{c['ratio_old_over_new_median_of_pairs']:6.2f}")
    out = {"what": "median ms of the old (4065a9b) and new PPO on identical copies, interleaved (wall, and this "
                   "thread's CPU time); update: the fixation's last learn (the update) per cue; bare_update: _update "
                   "on a rollout set directly, per cue; fixation: a recorded fixation's learn/act calls and its "
                   "update, per training iteration (both cues); ratio: median over the runs of old/new",
           "bit_identical": True, "repeats": args.repeats, "torch_threads": args.threads,
           "iterations_per_fixation": iterations, "torch": torch.__version__, "machine": platform.machine(),
           "results": results}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
