"""aectorch.runtime.metrics.TrainingMetrics against a brute-force computation on synthetic records."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aectorch.framework import CueRecord, IterationRecord
from aectorch.runtime.metrics import TrainingMetrics

B, SCALES, ATOMS, H = 3, ("coarse", "fine"), 8, 2
CUES = {"parallax": SCALES, "stereo": SCALES}


def _records(n: int, seed: int = 0) -> list[IterationRecord]:
    g = torch.Generator().manual_seed(seed)
    out = []
    for i in range(n):
        fixation_end = i % H == H - 1
        trial_end = i % (2 * H) == 2 * H - 1

        def cue():
            return CueRecord(
                reward=-torch.rand(B, generator=g),
                errors=torch.rand(B, len(SCALES), generator=g),
                td_error=None if i % 5 == 0 else torch.randn(B, generator=g),
                entropy=torch.rand(B, generator=g),
                actions=torch.zeros(B, dtype=torch.long),
                increments_deg=torch.zeros(B),
                atom_counts=torch.randint(0, 4, (len(SCALES), ATOMS), generator=g),
            )

        prediction = distance = q = None
        if trial_end:
            distance = torch.rand(B, generator=g) + 1
            prediction = torch.rand(B, generator=g) + 1
            if i < 6:  # before the first depth fit: NaN
                prediction = torch.full((B,), math.nan)
            q = torch.zeros(B, 4)
        cues = {"parallax": cue(), "stereo": cue()}
        errors = {"pursuit": torch.randn(B, generator=g), "vergence": torch.randn(B, generator=g)}
        out.append(IterationRecord(cues, errors, fixation_end, trial_end, q, distance, prediction, False))
    return out


def _brute(records, since: int, wf: int, wt: int) -> dict:
    pursuit = [abs(float(v)) for r in records if r.fixation_end for v in r.pursuit_error_deg][-wf:]
    vergence = [abs(float(v)) for r in records if r.fixation_end for v in r.vergence_error_deg][-wf:]
    depth = [abs(float(p) - float(d)) for r in records if r.trial_end
             for p, d in zip(r.depth_prediction_m, r.distance_m) if not math.isnan(float(p))][-wt:]
    out = {"pursuit_mae_deg": np.mean(pursuit), "vergence_mae_deg": np.mean(vergence),
           "depth_mae_m": np.mean(depth) if depth else math.nan}
    interval = records[since:]
    for cue in ("parallax", "stereo"):
        cs = [getattr(r, cue) for r in interval]
        out[f"{cue}/reward"] = np.mean([c.reward.double().mean().item() for c in cs])
        out[f"{cue}/entropy"] = np.mean([c.entropy.double().mean().item() for c in cs])
        td = [c.td_error.double().abs().mean().item() for c in cs if c.td_error is not None]
        out[f"{cue}/td_error"] = np.mean(td) if td else math.nan
        for j, s in enumerate(SCALES):
            out[f"{cue}/{s}/error"] = np.mean([c.errors[:, j].double().mean().item() for c in cs])
            counts = sum(c.atom_counts[j].double().numpy() for c in cs)
            p = counts / counts.sum()
            p = p[p > 0]
            out[f"{cue}/{s}/atom_usage"] = math.exp(-(p * np.log(p)).sum()) / ATOMS
    return out


def _assert_close(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        if math.isnan(b[key]):
            assert math.isnan(a[key]), key
        else:
            assert a[key] == pytest.approx(b[key], rel=1e-6, abs=1e-9), key


def test_summary_matches_brute_force_with_windows_and_intervals():
    records = _records(40)
    metrics = TrainingMetrics(B, window_fixations=7, window_trials=4, cues=CUES)
    since = 0
    for i, r in enumerate(records, 1):
        metrics.update(r)
        if i % 10 == 0:
            _assert_close(metrics.summary(), _brute(records[:i], since, 7, 4))
            since = i


def test_depth_is_nan_until_a_prediction_and_interval_resets():
    records = _records(6)
    metrics = TrainingMetrics(B, cues=CUES)
    for r in records:
        metrics.update(r)
    first = metrics.summary()
    assert math.isnan(first["depth_mae_m"]) and not math.isnan(first["pursuit_mae_deg"])
    empty = metrics.summary()  # no iteration since: the interval averages are undefined
    assert math.isnan(empty["parallax/reward"]) and math.isnan(empty["stereo/fine/atom_usage"])
    assert empty["pursuit_mae_deg"] == first["pursuit_mae_deg"]


def test_atom_usage_extremes():
    metrics = TrainingMetrics(1, cues={"parallax": ("fine",), "stereo": ("fine",)})
    record = _records(1)[0]
    one = torch.zeros(1, ATOMS, dtype=torch.long)
    one[0, 3] = 5
    uniform = torch.full((1, ATOMS), 2)
    for counts, expected in ((one, 1 / ATOMS), (uniform, 1.0)):
        cue = record.parallax._replace(errors=torch.rand(1, 1), reward=torch.zeros(1), entropy=torch.zeros(1),
                                        td_error=None, atom_counts=counts)
        metrics.update(record._replace(cues={"parallax": cue, "stereo": cue}, trial_end=False,
                                       errors_deg={"pursuit": torch.zeros(1), "vergence": torch.zeros(1)}))
        assert metrics.summary()["parallax/fine/atom_usage"] == pytest.approx(expected)


def test_state_dict_resumes_exactly():
    records = _records(30, seed=1)
    straight = TrainingMetrics(B, window_fixations=5, cues=CUES)
    for r in records:
        straight.update(r)
    first = TrainingMetrics(B, window_fixations=5, cues=CUES)
    for r in records[:13]:
        first.update(r)
    state = first.state_dict()
    first.update(records[13])  # the state is a copy, not a view
    resumed = TrainingMetrics(B, window_fixations=5, cues=CUES)
    resumed.load_state_dict(state)
    for r in records[13:]:
        resumed.update(r)
    a, b = straight.summary(), resumed.summary()
    assert a.keys() == b.keys()
    assert all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in a)
    with pytest.raises(ValueError, match="window_fixations"):
        TrainingMetrics(B, window_fixations=6, cues=CUES).load_state_dict(state)


def test_rejects_bad_arguments_and_records():
    with pytest.raises(ValueError, match="num_envs"):
        TrainingMetrics(0)
    with pytest.raises(ValueError, match="environments"):
        TrainingMetrics(B + 1, cues=CUES).update(_records(1)[0])
    with pytest.raises(ValueError, match="the metrics expect \\['parallax'\\]"):
        TrainingMetrics(B, cues={"parallax": SCALES}).update(_records(1)[0])
    with pytest.raises(ValueError, match="movements"):
        TrainingMetrics(B, cues=CUES, movements=["vergence"]).update(_records(1)[0])


def test_a_vergence_only_record_keeps_both_movements_and_one_cue():
    records = _records(8)
    metrics = TrainingMetrics(B, window_fixations=100, cues={"stereo": SCALES})
    for r in records:
        metrics.update(r._replace(cues={"stereo": r.stereo}))
    summary = metrics.summary()
    assert "pursuit_mae_deg" in summary and "stereo/reward" in summary and "parallax/reward" not in summary


def test_docstring_example_runs():
    import doctest

    import aectorch.runtime.metrics

    failed, attempted = doctest.testmod(aectorch.runtime.metrics, verbose=False)
    assert attempted > 0 and failed == 0
