"""Evaluation on rectified stereo photographs: the library (aectorch.evaluation.stereo_pairs) and
``python -m aectorch.evaluate pairs=FOLDER`` on tiny pairs of both layouts with a small checkpoint."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from aectorch.evaluate import main
from aectorch.evaluation.stereo_pairs import START_KINDS, Scoring, evaluate_pairs
from aectorch.sim.stereo_pairs import StereoPair, pick_fixations

#: The newest checkpoint of the migration fixtures: a small learner (2 iterations per fixation).
CHECKPOINT = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "checkpoints").glob("*.pt"))[-1]
DISPARITY = 4


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    noise = np.random.default_rng(seed).random((h + 2, w + 2))
    return (noise[:-2, :-2] + noise[1:-1, 1:-1] + noise[2:, 2:]) / 3


def shifted(image: np.ndarray, k: int) -> np.ndarray:
    """The right photograph of a scene at disparity ``k``: ``right[x - k] = left[x]``."""
    return np.concatenate((image[:, k:], np.repeat(image[:, -1:], k, 1)), 1)


def save_png(path: Path, image: np.ndarray) -> None:
    Image.fromarray((np.clip(image, 0, 1) * 255).round().astype(np.uint8)).save(path)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> Path:
    """Two 180 x 260 pairs at disparity 4 px: one in the plain layout, one in Middlebury's."""
    folder = tmp_path_factory.mktemp("pairs")
    image = texture(180, 260)
    plain, middlebury = folder / "plain", folder / "middlebury"
    plain.mkdir()
    middlebury.mkdir()
    save_png(plain / "left.png", image)
    save_png(plain / "right.png", shifted(image, DISPARITY))
    np.save(plain / "disparity.npy", np.full(image.shape, float(DISPARITY), np.float32))
    save_png(middlebury / "im0.png", image)
    save_png(middlebury / "im1.png", shifted(image, DISPARITY))
    disparity = np.full(image.shape, float(DISPARITY), np.float32)
    disparity[:, :3] = np.inf  # unknown
    rows = np.ascontiguousarray(disparity[::-1], "<f4")
    (middlebury / "disp0.pfm").write_bytes(f"Pf\n{image.shape[1]} {image.shape[0]}\n-1.0\n".encode() + rows.tobytes())
    return folder


def test_the_command_evaluates_the_learner_and_the_matcher_on_pairs_of_both_layouts(pairs, tmp_path, capsys):
    out = tmp_path / "pairs.json"
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={pairs}", f"out={out}", "fixations=3", "progress=false"]) == 0
    result = json.loads(out.read_text())
    assert [p["name"] for p in result["pairs"]] == ["middlebury", "plain"]
    assert [p["fixations"] for p in result["pairs"]] == [3, 3]
    assert result["pair_scale"] == 1 and result["folder"] == str(pairs) and result["steps"] == 2  # the run's protocol
    rows = result["per_fixation"]
    assert len(rows) == 2 * 3 * len(START_KINDS) * 2  # pairs x points x starts x (learner, matcher)
    for row in rows:
        assert row["ground_truth_px"] == DISPARITY and row["window"] == "smooth"
        assert row["vergence_error_px"] == pytest.approx(
            PINHOLE_FOCAL * np.tan(np.radians(row["end_vergence_deg"])) - DISPARITY, abs=1e-4)
    protocol = [r for r in rows if r["start"] == "protocol"]
    assert all(r["start_vergence_deg"] == 0.0 and r["start_error_px"] == -DISPARITY for r in protocol)  # parallel
    summary = result["summary"]
    assert set(summary) == {"learner", "matcher", "no_movement"}
    assert summary["no_movement"]["protocol"]["all"]["median_abs_px"] == DISPARITY
    # the matcher, with the learner's actions, ends within a pixel of every match from parallel eyes
    assert summary["matcher"]["protocol"]["all"]["within_1px"] == 1.0
    assert summary["learner"]["vergence_test"]["edge"]["n"] == 0
    assert "matcher      protocol" in capsys.readouterr().out
    # two photo pixels per eye pixel: the optimum is half as far (the eyes' windows need a larger photo)
    large = tmp_path / "large"
    large.mkdir()
    image = texture(340, 420)
    save_png(large / "left.png", image)
    save_png(large / "right.png", shifted(image, DISPARITY))
    np.save(large / "disparity.npy", np.full(image.shape, float(DISPARITY)))
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={large}", f"out={out}", "fixations=2", "pair_scale=2",
                 "progress=false"]) == 0
    result = json.loads(out.read_text())
    assert {r["ground_truth_px"] for r in result["per_fixation"]} == {DISPARITY / 2}


PINHOLE_FOCAL = 257.3401


@pytest.mark.parametrize("arguments, message", [
    (["textures=."], "pairs and textures exclude each other"),
    (["tracking=[0,1]"], "pairs and tracking exclude each other"),
    (["pairs=nowhere"], "pairs: no such folder 'nowhere'"),
    (["pair_scale=0"], "pair_scale must be"),
])
def test_bad_arguments_name_the_argument(pairs, tmp_path, capsys, arguments, message):
    given = [f"pairs={pairs}"] if not any(a.startswith("pairs=") for a in arguments) else []
    code = main([f"checkpoint={CHECKPOINT}", f"out={tmp_path / 'e.json'}", *given, *arguments])
    assert code == 2 and message in capsys.readouterr().err


def test_pair_options_need_pairs(tmp_path, capsys):
    assert main([f"checkpoint={CHECKPOINT}", f"out={tmp_path / 'e.json'}", "pair_scale=2"]) == 2
    assert "pair_scale acts only on stereo pairs: give pairs=FOLDER" in capsys.readouterr().err


def test_bad_pair_folders_are_named(tmp_path, capsys):
    odd = tmp_path / "odd" / "one"
    odd.mkdir(parents=True)
    save_png(odd / "left.png", texture(180, 260))
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={odd.parent}", f"out={tmp_path / 'e.json'}"]) == 2
    assert "pairs: pair folder" in (err := capsys.readouterr().err) and "lacks right.*, disparity.npy" in err
    flat = tmp_path / "flat" / "grey"
    flat.mkdir(parents=True)
    for name in ("left.png", "right.png"):
        save_png(flat / name, np.full((180, 260), 0.5))
    np.save(flat / "disparity.npy", np.full((180, 260), 4.0))
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={flat.parent}", f"out={tmp_path / 'e.json'}"]) == 2
    assert "pairs: pair 'grey' (260 x 180 px) has no fixation point with contrast >= 0.05" in capsys.readouterr().err


def test_an_oracle_policy_ends_on_every_match_and_depth_edges_are_told_from_smooth_windows():
    """A policy that turns the eye by its error lands on the ground truth; a window is an edge where
    the ground truth steps (4 px left of column 300, 12 px right of it) inside its coarse window."""
    image = torch.from_numpy(texture(200, 600)).float()
    disparity = torch.full((200, 600), 4.0)
    disparity[:, 300:] = 12.0
    right = torch.from_numpy(shifted(texture(200, 600), 4)).float()  # the images need not match for the oracle
    pair = StereoPair("step", image, right, disparity)

    def oracle(observation, world):
        return -world.vergence_error_deg.float()

    out = evaluate_pairs({"oracle": oracle}, [pair], fixations=40, steps=1, seed=1)
    for kind in START_KINDS:
        assert out["summary"]["oracle"][kind]["all"]["median_abs_px"] < 1e-6
    rows = out["per_fixation"]
    assert all(abs(r["vergence_error_px"]) < 1e-6 for r in rows)
    for row in rows:
        if abs(row["x"] - 300) > 80:
            assert row["window"] == "smooth" and row["plane_residual_px"] < 1e-6, row
        if abs(row["x"] - 300) < 32:
            assert row["window"] == "edge", row
    assert {r["window"] for r in rows} == {"smooth", "edge"}


def layered_pair(near: int = 12, far: int = 4) -> tuple[StereoPair, np.ndarray]:
    """A rendered pair of two surfaces: a background at disparity ``far`` and, before it, a near
    square at disparity ``near`` (columns 120-199 of the left photograph, rows 40-139). Each eye's
    photograph is painted back to front, so what the right one shows is what it sees; the
    ground truth is the left photograph's. Returns the pair and which left pixels the right
    photograph shows at their ground truth (the oracle's visibility)."""
    h, w = 180, 320
    back, front = texture(h, w + near, seed=3), texture(h, w + near, seed=4)
    left, right = back[:, :w].copy(), back[:, far:far + w].copy()  # right[x - far] = back[x]
    disparity = np.full((h, w), float(far), np.float32)
    rows, cols = slice(40, 140), slice(120, 200)
    left[rows, cols] = front[rows, cols]
    right[rows, 120 - near:200 - near] = front[rows, cols]  # painted over the background
    disparity[rows, cols] = near
    # Oracle: the left pixel (y, x) is seen by the right eye where the right photograph at x - d
    # shows the same surface point, i.e. it was painted by the same layer.
    painted_front = np.zeros((h, w), bool)
    painted_front[rows, 120 - near:200 - near] = True
    x = np.arange(w)[None, :].repeat(h, 0)
    target = (x - disparity.astype(int))
    inside = (target >= 0) & (target < w)
    on_front = disparity == near
    seen = inside & (painted_front[np.arange(h)[:, None], target.clip(0, w - 1)] == on_front)
    pair = StereoPair("layered", torch.from_numpy(left).float(), torch.from_numpy(right).float(),
                      torch.from_numpy(disparity))
    return pair, seen


def test_occlusion_marks_what_a_rendered_right_photograph_hides():
    """`occlusion` from the ground truth alone against the renderer's own visibility: the strip
    of background left of the near square (near - far = 8 px wide) is hidden, nothing else but
    the columns that land outside the right photograph; and where it says visible, the right
    photograph shows the left pixel at its ground truth."""
    from aectorch.sim.stereo_pairs import occlusion

    pair, seen = layered_pair()
    hidden = occlusion(pair).numpy()
    assert np.array_equal(hidden, ~seen)
    assert hidden[60, 112:120].all() and not hidden[60, 111] and not hidden[60, 120:].any()
    assert hidden[10, :4].all() and not hidden[10, 4:].any()
    d = pair.disparity.numpy().astype(int)
    y, x = np.nonzero(~hidden)
    assert np.array_equal(pair.left.numpy()[y, x], pair.right.numpy()[y, x - d[y, x]])


def test_the_summaries_count_the_visible_points_apart():
    """Fixation points on the hidden strip are occluded; the visible part's summary is over the others."""
    pair, seen = layered_pair()

    def oracle(observation, world):
        return -world.vergence_error_deg.float()

    out = evaluate_pairs({"oracle": oracle}, [pair], fixations=400, steps=1, seed=0, scales=("full",))
    rows = out["per_fixation"]
    for row in rows:
        x, y = row["x"], row["y"]
        assert row["occluded"] == (not seen[y - 1:y + 1, x - 1:x + 1].all()), row
    assert any(r["occluded"] for r in rows) and not all(r["occluded"] for r in rows)
    for kind in START_KINDS:
        visible = out["summary"]["oracle"][kind]["visible"]
        assert visible["n"] == sum(not r["occluded"] for r in rows if r["start"] == kind)
def without_truth(image: torch.Tensor, k: int, name: str = "robot") -> StereoPair:
    """A pair at disparity ``k`` everywhere, its disparity not given."""
    return StereoPair(name, image, torch.from_numpy(shifted(image.numpy(), k)).float())


def image_reward(observation: dict) -> torch.Tensor:
    """A stand-in for the coding reward: the fine scale's halves' mean |difference|, negated."""
    fine = observation["fine"]
    return -(fine[:, 0] - fine[:, 1]).abs().mean((1, 2)).double()


def test_a_pair_without_ground_truth_is_scored_by_reward_stability_and_agreement():
    """From parallel eyes the matcher (any increment) ends on the shift, the still policy stays at
    0: perfectly stable, 6 px from the matcher, with the worse reward; no vergence test runs."""
    from aectorch.baselines import Matcher

    k, fixations = 6, 5
    pair = without_truth(torch.from_numpy(texture(200, 400)).float(), k)
    matcher = Matcher(actions_deg=None, scales=("wide", "coarse", "fine", "full"))
    policies = {"still": lambda observation, world: torch.zeros(world.num_envs),
                "matcher": lambda observation, world: matcher.increment_deg(observation)}
    out = evaluate_pairs(policies, [pair], fixations=fixations, steps=12,
                         scoring=Scoring(reward=image_reward, reference="matcher"))
    rows = out["per_fixation"]
    assert len(rows) == 2 * fixations and {r["start"] for r in rows} == {"protocol"}  # no vergence test
    assert all(r["ground_truth"] is False and "vergence_error_px" not in r for r in rows)
    still = [r for r in rows if r["policy"] == "still"]
    ends = [r for r in rows if r["policy"] == "matcher"]
    for s, m in zip(still, ends):
        assert (s["x"], s["y"]) == (m["x"], m["y"]) and s["start_shift_px"] == 0.0
        assert s["stability_px"] == 0.0 and s["last_increment_px"] == 0.0 and s["end_shift_px"] == 0.0
        assert s["reward"] == s["start_reward"] == m["start_reward"]
        assert m["end_shift_px"] == pytest.approx(k, abs=0.25) and m["stability_px"] < 0.5
        assert s["agreement_px"] == pytest.approx(m["end_shift_px"], abs=1e-6) and m["agreement_px"] is None
        assert m["reward"] > s["reward"]
    part = out["without_ground_truth"]
    assert out["summary"] == {} and part["pairs"] == ["robot"] and part["start_kinds"] == ["protocol"]
    assert "vergence test" in part["note"] and part["search_deg"] == [-2.0, 8.0]
    summary = part["summary"]
    assert summary["still"]["protocol"] == {
        "n": fixations, "median_reward": pytest.approx(sorted(r["reward"] for r in still)[fixations // 2]),
        "median_stability_px": 0.0, "stable": 1.0, "median_last_increment_px": 0.0,
        "median_agreement_px": pytest.approx(k, abs=0.25), "agree_within_1px": 0.0, "agree_beyond_5px": 1.0,
        "at_limit": 0.0}
    assert summary["matcher"]["protocol"]["stable"] == 1.0 and math.isnan(summary["matcher"]["protocol"]["agree_within_1px"])
    assert summary["no_movement"]["protocol"]["n"] == fixations
    assert out["per_pair"]["robot"] == summary and out["pairs"][0]["ground_truth"] is False
    # the points' windows lie inside both photos over the search: x - 36.2 px >= 80 and x + 9 px <= 400 - 80
    assert all(117 <= r["x"] <= 311 and 80 <= r["y"] <= 120 for r in rows)
    # a search that stops short of the match (1 deg: 4.5 px) holds the matcher at its limit
    out = evaluate_pairs(policies, [pair], fixations=2, steps=4,
                         scoring=Scoring(reference="matcher", search_deg=(-2.0, 1.0)))
    ends = [r for r in out["per_fixation"] if r["policy"] == "matcher"]
    assert all(r["at_limit"] and r["end_shift_px"] == pytest.approx(4.4915, abs=1e-3) for r in ends)
    assert out["without_ground_truth"]["summary"]["matcher"]["protocol"]["at_limit"] == 1.0
    assert out["without_ground_truth"]["summary"]["still"]["protocol"]["at_limit"] == 0.0


def test_pairs_with_and_without_ground_truth_mix_and_bad_input_is_named():
    image = torch.from_numpy(texture(200, 400)).float()
    truth = StereoPair("truth", image, without_truth(image, 4).right, torch.full((200, 400), 4.0))
    still = {"still": lambda observation, world: torch.zeros(world.num_envs)}
    out = evaluate_pairs(still, [truth, without_truth(image, 4)], fixations=3, steps=2)
    rows = out["per_fixation"]
    assert {(r["pair"], r["ground_truth"], r["start"]) for r in rows} == {
        ("truth", True, "protocol"), ("truth", True, "vergence_test"), ("robot", False, "protocol")}
    assert out["summary"]["still"]["protocol"]["all"] == {"n": 3, "median_abs_px": 4.0, "within_1px": 0.0,
                                                          "beyond_5px": 0.0, "mean_abs_px": 4.0}
    assert out["without_ground_truth"]["summary"]["still"]["protocol"]["n"] == 3
    assert "reward" not in rows[0] and "agreement_px" not in rows[0]  # no scoring given: the stability alone
    assert math.isnan(out["without_ground_truth"]["summary"]["still"]["protocol"]["median_reward"])
    with pytest.raises(ValueError, match=r"scoring.reference 'matcher' is none of the policies \['still'\]"):
        evaluate_pairs(still, [truth], scoring=Scoring(reference="matcher"))
    with pytest.raises(ValueError, match=r"the search range \[10.0, 20.0\] deg lies outside the vergence range"):
        evaluate_pairs(still, [without_truth(image, 4)], scoring=Scoring(search_deg=(10.0, 20.0)),
                       vergence_range_deg=(-2.0, 8.0))
    with pytest.raises(ValueError, match="inside both images over the shifts -9.0 to 36.2 photo px"):
        evaluate_pairs(still, [without_truth(image[:, :200], 4)])  # too narrow for the search
    with pytest.raises(ValueError, match="has no ground truth: give shift_range_px"):
        pick_fixations(without_truth(image, 4), 3, half_extent_px=80, texture_half_px=20)


def test_the_command_scores_pairs_without_ground_truth_beside_pairs_with_it(pairs, tmp_path, capsys):
    folder = tmp_path / "mixed"
    shutil.copytree(pairs, folder)
    robot = folder / "robot"
    robot.mkdir()
    image = texture(180, 260, seed=3)
    save_png(robot / "left.png", image)
    save_png(robot / "right.png", shifted(image, DISPARITY))
    out = tmp_path / "mixed.json"
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={folder}", f"out={out}", "fixations=3", "progress=false"]) == 0
    result = json.loads(out.read_text())
    assert [(p["name"], p["ground_truth"]) for p in result["pairs"]] == [
        ("middlebury", True), ("plain", True), ("robot", False)]
    rows = [r for r in result["per_fixation"] if r["pair"] == "robot"]
    assert len(rows) == 3 * 2 and {r["start"] for r in rows} == {"protocol"}
    for row in rows:  # the learner's stereo encoder scores both policies' ends
        assert row["reward"] < 0 and row["start_reward"] < 0 and row["stability_px"] >= 0
        assert (row["agreement_px"] is None) == (row["policy"] == "matcher")
    part = result["without_ground_truth"]
    assert part["pairs"] == ["robot"] and part["reference"] == "matcher" and part["reward"] is True
    assert set(part["summary"]) == {"learner", "matcher", "no_movement"}
    assert part["summary"]["learner"]["protocol"]["n"] == 3
    assert set(result["summary"]) == {"learner", "matcher", "no_movement"}  # over the pairs with ground truth
    assert result["summary"]["learner"]["protocol"]["all"]["n"] == 6
    assert "without ground truth (robot): the protocol's start only" in capsys.readouterr().out


@pytest.mark.parametrize("arguments, message", [
    (["search_deg=[3,1]"], "search_deg must be [low, high] with low < high"),
    (["search_deg=[1]"], "search_deg must be [low, high] in degrees"),
])
def test_bad_search_ranges_name_the_argument(pairs, tmp_path, capsys, arguments, message):
    assert main([f"checkpoint={CHECKPOINT}", f"out={tmp_path / 'e.json'}", f"pairs={pairs}", *arguments]) == 2
    assert message in capsys.readouterr().err


def test_search_needs_pairs_and_a_folder_needs_both_images(tmp_path, capsys):
    assert main([f"checkpoint={CHECKPOINT}", f"out={tmp_path / 'e.json'}", "search_deg=[-1,4]"]) == 2
    assert "search_deg acts only on stereo pairs: give pairs=FOLDER" in capsys.readouterr().err
    lone = tmp_path / "lone" / "one"
    lone.mkdir(parents=True)
    np.save(lone / "disparity.npy", np.full((180, 260), 4.0))
    assert main([f"checkpoint={CHECKPOINT}", f"pairs={lone.parent}", f"out={tmp_path / 'e.json'}"]) == 2
    assert "(the plain layout) lacks left.*, right.*" in capsys.readouterr().err
