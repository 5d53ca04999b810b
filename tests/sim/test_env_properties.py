"""Property-based tests (hypothesis) of ActiveDepthEnv's geometry and ground truth."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aectorch.sim import ActiveDepthEnv, TrialProtocol

B = 6
distances = st.lists(st.floats(0.5, 3.5), min_size=B, max_size=B)
pans = st.lists(st.floats(-40.0, 40.0), min_size=B, max_size=B)
PROPS = settings(max_examples=30, deadline=None)


@pytest.fixture(scope="module")
def env() -> ActiveDepthEnv:
    # The whole 0.1 m shift before the first iteration, so fixation 0's first state holds it all.
    return ActiveDepthEnv(B, protocol=TrialProtocol(shift_iterations=1, yoked_pursuit=False),
                          textures=torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(0)), seed=0,
                          dtype=torch.float64)


def _trial(env, d, left=None):
    env.set_trial(torch.zeros(B, dtype=torch.long), torch.tensor(d, dtype=torch.float64))
    if left is not None:
        env.set_pan_deg(torch.stack([torch.tensor(left, dtype=torch.float64)] * 2, 1))


@PROPS
@given(d=distances)
def test_parallax_shrinks_with_distance_and_is_the_lineage_angle(env, d):
    # Fixation 0 starts straight ahead; the body shifts +0.1 m: the left eye must pan by
    # -atan(0.1 / d) to keep the target (aec-lineage.md), smaller for farther planes.
    _trial(env, d)
    optimal = env.optimal_left_pan_deg()
    expected = -torch.rad2deg(torch.atan(0.1 / torch.tensor(d, dtype=torch.float64)))
    torch.testing.assert_close(optimal, expected, rtol=0, atol=1e-9)
    order = torch.argsort(torch.tensor(d))
    assert (optimal[order].abs().diff() <= 1e-12).all()


@PROPS
@given(d=distances, left=pans)
def test_a_perfect_step_leaves_no_error_and_the_vergence_shrinks_with_distance(env, d, left):
    _trial(env, d, left)
    target_right = env.optimal_right_pan_deg()
    env.apply_vergence(target_right - env.right_pan_deg)  # one exact vergence step
    info = env.end_iteration()
    ok = target_right.abs() < 45  # within the eye's pan limit
    assert info.vergence_error_deg[ok].abs().max() < 1e-9 if ok.any() else True
    # fixating a nearer plane needs more convergence (with the left eye straight ahead)
    _trial(env, d, [0.0] * B)
    vergence = env.optimal_right_pan_deg() - env.left_pan_deg
    assert (vergence > 0).all()
    order = torch.argsort(torch.tensor(d))
    assert (vergence[order].diff() <= 1e-12).all()


@PROPS
@given(d=distances, left=pans, perm=st.permutations(list(range(B))))
def test_ground_truth_is_equivariant_to_permuting_the_environments(env, d, left, perm):
    _trial(env, d, left)
    a = torch.stack([env.optimal_left_pan_deg(), env.optimal_right_pan_deg()], 1)
    _trial(env, [d[i] for i in perm], [left[i] for i in perm])
    b = torch.stack([env.optimal_left_pan_deg(), env.optimal_right_pan_deg()], 1)
    torch.testing.assert_close(b, a[list(perm)], rtol=0, atol=1e-12)


@PROPS
@given(d=distances, steps=st.lists(st.floats(-30.0, 30.0), min_size=B, max_size=B))
def test_any_increments_keep_the_eyes_within_their_limits(env, d, steps):
    _trial(env, d)
    low, high = env.head.limits_deg["left_eye_pan"]
    assert env.head.limits_deg["right_eye_pan"] == (low, high)
    delta = torch.tensor(steps, dtype=torch.float64)
    for _ in range(3):
        env.apply_pursuit(delta)
        env.apply_vergence(-2 * delta)
        assert bool((env.pan_deg >= low - 1e-9).all()) and bool((env.pan_deg <= high + 1e-9).all())
        assert all(math.isfinite(v) for v in env.pan_deg.flatten().tolist())
