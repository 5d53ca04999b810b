"""The standard RL environments (aectorch.envs), checked by their own libraries' checkers.

Gymnasium's ``check_env`` on every id (warnings as errors), ``make_vec`` across episode ends with
the declared autoreset mode, TorchRL's ``check_env_specs``, Stable-Baselines3's PPO on the VecEnv,
reproducibility under a seed, and one batched simulator (one render call per step).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

gym = pytest.importorskip("gymnasium")

import aectorch.envs as envs  # noqa: E402
from aectorch.sim.observations import EyeImages  # noqa: E402

torch.set_num_threads(1)
SMALL = dict(fixation_iterations=4, textures=torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)),
             encoder={"num_atoms": 16})


@pytest.mark.parametrize("env_id", list(envs.IDS))
@pytest.mark.parametrize("observation", ["features", "images"])
def test_gymnasium_check_env_passes_without_a_warning(env_id, observation):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, observation=observation, **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", ["aectorch/Pursuit-v0", "aectorch/ActiveDepth-v0"])
def test_a_moving_target_passes_the_checker_and_moves(env_id):
    from gymnasium.utils.env_checker import check_env

    moving = dict(SMALL, object_speed_deg=(-1.0, 1.0), object_depth_speed_m=(-0.02, -0.01))
    env = gym.make(env_id, **moving)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    env.reset(seed=0)
    distances = [env.step(env.action_space.sample())[-1]["distance_m"] for _ in range(3)]
    assert distances[0] > distances[1] > distances[2]  # it approaches, and the info follows it
    env.close()
    with pytest.raises(ValueError, match="object_speed_deg"):
        gym.make(env_id, object_speed_deg=(1.0, 0.0))


@pytest.mark.parametrize("env_id", list(envs.IDS))
def test_make_vec_is_one_batched_env_across_episode_ends(env_id):
    vec = gym.make_vec(env_id, num_envs=8, vectorization_mode="vector_entry_point", **SMALL)
    assert isinstance(vec, envs.gym.EyeVectorEnv) and vec.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    obs, _ = vec.reset(seed=0)
    vec.action_space.seed(0)
    steps = 8 if env_id == "aectorch/ActiveDepth-v0" else 4  # an episode: a trial, or a fixation
    ends = 0
    for t in range(1, 71):
        obs, rewards, terminated, truncated, infos = vec.step(vec.action_space.sample())
        assert obs in vec.observation_space and rewards.shape == (8,) and not terminated.any()
        assert truncated.all() == (t % steps == 0) and truncated.all() == truncated.any()
        assert {"distance_m", "pursuit_error_deg", "vergence_error_deg", "left_pan_deg", "right_pan_deg"} <= set(infos)
        if truncated.all():
            ends += 1
            assert infos["_final_obs"].all() and infos["final_obs"].shape == obs.shape
            assert not np.array_equal(infos["final_obs"], obs)
            # SAME_STEP: the returned observation is the next episode's first, as a fresh observation gives it
            task = vec.task
            assert task.env.iteration == 0 and task.steps == 0
            fresh = torch.cat([task.encoders[cue].encode(task.env.observe(cue, task.scales)).features
                               for cue in task.cues], -1) * task.config.feature_scale
            np.testing.assert_allclose(obs, fresh.numpy(), rtol=1e-5, atol=1e-6)
    assert ends == 70 // steps
    vec.close()


@pytest.mark.parametrize("env_id", list(envs.IDS))
def test_torchrl_check_env_specs_passes(env_id):
    from torchrl.envs.utils import check_env_specs

    env = envs.make_torchrl_env(env_id, num_envs=8, seed=0, **SMALL)
    assert tuple(env.batch_size) == (8,) and env.device == torch.device("cpu")
    check_env_specs(env)
    rollout = env.rollout(9, break_when_any_done=False)  # across an episode end
    assert rollout["next", "truncated"].sum() == 8 * (9 // (8 if "Depth" in env_id else 4))
    assert rollout["next", "observation"].dtype == torch.float32
    env.close()


def test_torchrl_images_keep_every_scale():
    env = envs.make_torchrl_env("aectorch/Vergence-v0", num_envs=2, observation="images", seed=0, **SMALL)
    td = env.reset()
    assert {"stereo_wide", "stereo_coarse", "stereo_fine"} <= set(td.keys())
    assert td["stereo_fine"].shape[:2] == (2, 2)
    env.close()


def test_the_same_seed_gives_the_same_episodes_and_another_seed_does_not():
    def run(seed):
        vec = gym.make_vec("aectorch/Vergence-v0", num_envs=4, vectorization_mode="vector_entry_point", **SMALL)
        obs, _ = vec.reset(seed=seed)
        out = [obs]
        for t in range(6):
            obs, rewards, *_ , infos = vec.step(np.arange(4) % 11)
            out += [obs, rewards, infos["vergence_error_deg"]]
        vec.close()
        return out

    first, again, other = run(3), run(3), run(4)
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert not all(np.array_equal(a, b) for a, b in zip(first, other))


def test_one_render_call_per_step(monkeypatch):
    calls = []
    render = EyeImages.render
    monkeypatch.setattr(EyeImages, "render", lambda self, *a, **k: calls.append(1) or render(self, *a, **k))
    vec = gym.make_vec("aectorch/Vergence-v0", num_envs=16, vectorization_mode="vector_entry_point", **SMALL)
    vec.reset(seed=0)
    counts = []
    for _ in range(8):
        calls.clear()
        *_, truncated, _ = vec.step(np.zeros(16, dtype=np.int64))
        counts.append((len(calls), bool(truncated.all())))
    # one batched render for all 16 heads; at an episode's end also the next episode's first view
    assert counts == [(1, False), (1, False), (1, False), (2, True)] * 2
    vec.close()


def test_stable_baselines3_ppo_learns_on_the_vec_env():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    env = envs.make_sb3_vec_env("aectorch/Vergence-v0", num_envs=4, seed=0, reward="error", **SMALL)
    obs = env.reset()
    assert obs.shape == (4, 64)
    for t in range(4):
        obs, rewards, dones, infos = env.step(np.full(4, 5))
    assert dones.all() and all(info["TimeLimit.truncated"] and info["terminal_observation"].shape == (64,)
                               for info in infos)
    model = PPO("MlpPolicy", VecMonitor(env), n_steps=8, batch_size=16, n_epochs=1, seed=0, device="cpu")
    model.learn(64)
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (4,)
    env.close()


def test_bad_options_are_named():
    with pytest.raises(ValueError, match="observation must be one of"):
        gym.make("aectorch/Vergence-v0", observation="pixels")
    with pytest.raises(ValueError, match="env id must be one of"):
        envs.make_torchrl_env("aectorch/Saccade-v0")
    env = gym.make("aectorch/ActiveDepth-v0", **SMALL)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must be indices in \[0, 11\)"):
        env.step(np.array([0, 11]))
    env.close()


@pytest.mark.integration
@pytest.mark.parametrize("example", ["sb3_vergence", "torchrl_vergence", "cleanrl_ppo_vergence"])
def test_the_rl_examples_train_and_evaluate(example, tmp_path):
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "examples" / f"{example}.py"
    spec = importlib.util.spec_from_file_location(example, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "result.json"
    result = module.main(["--steps", "480", "--num-envs", "4", "--eval-episodes", "1", "--out", str(out)])
    assert json.loads(out.read_text()) == json.loads(json.dumps(result))
    for policy in ("trained", "random"):
        row = result["eval"]["test textures"][policy]
        assert row["fixations"] == 4 and np.isfinite(row["vergence_mae_deg"])


def test_loaded_encoders_stay_across_seeded_resets_and_give_the_trained_features():
    trained = envs.EyeTask(2, envs.TaskConfig(**SMALL), seed=0)
    trained.reset(seed=0)
    for _ in range(3):
        trained.step(torch.full((2,), 7))
    other = envs.EyeTask(2, envs.TaskConfig(**SMALL, learn_encoder=False), seed=5)
    other.load_encoders(trained.encoders)
    obs = other.reset(seed=5)  # a seeded reset keeps the loaded encoders
    expected = trained.encoders["stereo"].encode(other.env.observe("stereo", other.scales)).features * 10
    torch.testing.assert_close(obs["features"], expected)
    with pytest.raises(ValueError, match=r"encoders must hold the cues \['stereo'\]"):
        other.load_encoders({})


def test_the_reward_forms_are_the_learners():
    from aectorch.control import RewardScale, learned_reward

    r, r_prev = torch.tensor([-1.0, -2.0, -0.5]), torch.tensor([-1.5, -1.0, -0.5])
    assert torch.equal(learned_reward("coding", r), r)
    assert learned_reward("improvement", r, r_prev).tolist() == [0.5, -1.0, 0.0]
    scale = RewardScale(window=4)
    first = learned_reward("scaled", r, r_prev, scale)
    torch.testing.assert_close(first, torch.tensor([0.5, -1.0, 0.0]) / (1.25 / 3) ** 0.5)
    learned_reward("scaled", torch.tensor([2.0, 2.0]), torch.zeros(2), scale)  # weighs 2 old + 2 new
    torch.testing.assert_close(scale.mean_square, torch.tensor((2 * 1.25 / 3 + 8) / 4, dtype=torch.float64))
    with pytest.raises(ValueError, match="previous observation's coding reward"):
        learned_reward("improvement", r)
    with pytest.raises(ValueError, match="RewardScale"):
        learned_reward("scaled", r, r_prev)
    with pytest.raises(ValueError, match="'bonus' is not a valid Reward"):
        learned_reward("bonus", r, r_prev)


@pytest.mark.parametrize("form", ["improvement", "scaled"])
def test_the_improvement_rewards_are_the_coding_rewards_change_within_each_episode(form):
    # Two tasks from one seed take the same actions: one gives the coding reward, one its change.
    # The first step of an episode is measured from the episode's first observation, coded at the
    # reset (or at the step that ended the last episode) and not learned from.
    tasks = {r: envs.EyeTask(3, envs.TaskConfig(**SMALL, reward=r), seed=1) for r in ("coding", form)}
    for task in tasks.values():
        task.reset(seed=1)
    coder = tasks["coding"]

    def first_reward():
        with torch.no_grad():
            return coder.encoders["stereo"].encode(coder.env.observe("stereo", coder.scales)).reward

    previous, improvements = first_reward(), []
    actions = torch.randint(11, (2 * coder.episode_steps, 3), generator=torch.Generator().manual_seed(0))
    for action in actions:
        coding, other = (task.step(action) for task in tasks.values())
        improvements.append(coding.reward - previous)
        if form == "improvement":
            torch.testing.assert_close(other.reward, improvements[-1])
        previous = first_reward() if coding.truncated else coding.reward
    if form == "scaled":  # the last step's scale holds every improvement so far
        rms = torch.cat(improvements).double().square().mean().sqrt()
        torch.testing.assert_close(other.reward, improvements[-1] / rms.float())
    assert not torch.allclose(torch.stack(improvements), torch.zeros(len(improvements), 3))


def test_the_default_reward_is_the_scaled_improvement_the_documented_agents_learn_from():
    assert envs.TaskConfig().reward == "scaled"
    with pytest.raises(ValueError, match="reward"):
        envs.TaskConfig(reward="bonus")


def test_the_cleanrl_style_example_is_one_short_file_on_make_vec():
    from pathlib import Path

    source = (Path(__file__).resolve().parents[2] / "examples" / "cleanrl_ppo_vergence.py").read_text()
    assert len(source.splitlines()) <= 200
    assert "gym.make_vec(" in source and "stable_baselines3" not in source and "torchrl" not in source


def test_the_standard_environments_keep_the_eyes_within_the_oculomotor_range():
    from aectorch.envs.core import EyeTask, TaskConfig

    task = EyeTask(2, TaskConfig(**{**SMALL, "fixation_iterations": 6}, vergence_range_deg=(-1.5, 30.0)), seed=0)
    task.reset(seed=0)
    for _ in range(5):  # -1 degree of vergence a step from parallel: the floor stops it
        task.step(torch.tensor([0, 0]))
    assert torch.allclose(task.env.vergence_deg, torch.full((2,), -1.5))
    assert EyeTask(1, TaskConfig(**SMALL)).env.vergence_range_deg == (-2.0, 40.0)  # on by default
    with pytest.raises(ValueError, match="vergence_range_deg must hold 0"):
        gym.make("aectorch/Vergence-v0", **SMALL, vergence_range_deg=(0.5, 3.0))
