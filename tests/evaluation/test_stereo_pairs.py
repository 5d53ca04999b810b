"""Evaluation on rectified stereo photographs: the library (aectorch.evaluation.stereo_pairs) and
``python -m aectorch.evaluate pairs=FOLDER`` on tiny pairs of both layouts with a small checkpoint."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from aectorch.evaluate import main
from aectorch.evaluation.stereo_pairs import START_KINDS, evaluate_pairs
from aectorch.sim.stereo_pairs import StereoPair

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
