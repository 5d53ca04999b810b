"""Stable-Baselines3's PPO, unchanged, learns vergence on ``aectorch/Vergence-v0``.

Eight simulated heads (one batched simulator) train SB3's ``PPO("MlpPolicy")``, with the
observations normalised by SB3's ``VecNormalize``, on the procedural training textures; the policy is then evaluated greedily on another set of images (a folder of
photographs, or the 40 procedural test textures) against a random policy: the mean |vergence
error| at the end of each fixation. With ``reward="coding"`` the agent learns from the internal
encoder's coding reward alone (active efficient coding: no ground truth), with ``reward="error"``
from minus the absolute vergence error (an oracle baseline). The evaluation reads the trained
encoder's features (frozen), as the policy saw them.

    python examples/sb3_vergence.py --reward error --steps 40000 --seed 0 --eval-textures data/choose-photos
    python examples/sb3_vergence.py --reward coding --out runs/sb3_coding_s0.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

import aectorch.envs as envs


def evaluate(model, train_env, textures, episodes: int, seed: int, num_envs: int = 8) -> dict:
    """Mean |vergence error| (deg) at the fixation ends of ``episodes`` batches of ``num_envs``
    greedy fixations on ``textures`` (``model=None``: uniformly random actions)."""
    eval_env = envs.make_sb3_vec_env("aectorch/Vergence-v0", num_envs=num_envs, seed=seed + 1000,
                                     textures=textures, reward=train_env.task.config.reward, learn_encoder=False)
    eval_env.task.load_encoders(train_env.task.encoders)  # the features the policy learned on, frozen
    rng = np.random.default_rng(seed)
    normalize = model.get_vec_normalize_env().normalize_obs if model is not None else None
    obs, errors = eval_env.reset(), []
    while len(errors) < episodes * num_envs:
        if model is None:
            actions = rng.integers(0, eval_env.action_space.n, num_envs)
        else:
            actions, _ = model.predict(normalize(obs), deterministic=True)
        obs, _, dones, infos = eval_env.step(actions)
        if dones.any():
            errors += [abs(info["vergence_error_deg"]) for info in infos]
    eval_env.close()
    errors = np.asarray(errors)
    return {"vergence_mae_deg": float(errors.mean()), "within_0.22_deg": float((errors <= 0.22).mean()),
            "fixations": int(errors.size)}


def main(argv=None) -> dict:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reward", choices=["error", "coding"], default="error")
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
    env = envs.make_sb3_vec_env("aectorch/Vergence-v0", num_envs=args.num_envs, seed=args.seed, reward=args.reward)
    # SB3's defaults but for the rollout, four fixations (120 steps) of every environment per update,
    # and the observations normalised by SB3's running statistics (VecNormalize), as SB3 advises for PPO.
    venv = VecNormalize(VecMonitor(env), norm_obs=True, norm_reward=False)
    model = PPO("MlpPolicy", venv, n_steps=120, batch_size=240, seed=args.seed, device="cpu", verbose=0)
    clock = time.perf_counter()
    model.learn(args.steps)
    seconds = time.perf_counter() - clock
    result = {"reward": args.reward, "steps": args.steps, "seed": args.seed, "train_s": seconds,
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
