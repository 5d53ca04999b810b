"""Active efficient coding in one loop: B simulated heads learn to fixate and to judge distance.

The joint learner (`aectorch.framework.JointLearner`) written out with the library's public parts,
top to bottom: for each depth cue of the environment (motion parallax drives pursuit, stereo
drives vergence), a sparse coder turns the cue's image pair into features and a reward (how well
the code reconstructs the pair), an agent learns from the reward and chooses the eye movement, and
the coder learns from the same error; after each trial a depth MLP learns the distance from the
final eye angles. Without the cues' symmetries this is exactly what ``JointLearner`` computes
(tests/project/test_examples.py checks it).

    python examples/minimal_loop.py            # 600 iterations of 16 heads, about a minute on 2 cores
    python examples/minimal_loop.py 100
"""

from __future__ import annotations

import sys

import torch

from aectorch.coding import BinocularEncoder
from aectorch.control import Transitions, make_agent
from aectorch.depth import DepthLearner
from aectorch.framework import CueConfig
from aectorch.sim import ActiveDepthEnv, TextureBank


def train(iterations: int = 600, num_envs: int = 16, seed: int = 0, config: CueConfig | None = None,
          log_every: int = 100) -> dict:
    """Train for ``iterations`` iterations; returns the encoders, agents and depth learner."""
    config = config or CueConfig()  # each cue's settings: coder, agent, actions, reward (no symmetry)
    env = ActiveDepthEnv(num_envs, textures=TextureBank.default("train"), seed=seed)
    g = torch.Generator().manual_seed(seed)  # the initial dictionaries and policies, then the actions
    cues = list(env.CUES)  # ["parallax", "stereo"]: steps k1 and k2 of every iteration
    encoders = {cue: BinocularEncoder(config.encoder, config.scales, generator=g) for cue in cues}
    agents = {cue: make_agent(config.agent, encoders[cue].num_features, config.actions_deg, config.agent_config,
                              generator=g) for cue in cues}
    depth = DepthLearner(generator=g)
    pending: dict[str, tuple] = {}  # each cue's last (features, action, reward): a transition to complete
    errors: dict[str, list[float]] = {}  # each eye movement's |error| at fixation ends
    depth_errors: list[float] = []

    for it in range(1, iterations + 1):
        last = env.iteration == env.fixation_iterations - 1  # these observations end the fixation
        for cue in cues:
            encoder, agent = encoders[cue], agents[cue]
            with torch.no_grad():  # the coder's pursuit needs no graph (PPO's update makes its own)
                # The cue's image pair at each foveal scale's resolution, coded scale by scale:
                # features f = the atoms' pooled activity (eq. 5), reward R = -sum of errors (eq. 6).
                out = encoder(env.observe(cue, encoder.scales))
                features = out.features * config.feature_scale
            if cue in pending:  # the previous action's transition, rewarded by the coding gain
                f0, a0, r0 = pending[cue]
                agent.learn(Transitions(f0, a0, out.reward - r0, features, last=last))
            act = agent.act(features, uniform=torch.rand(num_envs, 1, generator=g)[:, 0])
            encoder.learn_(out)  # one dictionary step on the same reconstruction error
            env.act(cue, act.increments_deg)  # pursuit moves the left eye (yoked), vergence the right
            pending[cue] = (features, act.actions, out.reward)
        info = env.end_iteration()

        if info.fixation_end:  # a new fixation: no transition across it
            pending.clear()
            for movement, error in info.errors_deg.items():
                errors.setdefault(movement, []).extend(error.abs().tolist())
        if info.trial_end:  # the four final eye angles q -> distance, judged before learning from it
            predicted = depth.predict(info.q_deg)
            if bool(depth.trained):
                depth_errors.extend((predicted - info.distance_m).abs().tolist())
            depth.add_trials(info.q_deg, info.distance_m)
        if log_every and (it % log_every == 0 or it == iterations):
            window = ", ".join(f"{m} {sum(e[-500:]) / len(e[-500:]):.3f} deg" for m, e in errors.items() if e)
            depth_text = f", depth {sum(depth_errors[-200:]) / len(depth_errors[-200:]):.3f} m" if depth_errors else ""
            print(f"iteration {it}: MAE at fixation ends {window}{depth_text}", flush=True)
    env.close()
    return {"encoders": encoders, "agents": agents, "depth": depth, "errors_deg": errors}


if __name__ == "__main__":
    train(int(sys.argv[1]) if len(sys.argv) > 1 else 600)
