"""PPO in one file, CleanRL style, learns vergence on ``aectorch/Vergence-v0`` from the intrinsic reward.

``gymnasium.make_vec`` gives eight simulated heads as one batched environment. The reward is the
environment's ``scaled`` coding improvement (how much the step made the internal encoder's code
of the stereo pair better, over a running scale of that change): no ground truth. The features
are z-scored by running statistics (`aectorch.control.features`, as the project's own agents see
them). The greedy policy is then scored with the trained encoder, frozen, on the 40 procedural
test textures and on a folder of photographs: the mean |vergence error| at fixation ends, beside
a random policy (as ``examples/sb3_vergence.py``).

    python examples/cleanrl_ppo_vergence.py --seed 0 --eval-textures data/choose-photos --out runs/rl/cleanrl_scaled_s0.json
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical

import aectorch.envs  # noqa: F401  (registers the ids)
from aectorch.control.features import merge_moments, standardize
from aectorch.sim import TextureBank


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=40_000, help="environment steps, all environments")
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--rollout", type=int, default=120, help="steps per environment per update (4 fixations)")
    p.add_argument("--reward", default="scaled", choices=["improvement", "coding", "scaled", "error"])
    p.add_argument("--gamma", type=float, default=0.5)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--minibatches", type=int, default=4)
    p.add_argument("--clip", type=float, default=0.2)
    p.add_argument("--ent-coef", type=float, default=0.0)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=0.5)
    p.add_argument("--eval-textures", default=None, help="also evaluate on this folder of images")
    p.add_argument("--eval-episodes", type=int, default=30, help="batches of fixations evaluated per set")
    p.add_argument("--out", default=None, help="write the result as JSON")
    return p.parse_args(argv)


def layer(inputs, outputs, std=np.sqrt(2)):
    linear = nn.Linear(inputs, outputs)
    nn.init.orthogonal_(linear.weight, std)
    nn.init.zeros_(linear.bias)
    return linear


class Agent(nn.Module):
    """CleanRL's actor and critic (two tanh layers of 64), on running z-scores of the features."""

    def __init__(self, features: int, actions: int):
        super().__init__()
        self.register_buffer("count", torch.zeros((), dtype=torch.int64))
        self.register_buffer("mean", torch.zeros(features))
        self.register_buffer("m2", torch.zeros(features))
        self.critic = nn.Sequential(layer(features, 64), nn.Tanh(), layer(64, 64), nn.Tanh(), layer(64, 1, 1.0))
        self.actor = nn.Sequential(layer(features, 64), nn.Tanh(), layer(64, 64), nn.Tanh(), layer(64, actions, 0.01))

    def observe(self, obs):  # collected observations update the statistics; returns their z-scores
        self.count, self.mean, self.m2 = merge_moments(self.count, self.mean, self.m2, obs, None, lambda t: t)
        return self.normalize(obs)

    def normalize(self, obs):
        return standardize(obs, self.count, self.mean, self.m2, 1e-8).clamp(-10, 10)

    def get_value(self, x):
        return self.critic(x).squeeze(-1)

    def get_action_and_value(self, x, action=None):
        dist = Categorical(logits=self.actor(x))
        action = dist.sample() if action is None else action
        return action, dist.log_prob(action), dist.entropy(), self.get_value(x)


def make_env(num_envs, reward, **options):
    return gym.make_vec("aectorch/Vergence-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                        reward=reward, **options)


def evaluate(agent, train_envs, textures, args):
    """Mean |vergence error| (deg) at fixation ends, greedy (``agent=None``: random actions)."""
    envs = make_env(args.num_envs, args.reward, textures=textures, learn_encoder=False)
    envs.unwrapped.task.load_encoders(train_envs.unwrapped.task.encoders)  # the trained encoder, frozen
    obs, _ = envs.reset(seed=args.seed + 1000)
    rng, errors = np.random.default_rng(args.seed), []
    while len(errors) < args.eval_episodes * args.num_envs:
        if agent is None:
            action = rng.integers(0, envs.single_action_space.n, args.num_envs)
        else:
            with torch.no_grad():
                action = agent.actor(agent.normalize(torch.as_tensor(obs))).argmax(-1).numpy()
        obs, _, _, truncated, infos = envs.step(action)
        if truncated.all():
            errors += np.abs(infos["final_info"]["vergence_error_deg"]).tolist()
    envs.close()
    errors = np.asarray(errors)
    return {"vergence_mae_deg": float(errors.mean()), "within_0.22_deg": float((errors <= 0.22).mean()),
            "fixations": int(errors.size)}


def main(argv=None) -> dict:
    args = parse_args(argv)
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)
    envs = make_env(args.num_envs, args.reward)
    n, t = args.num_envs, args.rollout
    agent = Agent(envs.single_observation_space.shape[0], envs.single_action_space.n)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    obs = torch.zeros((t, n) + envs.single_observation_space.shape)
    actions, logprobs, rewards, dones, values = (torch.zeros((t, n)) for _ in range(5))

    clock = time.perf_counter()
    next_obs, _ = envs.reset(seed=args.seed)
    next_obs = agent.observe(torch.as_tensor(next_obs))
    for update in range(args.steps // (n * t)):
        for step in range(t):  # the rollout
            obs[step] = next_obs
            with torch.no_grad():
                action, logprobs[step], _, values[step] = agent.get_action_and_value(next_obs)
            actions[step] = action
            raw, reward, terminated, truncated, _ = envs.step(action.numpy())
            rewards[step] = torch.as_tensor(reward, dtype=torch.float32)
            # An episode ends by its time limit only; as CleanRL, its last value is not bootstrapped.
            dones[step] = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            next_obs = agent.observe(torch.as_tensor(raw))

        with torch.no_grad():  # generalised advantage estimates
            next_value = agent.get_value(next_obs)
            advantages, last = torch.zeros_like(rewards), torch.zeros(n)
            for step in reversed(range(t)):
                following = next_value if step == t - 1 else values[step + 1]
                alive = 1.0 - dones[step]
                delta = rewards[step] + args.gamma * following * alive - values[step]
                advantages[step] = last = delta + args.gamma * args.gae_lambda * alive * last
            returns = advantages + values

        b_obs, b_actions = obs.reshape(n * t, -1), actions.reshape(-1).long()
        b_logprobs, b_adv, b_returns = logprobs.reshape(-1), advantages.reshape(-1), returns.reshape(-1)
        for _ in range(args.epochs):  # the clipped surrogate, the value loss and the entropy
            for mb in torch.randperm(n * t).chunk(args.minibatches):
                _, logprob, entropy, value = agent.get_action_and_value(b_obs[mb], b_actions[mb])
                ratio = (logprob - b_logprobs[mb]).exp()
                adv = (b_adv[mb] - b_adv[mb].mean()) / (b_adv[mb].std() + 1e-8)
                pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - args.clip, 1 + args.clip)).mean()
                v_loss = 0.5 * (value - b_returns[mb]).square().mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + args.vf_coef * v_loss
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
    seconds = time.perf_counter() - clock

    sets = {"test textures": TextureBank.default("test")}
    if args.eval_textures:
        sets[args.eval_textures] = args.eval_textures
    result = {"args": vars(args), "reward": args.reward, "steps": args.steps, "seed": args.seed, "train_s": seconds,
              "eval": {name: {"trained": evaluate(agent, envs, textures, args), "random": evaluate(None, envs, textures, args)}
                       for name, textures in sets.items()}}
    envs.close()
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
