"""TorchRL's collector and PPO learn vergence on ``aectorch/Vergence-v0`` (no NumPy on the way).

The environment is one batched TorchRL ``EnvBase`` of 8 heads (`aectorch.envs.make_torchrl_env`);
a ``Collector`` (``SyncDataCollector`` before TorchRL 0.12) gathers four fixations of every head per batch, TorchRL's ``GAE`` and
``ClipPPOLoss`` train an MLP policy and value function (64 tanh units, as SB3's ``MlpPolicy``, on
observations z-scored by running statistics, as SB3's ``VecNormalize``) for 10 epochs of
minibatches. The greedy policy is then evaluated as in
``examples/sb3_vergence.py``: the mean |vergence error| at each fixation's end, on another set of
images, beside a random policy.

By default the agent learns from the intrinsic ``reward="scaled"`` with a discount of 0.5.

    python examples/torchrl_vergence.py --seed 0 --eval-textures data/choose-photos --out runs/rl/torchrl_scaled_s0.json
    python examples/torchrl_vergence.py --reward error --gamma 0.99 --seed 0
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from torch import nn

import aectorch.envs as envs


class RunningNorm(nn.Module):
    """Observations z-scored by running statistics of what the collector saw (as SB3's
    VecNormalize: updated in training mode, clipped to +-10)."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.register_buffer("count", torch.tensor(1e-4))
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))

    def forward(self, x):
        if self.training:
            with torch.no_grad():
                flat = x.reshape(-1, x.shape[-1])
                n, mean, var = flat.shape[0], flat.mean(0), flat.var(0, unbiased=False)
                delta, total = mean - self.mean, self.count + n
                self.var.copy_((self.var * self.count + var * n + delta.square() * self.count * n / total) / total)
                self.mean.add_(delta * n / total)
                self.count.copy_(total)
        return ((x - self.mean) / torch.sqrt(self.var + 1e-8)).clamp(-10, 10)


def _mlp(norm: nn.Module, inputs: int, outputs: int) -> nn.Module:
    return nn.Sequential(norm, nn.Linear(inputs, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, outputs))


def evaluate(policy, train_env, textures, episodes: int, seed: int, num_envs: int = 8) -> dict:
    """Mean |vergence error| (deg) at the fixation ends of ``episodes`` batches of greedy fixations
    (``policy=None``: uniformly random actions), with the trained encoder's features (frozen)."""
    env = envs.make_torchrl_env("aectorch/Vergence-v0", num_envs=num_envs, seed=seed + 1000, textures=textures,
                                reward=train_env.task.config.reward, learn_encoder=False)
    env.task.load_encoders(train_env.task.encoders)  # the features the policy learned on, frozen
    generator = torch.Generator().manual_seed(seed)
    td, errors = env.reset(), []
    with torch.no_grad():
        while len(errors) < episodes * num_envs:
            if policy is None:
                td["action"] = torch.randint(len(env.task.actions_deg), (num_envs,), generator=generator)
            else:
                td["action"] = policy.eval()(td["observation"]).argmax(-1)
            td = env.step(td)
            if td["next", "truncated"].all():
                errors += td["next", "vergence_error_deg"].abs().tolist()
                td = env.reset(td["next"].exclude("reward"))  # the next episode has begun
            else:
                td = td["next"]
    env.close()
    errors = torch.tensor(errors)
    return {"vergence_mae_deg": float(errors.mean()), "within_0.22_deg": float((errors <= 0.22).double().mean()),
            "fixations": errors.numel()}


def main(argv=None) -> dict:
    from tensordict.nn import TensorDictModule
    try:
        from torchrl.collectors import Collector
    except ImportError:  # torchrl < 0.12 names it SyncDataCollector
        from torchrl.collectors import SyncDataCollector as Collector
    from torchrl.modules import ProbabilisticActor, ValueOperator
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reward", choices=["improvement", "coding", "scaled", "error"], default="scaled")
    parser.add_argument("--gamma", type=float, default=0.5, help="the discount")
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--steps", type=int, default=40_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--eval-textures", default=None,
                        help="also evaluate on this folder of images (the 40 test textures always)")
    parser.add_argument("--eval-episodes", type=int, default=30)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)  # small networks: one thread (the simulator's kernels keep their own)
    from aectorch.sim import TextureBank

    sets = {"test textures": TextureBank.default("test")}
    if args.eval_textures:
        sets[args.eval_textures] = args.eval_textures
    env = envs.make_torchrl_env("aectorch/Vergence-v0", num_envs=args.num_envs, seed=args.seed, reward=args.reward)
    features, actions = env.observation_spec["observation"].shape[-1], len(env.task.actions_deg)
    norm = RunningNorm(features)  # shared by the policy and the value function
    logits = _mlp(norm, features, actions)
    actor = ProbabilisticActor(TensorDictModule(logits, in_keys=["observation"], out_keys=["logits"]),
                               in_keys=["logits"], distribution_class=torch.distributions.Categorical,
                               return_log_prob=True, spec=env.action_spec)
    critic = ValueOperator(_mlp(norm, features, 1), in_keys=["observation"])
    frames = 120 * args.num_envs  # four fixations of every head
    collector = Collector(env, actor, frames_per_batch=frames, total_frames=args.steps)
    advantage = GAE(gamma=args.gamma, lmbda=0.95, value_network=critic)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.0, critic_coeff=0.5)
    optimizer = torch.optim.Adam(loss.parameters(), lr=args.lr)
    clock = time.perf_counter()
    for batch in collector:
        norm.eval()  # the statistics follow the collected observations only
        with torch.no_grad():
            advantage(batch)
        flat = batch.reshape(-1)
        for _ in range(10):
            for index in torch.randperm(flat.numel()).split(240):
                out = loss(flat[index])
                total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
                optimizer.step()
        norm.train()
    seconds = time.perf_counter() - clock
    collector.shutdown()
    result = {"args": vars(args), "reward": args.reward, "steps": args.steps, "seed": args.seed, "train_s": seconds,
              "eval": {name: {"trained": evaluate(logits, env, textures, args.eval_episodes, args.seed, args.num_envs),
                              "random": evaluate(None, env, textures, args.eval_episodes, args.seed, args.num_envs)}
                       for name, textures in sets.items()}}
    env.close()
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
