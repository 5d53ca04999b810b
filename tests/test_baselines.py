"""aectorch.baselines: the classical matcher, the accuracy anchor beside the learner."""

from __future__ import annotations

import pytest
import torch

from aectorch.baselines import Matcher, ncc_displacement_px
from aectorch.evaluation import evaluate, run_trials
from aectorch.sim import ActiveDepthEnv, TextureBank, TrialProtocol

torch.set_num_threads(1)


def test_ncc_finds_a_known_subpixel_shift():
    # A smooth random image shifted by a known, non-integer number of pixels (linear interpolation).
    g = torch.Generator().manual_seed(0)
    wide = torch.nn.functional.avg_pool2d(torch.rand(3, 1, 40, 80, generator=g), 5, 1, 2)[:, 0]
    x = torch.arange(40, dtype=torch.float32) + 20
    for shift in (-2.3, 0.0, 0.4, 1.7):
        first = wide[..., 20:60]
        pos = x - shift  # second[x] = first[x - shift]: content displaced by +shift
        lo = pos.floor().long()
        w = pos - lo
        second = (1 - w) * wide[..., lo] + w * wide[..., lo + 1]
        d = ncc_displacement_px(first, second)
        assert d.tolist() == pytest.approx([shift] * 3, abs=0.15)
    with pytest.raises(ValueError, match="first and second"):
        ncc_displacement_px(torch.zeros(2, 8, 8), torch.zeros(2, 8, 9))


@pytest.mark.parametrize("cue,movement", [("parallax", "pursuit"), ("stereo", "vergence")])
def test_matcher_reads_an_eyes_offset_from_its_pair(cue, movement):
    env = ActiveDepthEnv(3, protocol=TrialProtocol(shift_iterations=1), textures=TextureBank.default("test"), seed=0)
    env.set_trial(torch.tensor([0, 5, 9]), torch.tensor([1.0, 2.0, 3.0]))
    matcher = Matcher(actions_deg=None)
    for offset in (-0.6, 0.25):
        left = env.optimal_left_pan_deg()
        if movement == "pursuit":
            pans = torch.stack((left + offset, env.optimal_right_pan_deg(left + offset)), -1)
        else:
            pans = torch.stack((left, env.optimal_right_pan_deg(left) + offset), -1)
        env.set_pan_deg(pans)
        increment = matcher.increment_deg(env.observe(cue, matcher.scales))
        assert increment.tolist() == pytest.approx([-offset] * 3, abs=0.06)


def test_matcher_runs_the_learners_trials_and_fixates_within_a_pixel():
    bank = TextureBank.default("test").subset(range(4))
    for actions in ("default", None):
        matcher = Matcher() if actions else Matcher(actions_deg=None)
        out = run_trials(matcher, bank, distances_m=[1.0, 3.0])
        assert out["vergence_deg"].shape == (8, 2) and torch.isnan(out["depth_error_m"]).all()
        assert out["pursuit_deg"].abs().max() < 0.1 and out["vergence_deg"].abs().max() < 0.1
    result = evaluate(Matcher(), bank, distances_m=[2.0], vergence_test=True, steps=10)
    assert result["fractions"]["both"]["within"] == 1.0
    assert result["vergence_test"]["degrees"]["rmse"] < 0.1
    constrained = Matcher(actions_deg=[-0.2, 0.0, 0.2])
    increments = constrained.increment_deg({s.name: torch.rand(2, 2, s.crop // s.downsample, s.crop // s.downsample)
                                           for s in constrained.scales})
    assert all(any(abs(i - a) < 1e-6 for a in (-0.2, 0.0, 0.2)) for i in increments.tolist())
    with pytest.raises(ValueError, match="actions_deg"):
        Matcher(actions_deg=[])
