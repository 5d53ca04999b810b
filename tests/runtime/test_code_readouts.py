"""``train.readout_every``: the code read out during training into ``code_readouts.jsonl``, kept up to
the checkpoint on resume, read back by `Run.code_readouts`."""

from __future__ import annotations

import json

import pytest
from omegaconf import OmegaConf

from aectorch.coding.readouts import code_summary
from aectorch.runtime import load_learner, run_experiment
from aectorch.runtime.builders import dictionaries
from aectorch.runtime.config import to_experiment_config
from aectorch.runtime.outputs import CODE_READOUTS, RUN_FILES, RunFolder
from aectorch.runs import Run

from tests.runtime.test_train import _cfg, textures  # noqa: F401  (shared fixture)


@pytest.mark.parametrize("value", [0, -2, True, 1.5, "often"])
def test_a_bad_readout_every_is_refused_naming_the_key(value):
    with pytest.raises(ValueError, match=r"train\.readout_every"):
        to_experiment_config(OmegaConf.create({"train": {"readout_every": value}}))


def test_readouts_are_a_run_file_and_absent_reads_as_none(tmp_path):
    assert CODE_READOUTS in RUN_FILES  # train.overwrite deletes it; a new run into the folder stops at it
    assert to_experiment_config(OmegaConf.create({})).train.readout_every is None
    assert Run(tmp_path).code_readouts == []


def test_the_folder_keeps_lines_up_to_the_resumed_checkpoint(tmp_path):
    path = tmp_path / CODE_READOUTS
    lines = [json.dumps({"iteration": i, "code": {}}) for i in (2, 4, 6)]
    path.write_text("\n".join(lines) + '\n{"iteration": 8, "co')  # a line torn by a kill
    folder = RunFolder(tmp_path)
    folder.start({}, {}, resumed_at=4, tensorboard=False)
    assert [line["iteration"] for line in Run(tmp_path).code_readouts] == [2, 4]
    folder.start({}, {}, resumed_at=None, tensorboard=False)  # a new run starts without them
    assert not path.exists()
    folder.release()


@pytest.mark.integration
def test_readouts_every_n_and_at_the_end(tmp_path, textures):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=7", "train.readout_every=2"), run)
    readouts = Run(run).code_readouts
    assert [line["iteration"] for line in readouts] == [2, 4, 6, 7]
    _, learner = load_learner(run / "checkpoint.pt")
    atoms = dictionaries(learner)
    assert set(readouts[-1]["code"]) == set(atoms) and "stereo/fine" in atoms
    assert readouts[-1]["code"] == {name: code_summary(a) for name, a in atoms.items()}
    assert readouts[0]["code"] != readouts[-1]["code"]  # the code learns between read-outs


@pytest.mark.integration
def test_a_resume_drops_the_readouts_past_its_checkpoint(tmp_path, textures):
    run = tmp_path / "run"
    cfg = ["train.readout_every=2", "train.checkpoint_every=4"]

    def fail(done, record):
        if done == 7:
            raise RuntimeError("stopped for the test")

    with pytest.raises(RuntimeError, match="stopped for the test"):
        run_experiment(_cfg(textures, *cfg), run, callback=fail)
    before = Run(run).code_readouts
    assert [line["iteration"] for line in before] == [2, 4, 6]  # the checkpoint holds iteration 4
    run_experiment(_cfg(textures, *cfg, f"train.resume={run}"), run)
    after = Run(run).code_readouts
    assert [line["iteration"] for line in after] == [2, 4, 6, 8, 10, 12]
    assert after[:3] == before  # kept, and iteration 6 trained again to the same code (a resume is exact)
