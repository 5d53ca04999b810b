"""The rearing study's scripts (experiments/rearing) at a tiny size: the code learned from texture
crops alone, and the lineage's binocularity measure beside ours on a tiny reared run."""

from __future__ import annotations

import json

import pytest
import torch

from tests.end_to_end import EXPERIMENTS, TINY, noise_images, run_script, study_module

STUDY = EXPERIMENTS / "rearing"


@pytest.mark.integration
def test_the_code_learned_from_crops_alone_is_read_out_for_both_texture_sets(tmp_path):
    out = tmp_path / "code_only.json"
    done = run_script(str(STUDY / "code_only.py"), "--steps", "2", "--every", "1", "--num-textures", "2",
                      "--json", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    results = json.loads(out.read_text())["results"]
    assert len(results) == 2 and all([row["step"] for row in rows] == [0, 1, 2] for rows in results.values())
    first = next(iter(results.values()))
    assert set(first[0]) == {"step", "fine", "full"} and 0 <= first[-1]["full"]["mean_abs_index"] <= 1


@pytest.mark.integration
def test_gabor_reads_a_reared_run_with_both_measures(tmp_path):
    photos = noise_images(tmp_path / "textures", 2, 64, seed=0)
    run = tmp_path / "suite" / "monocular_s0"
    done = run_script("train.py", "rearing=monocular", f"env.textures={photos}", *TINY, "train.iterations=4",
                      "eval.enabled=false", f"hydra.run.dir={run}")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    out = tmp_path / "gabor.json"
    done = run_script(str(STUDY / "gabor.py"), str(tmp_path / "suite"), "--json", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "| monocular (1) | stereo/fine |" in done.stdout
    table = json.loads(out.read_text())
    assert set(table["monocular"]) == {"wide", "coarse", "fine", "full"}


def test_both_measures_call_monocular_atoms_monocular():
    from aectorch.coding.gabor import _gabor  # the Gabor model the fit uses

    measures = study_module("rearing", "gabor").measures

    y, x = torch.meshgrid(torch.arange(8.0) - 3.5, torch.arange(8.0) - 3.5, indexing="ij")
    params = torch.tensor([[1.0, 0.3 * k - 1, 0.2, 0.4 * k, 0.15, 0.5, 0.7, 0.9] for k in range(6)], dtype=torch.float64)
    halves = _gabor(params, x.flatten().double(), y.flatten().double())  # [6, 64]
    atoms = torch.cat([torch.cat([halves[:3], torch.zeros(3, 64, dtype=torch.float64)], 1),
                       torch.cat([torch.zeros(3, 64, dtype=torch.float64), halves[3:]], 1)]).T  # [128, 6]
    out = measures(atoms)
    assert out["valid"] == 1.0 and out["gabor_left"] == out["ours_left"] == 0.5
    assert out["gabor_right"] == out["ours_right"] == 0.5
