"""A pursuit velocity learned from the retinal slip (`ActiveDepthEnv` with ``pursuit_velocity``): the
slip pair is the frame the last iteration ended with against the current one, the velocity moves
the eyes between iterations, its optimum is the ground truth's change, and the defaults are untouched."""

import pytest
import torch

from aectorch.coding import EncoderConfig
from aectorch.framework import CueConfig, JointLearner, LearnerConfig, default_cues
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def bank():
    return TextureBank.procedural(3, size=(128, 128), seed=7)


def moving_env(bank, b=3, **kwargs):
    protocol = TrialProtocol(fixation_iterations=4, pursuit_velocity=True, object_speed_deg=(-1.5, 1.5),
                             object_depth_speed_m=(-0.02, 0.02))
    env = ActiveDepthEnv(b, protocol=protocol, textures=bank, **kwargs)
    env.set_object_speed(torch.tensor([1.0, -0.5, 0.0])[:b], torch.tensor([-0.02, 0.0, 0.01])[:b])
    env.set_trial(torch.arange(b), torch.tensor([1.0, 2.0, 3.0])[:b])
    return env


def test_the_slip_pair_is_the_last_iterations_frame_against_now_and_the_velocity_moves_the_eyes(bank):
    env = moving_env(bank, seed=0)
    assert list(env.CUES) == ["slip", "parallax", "stereo"]  # the slip cue sees the eyes before any step
    g = torch.Generator().manual_seed(0)
    ended = None
    for i in range(6):  # past a fixation's end
        slip = env.observe("slip")["window"]
        parallax = env.parallax_observation()["window"]
        torch.testing.assert_close(slip[:, 1], parallax[:, 1], rtol=0, atol=0)  # "now" is the same image
        if env.iteration == 0:  # a fixation's first: the fixation's first image
            torch.testing.assert_close(slip[:, 0], parallax[:, 0], rtol=0, atol=0)
        else:  # the left image the last iteration ended with (its stereo frame after every step)
            torch.testing.assert_close(slip[:, 0], ended, rtol=1e-6, atol=1e-6)
        velocity = torch.rand(3, generator=g) - 0.5
        env.act("slip", velocity - env.cue("slip").velocity_deg)
        env.apply_pursuit(torch.rand(3, generator=g) - 0.5)
        ended = env.stereo_observation()["window"][:, 0]
        env.apply_vergence(torch.zeros(3))
        pans = env.pan_deg.clone()
        last = env.iteration == env.fixation_iterations - 1
        env.end_iteration()
        if last:  # a new fixation: the eyes start still, where fixations start
            torch.testing.assert_close(env.cue("slip").velocity_deg, torch.zeros(3), rtol=0, atol=0)
        else:  # both eyes (yoked pursuit) moved on by the velocity
            torch.testing.assert_close(env.pan_deg, pans + velocity[:, None], rtol=0, atol=1e-6)


def test_the_optimal_velocity_is_the_ground_truths_change(bank):
    """Oracle: the optimal left pans of consecutive iterations (the body shifting, the object moving
    sideways and in depth). With every cue held the eyes follow exactly, and the slip of a velocity
    at its optimum is far smaller than an eye held still between iterations."""
    env = moving_env(bank, seed=1)
    infos, velocities, slips = [], [], []
    for _ in range(4):
        slips.append(env.observe("slip")["window"])
        env.hold("slip")
        velocities.append(env.cue("slip").velocity_deg.clone())
        for cue in ("parallax", "stereo"):
            env.observe(cue)
            env.hold(cue)
        infos.append(env.end_iteration())
    for i in range(3):
        change = infos[i + 1].optimal_left_pan_deg - infos[i].optimal_left_pan_deg
        torch.testing.assert_close(velocities[i], change, rtol=0, atol=1e-4)
        assert infos[i].errors_deg["pursuit_velocity"].abs().max() < 1e-4
        assert infos[i].pursuit_error_deg.abs().max() < 1e-4 and infos[i].vergence_error_deg.abs().max() < 1e-4
    assert abs(float(velocities[0][0])) > 0.5  # it moved
    followed = (slips[2][:, 0] - slips[2][:, 1]).abs().mean()
    still = (slips[0][:, 0] - slips[0][:, 1]).abs().mean()  # the first iteration: the eyes had not moved
    assert followed < 0.2 * still


def test_the_velocity_resumes_and_the_default_has_none(bank):
    env = moving_env(bank, seed=2)
    for _ in range(2):
        env.observe("slip")
        env.act("slip", torch.tensor([0.3, -0.2, 0.1]))
        env.end_iteration()
    state = env.state_dict()
    copy = moving_env(bank, seed=2)
    copy.load_state_dict(ActiveDepthEnv.join_states([ActiveDepthEnv.state_rows(state, 0, 1),
                                                     ActiveDepthEnv.state_rows(state, 1, 3)]))
    torch.testing.assert_close(copy.cue("slip").velocity_deg, env.cue("slip").velocity_deg, rtol=0, atol=0)
    torch.testing.assert_close(copy.observe("slip")["window"], env.observe("slip")["window"])
    plain = ActiveDepthEnv(1, protocol=TrialProtocol(fixation_iterations=2), textures=bank, seed=0)
    assert "slip" not in plain.CUES and "pursuit_velocity" not in plain.movements
    plain.parallax_observation()
    plain.end_iteration()
    assert not {"pursuit_velocity_deg", "previous_pans_deg"} & set(plain.state_dict())
    assert "pursuit_velocity" not in plain.end_iteration().errors_deg
    with pytest.raises(ValueError, match="cue must be one of .* got 'slip'"):
        plain.observe("slip")
    with pytest.raises(ValueError, match="cue must be one of .* got 'slip'"):
        plain.act("slip", torch.zeros(1))


def test_the_learner_learns_the_slip_cue_from_its_config(bank):
    """The cue recipe: a `CueConfig` named ``slip`` learns the velocity; a learner without it has it held."""
    env = moving_env(bank, b=2, seed=3)
    small = EncoderConfig(num_atoms=16)
    cues = {**default_cues(encoder=small), "slip": CueConfig(encoder=small, symmetry="mirror")}
    learner = JointLearner(LearnerConfig(cues=cues), generator=torch.Generator().manual_seed(0))
    for _ in range(6):
        record = learner.iteration(env)
    assert list(record.cues) == ["slip", "parallax", "stereo"] and record.slip.td_error is not None
    assert float(record.errors_deg["pursuit_velocity"].abs().max()) > 0  # its agent, not the optimum
    held = JointLearner(LearnerConfig(cues=cues, active_cues=["parallax", "stereo"]),
                        generator=torch.Generator().manual_seed(0))
    assert float(held.iteration(env).errors_deg["pursuit_velocity"].abs().max()) < 1e-4


def test_velocity_memory_keeps_the_pursuit_steps_as_velocity(bank):
    """With ``velocity_memory`` a pursuit step also goes on as velocity: an eye that catches up on a
    lag by position steps alone (a proportional step, the slip cue idle) ends up at the object's
    speed with no lag; without it the lag stays."""
    with pytest.raises(ValueError, match="velocity_memory needs pursuit_velocity"):
        TrialProtocol(velocity_memory=True)
    lags = {}
    for memory in (False, True):
        protocol = TrialProtocol(fixation_iterations=30, shift_m=0.0, pursuit_velocity=True, velocity_memory=memory,
                                 object_speed_deg=(0.0, 1.0))
        env = ActiveDepthEnv(1, protocol=protocol, textures=bank)
        env.set_object_speed(torch.tensor([1.0]), None)
        env.set_trial(torch.tensor([0]), torch.tensor([2.0]))
        for _ in range(25):
            env.apply_pursuit(0.5 * env.cue("parallax").to_optimum())  # half the seen offset
            info = env.end_iteration()
        lags[memory] = float(info.pursuit_error_deg)
        if memory:
            assert abs(float(env.cue("slip").velocity_deg) - 1.0) < 0.02
    assert lags[False] < -0.9 and abs(lags[True]) < 0.02
