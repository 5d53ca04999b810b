"""Old checkpoints in one place: every checkpoint written since the first release of train.py loads.

``tests/fixtures/checkpoints`` holds a small checkpoint of every version that changed what a
checkpoint holds (``make.py`` there says how each was made). Each loads through
`aectorch.runtime.migrations`, builds a learner that steps, and resumes; the last one of format 1
holds, under the old names, the very tensors today's code computes for the same run.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from aectorch.runtime import CHECKPOINT_FORMAT, load_checkpoint, load_learner, run_experiment, to_experiment_config
from aectorch.runtime.migrations import migrate
from aectorch.sim import ActiveDepthEnv

HERE = Path(__file__).resolve().parents[1] / "fixtures" / "checkpoints"
ROOT = HERE.parents[2]
STORED = sorted(HERE.glob("*.pt"))
_spec = importlib.util.spec_from_file_location("make_checkpoints", HERE / "make.py")
make = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make)


def test_every_version_that_changed_the_format_has_a_stored_checkpoint():
    assert [p.stem.split("-")[-1] for p in STORED] == list(make.COMMITS)


@pytest.mark.parametrize("path", STORED, ids=[p.stem for p in STORED])
def test_a_stored_checkpoint_loads_and_its_learner_steps(path):
    payload = load_checkpoint(path)
    assert payload["format"] == CHECKPOINT_FORMAT and torch.load(path, weights_only=False)["format"] in (1, 2)
    cfg, learner = load_learner(path, payload=payload)
    assert cfg.learner.cues["stereo"].encoder.num_atoms == 16 and list(learner.cues) == ["parallax", "stereo"]
    env = ActiveDepthEnv(2, protocol=cfg.env.protocol,
                         textures=torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)), seed=0)
    records = [learner.iteration(env) for _ in range(4)]
    assert all(bool(c.reward.isfinite().all()) for r in records for c in r.cues.values())
    assert any(r.stereo.td_error is not None for r in records)


def test_fields_a_version_did_not_have_take_what_that_version_did():
    first = load_learner(STORED[0])[0]  # 30ee905: no symmetries, whole crops, constant rates
    assert [c.symmetry for c in first.learner.cues.values()] == [None, None]
    assert not first.learner.render_scales and first.learner.cues["stereo"].encoder.decay is None
    assert first.learner.cues["stereo"].reward == "coding" and first.env.shift_iterations == 1
    assert first.learner.cues["stereo"].nac.batch_reference is None and not first.train.keep_best
    symmetric = load_learner(next(p for p in STORED if p.stem.endswith("488db67")))[0]
    assert [c.symmetry for c in symmetric.learner.cues.values()] == ["mirror", "swap"]
    last = load_learner(STORED[-2])[0]  # the last of format 1
    assert last.learner.render_scales and last.learner.cues["parallax"].encoder.decay == 500
    for path in STORED:  # every stored file predates the oculomotor range: the pan limits alone
        env = load_learner(path)[0].env
        assert (env.pan_range_deg, env.vergence_range_deg) == ([-45.0, 45.0], [-90.0, 90.0])
    for path in STORED[-2:]:  # format 1 and 2: NAC with the argmax read-out, no motor cost, a random start
        cues = load_learner(path)[0].learner.cues.values()
        assert [(c.agent, c.readout, c.motor_cost, c.encoder.start, tuple(c.scales)) for c in cues] == [
            ("nac", "argmax", 0.0, "random", ("wide", "coarse", "fine"))] * 2


def test_a_stored_format_1_payload_migrates_once_and_today_s_is_left_alone():
    raw = torch.load(STORED[-2], weights_only=False)
    new = migrate(raw)
    assert new is not raw and raw["format"] == 1 and "pursuit.actor_weight" in raw["learner"]
    assert "cues.parallax.agent.actor_weight" in new["learner"] and migrate(new) is new
    with pytest.raises(ValueError, match="format 4 is not one this aectorch reads"):
        migrate({**new, "format": 4})


@pytest.mark.integration
@pytest.mark.parametrize("path", [STORED[0], STORED[len(STORED) // 2], STORED[-2], STORED[-1]], ids=lambda p: p.stem)
def test_a_stored_checkpoint_resumes(tmp_path, path):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(path, run / "checkpoint.pt")
    cfg = to_experiment_config({"train": {"resume": str(run), "iterations": 6, "progress": False}})
    summary = run_experiment(cfg, tmp_path / "ignored")
    assert summary["iterations"] == 6 and load_checkpoint(run / "checkpoint.pt")["iteration"] == 6


#: The cues' defaults of formats 1 and 2 that format 3 changed, in today's keys.
OLD_DEFAULTS = [f"learner.cues.{cue}.{key}={value}" for cue in ("parallax", "stereo")
                for key, value in (("agent", "nac"), ("readout", "argmax"), ("scales", "[wide,coarse,fine]"))]


@pytest.mark.integration
@pytest.mark.parametrize("path", STORED[-2:], ids=lambda p: p.stem)
def test_the_last_checkpoint_of_each_old_format_holds_what_today_s_code_computes(tmp_path, path):
    """a9b2aa6's (format 1) and 430fb6a's (format 2) run of make.py's settings, migrated, against the
    same run of today's train.py with those versions' defaults: the same tensors under today's
    names (the same machine gives them bit for bit)."""
    run = tmp_path / "run"
    atoms = [f"learner.cues.{cue}.encoder.num_atoms=16" for cue in ("parallax", "stereo")]  # today's keys
    args = [a for a in (*make.TINY, *make.OPTIONAL) if not a.startswith("learner.num_atoms")] + atoms + OLD_DEFAULTS
    done = subprocess.run([sys.executable, str(ROOT / "train.py"), *args, f"hydra.run.dir={run}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    old, new = load_checkpoint(path), load_checkpoint(run / "checkpoint.pt")
    assert old["learner"].keys() == new["learner"].keys()
    for key, value in new["learner"].items():
        if isinstance(value, torch.Tensor):
            torch.testing.assert_close(old["learner"][key], value, rtol=1e-5, atol=1e-6, msg=key)
    for part in ("env", "metrics"):
        assert old[part].keys() == new[part].keys(), part
    assert {k: v for k, v in old["config"]["learner"].items() if k != "cues"} == \
        {k: v for k, v in new["config"]["learner"].items() if k != "cues"}
    for name, cue in new["config"]["learner"]["cues"].items():
        assert {k: v for k, v in cue.items() if k != "ppo"} == \
            {k: v for k, v in old["config"]["learner"]["cues"][name].items() if k != "ppo"}
