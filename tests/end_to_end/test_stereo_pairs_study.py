"""The stereo-pairs study's commands (experiments/stereo_pairs) at a tiny size: a small checkpoint
evaluated on a rendered two-layer pair at both pixel scales and on plain planes, then the study's
table (with its JSON), its plain-plane table and its figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.end_to_end import EXPERIMENTS, noise_images, run_script

STUDY = EXPERIMENTS / "stereo_pairs"
#: The newest checkpoint of the migration fixtures: a small learner (2 iterations per fixation).
CHECKPOINT = sorted((EXPERIMENTS.parent / "tests" / "fixtures" / "checkpoints").glob("*.pt"))[-1]


def two_layer_pair(folder: Path, near: int = 12, far: int = 4) -> Path:
    """A 400 x 520 pair in the plain layout: a background at disparity ``far`` and a near square at
    ``near`` (the right photograph painted back to front), with its ground truth."""
    h, w = 400, 520
    rng = np.random.default_rng(0)
    back, front = rng.random((h, w + near)), rng.random((h, w + near))
    left, right = back[:, :w].copy(), back[:, far:far + w].copy()
    disparity = np.full((h, w), float(far), np.float32)
    rows, cols = slice(150, 260), slice(220, 330)
    left[rows, cols], right[rows, 220 - near:330 - near] = front[rows, cols], front[rows, cols]
    disparity[rows, cols] = near
    folder.mkdir(parents=True)
    for name, image in (("left", left), ("right", right)):
        Image.fromarray((image * 255).round().astype(np.uint8)).save(folder / f"{name}.png")
    np.save(folder / "disparity.npy", disparity)
    return folder


@pytest.mark.integration
def test_the_study_evaluates_tabulates_and_draws_a_tiny_pair(tmp_path, capsys):
    from aectorch.evaluate import main

    pairs = two_layer_pair(tmp_path / "pairs" / "layers")
    photos = noise_images(tmp_path / "photos", 2, 64, seed=1)
    runs = [tmp_path / "s0", tmp_path / "s1"]
    for run in runs:
        run.mkdir()
    for k in (1, 2):
        assert main([f"checkpoint={CHECKPOINT}", f"pairs={tmp_path / 'pairs'}", f"pair_scale={k}", "fixations=8",
                     "progress=false", f"out={runs[0] / f'pairs_ps{k}.json'}"]) == 0
        assert "visible median" in capsys.readouterr().out
        (runs[1] / f"pairs_ps{k}.json").write_text((runs[0] / f"pairs_ps{k}.json").read_text())
    assert main([f"checkpoint={CHECKPOINT}", f"textures={photos}", "depths=[1.0]", "progress=false",
                 f"out={runs[0] / 'choose.json'}"]) == 0
    (runs[1] / "choose.json").write_text((runs[0] / "choose.json").read_text())

    table = tmp_path / "results.json"
    done = run_script(str(STUDY / "table.py"), *map(str, runs), "--json", str(table))
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert "visible: median, beyond 5 px" in lines[0]
    assert len(lines) == 2 + 2 * 2 * 3  # header, rule, 2 scales x 2 starts x 3 policies
    rows = json.loads(table.read_text())["rows"]
    learner = [r for r in rows if r["policy"] == "learner"]
    assert all(r["visible_n"][0] <= 8 for r in learner) and any(r["visible_n"][0] < 8 for r in learner)

    done = run_script(str(STUDY / "visible.py"), f"tiny={runs[0]},{runs[1]}")
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("| runs | pixel scale | start | visible points | visible: median (px)") and len(lines) == 2 + 2 * 2
    assert [line.split(" | ")[1:3] for line in lines[2:]] == [["1", "protocol"], ["1", "vergence test"],
                                                              ["2", "protocol"], ["2", "vergence test"]]
    done = run_script(str(STUDY / "visible.py"), f"none={tmp_path / 'photos'}")
    assert done.returncode == 2 and "none: every run needs pairs_ps<k>.json" in done.stderr

    done = run_script(str(STUDY / "plain.py"), "choose.json", f"tiny={runs[0]},{runs[1]}")
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines()[2].startswith("| tiny | ")

    figure = tmp_path / "pair.png"
    done = run_script(str(STUDY / "figure.py"), str(pairs), str(runs[0] / "pairs_ps1.json"), str(figure))
    assert done.returncode == 0, done.stdout + done.stderr
    assert figure.stat().st_size > 10_000
