"""Stable-Baselines3's PPO, unchanged, learns vergence on ``aectorch/Vergence-v0`` from the intrinsic reward.

Eight simulated heads (one batched simulator) train SB3's ``PPO("MlpPolicy")``, with the
observations z-scored by SB3's ``VecNormalize`` (the one wrapper), on the procedural training
textures; the greedy policy is then evaluated on another set of images (a folder of photographs,
and the 40 procedural test textures) against a random policy: the mean |error| at the end of each
fixation. By default the agent learns from ``reward="scaled"``, the improvement of the internal
encoder's coding reward over a running scale of it (active efficient coding: no ground truth),
with a discount of 0.5; ``--reward error`` is minus the absolute vergence error (an oracle
baseline), ``--reward coding`` the absolute coding reward. The evaluation reads the trained
encoder's features (frozen), as the policy saw them. ``--env aectorch/ActiveDepth-v0`` learns
both movements at once (``MultiDiscrete``) and scores both.

    python examples/sb3_vergence.py --seed 0 --eval-textures data/choose-photos --out runs/rl/sb3_scaled_s0.json
    python examples/sb3_vergence.py --reward error --gamma 0.99 --seed 0
    python examples/sb3_vergence.py --env aectorch/ActiveDepth-v0 --seed 0
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

import aectorch.envs as envs

ENV_IDS = {"vergence": "aectorch/Vergence-v0", "pursuit": "aectorch/Pursuit-v0", "active_depth": "aectorch/ActiveDepth-v0"}


def evaluate(model, train_env, textures, episodes: int, seed: int, num_envs: int = 8) -> dict:
    """Mean |error| (deg) of each movement the policy makes at the fixation ends of ``episodes``
    batches of ``num_envs`` greedy episodes on ``textures`` (``model=None``: uniformly random
    actions)."""
    task = train_env.task
    eval_env = envs.make_sb3_vec_env(ENV_IDS[task.config.task], num_envs=num_envs, seed=seed + 1000,
                                     textures=textures, reward=task.config.reward, learn_encoder=False)
    eval_env.task.load_encoders(task.encoders)  # the features the policy learned on, frozen
    movements = [eval_env.task.env.cue(cue).name for cue in eval_env.task.cues]
    per_fixation = eval_env.task.config.fixation_iterations
    space = eval_env.action_space  # Discrete(n), or MultiDiscrete (pursuit, vergence)
    nvec = np.asarray(space.nvec if hasattr(space, "nvec") else space.n)
    rng = np.random.default_rng(seed)
    normalize = model.get_vec_normalize_env().normalize_obs if model is not None else None
    obs, errors, steps, episodes_done = eval_env.reset(), {m: [] for m in movements}, 0, 0
    while episodes_done < episodes:
        if model is None:
            actions = rng.integers(0, nvec, (num_envs,) + nvec.shape)
        else:
            actions, _ = model.predict(normalize(obs), deterministic=True)
        obs, _, dones, infos = eval_env.step(actions)
        steps += 1
        if steps % per_fixation == 0:  # a fixation's end
            for m in movements:
                errors[m] += [abs(info[f"{m}_error_deg"]) for info in infos]
        episodes_done += int(dones.any())
    eval_env.close()
    out = {}
    for m in movements:
        e = np.asarray(errors[m])
        out.update({f"{m}_mae_deg": float(e.mean()), f"{m}_within_0.22_deg" if m != "vergence" else "within_0.22_deg":
                    float((e <= 0.22).mean())})
    out["fixations"] = int(np.asarray(errors[movements[0]]).size)
    return out


def main(argv=None) -> dict:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reward", choices=["improvement", "coding", "scaled", "error"], default="scaled")
    parser.add_argument("--gamma", type=float, default=0.5, help="the discount")
    parser.add_argument("--n-steps", type=int, default=120)
    parser.add_argument("--batch-size", type=int, default=240)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--ent-coef", type=float, default=0.0)
    parser.add_argument("--norm-reward", action="store_true")
    parser.add_argument("--env", choices=sorted(ENV_IDS.values()), default="aectorch/Vergence-v0")
    parser.add_argument("--steps", type=int, default=40_000, help="environment steps (all 8 environments)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--eval-textures", default=None,
                        help="also evaluate on this folder of images (the 40 test textures always)")
    parser.add_argument("--eval-episodes", type=int, default=30, help="batches of fixations evaluated per set")
    parser.add_argument("--out", default=None, help="write the result as JSON")
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)  # small networks: one thread (the simulator's kernels keep their own)
    from aectorch.sim import TextureBank

    sets = {"test textures": TextureBank.default("test")}
    if args.eval_textures:
        sets[args.eval_textures] = args.eval_textures
    env = envs.make_sb3_vec_env(args.env, num_envs=args.num_envs, seed=args.seed, reward=args.reward)
    # SB3's defaults but for the rollout, four fixations (120 steps) of every environment per update,
    # and the discount, 0.5: the improvement rewards a step's own change, and a discount near 1
    # adds the later steps' noise to its return (the project's own learner: 0.3). The observations
    # are z-scored by SB3's running statistics (VecNormalize), as SB3 advises for PPO.
    venv = VecNormalize(VecMonitor(env), norm_obs=True, norm_reward=args.norm_reward, gamma=args.gamma)
    model = PPO("MlpPolicy", venv, n_steps=args.n_steps, batch_size=args.batch_size, gamma=args.gamma,
                learning_rate=args.lr, n_epochs=args.epochs, ent_coef=args.ent_coef, seed=args.seed,
                device="cpu", verbose=0)
    clock = time.perf_counter()
    model.learn(args.steps)
    seconds = time.perf_counter() - clock
    result = {"args": vars(args), "reward": args.reward, "steps": args.steps, "seed": args.seed, "train_s": seconds,
              "eval": {name: {"trained": evaluate(model, env, textures, args.eval_episodes, args.seed, args.num_envs),
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
