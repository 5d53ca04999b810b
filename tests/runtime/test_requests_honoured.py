"""Nothing a user asks for is silently dropped, and no stale result passes for a new one.

- A resume compares the config groups it is given (``rearing``, ``+experiment``, ...) with the
  run's, and keeps Hydra's record of the run's start (``.hydra/``); ``train.resume=auto`` without
  a folder to resume is refused.
- ``train.overwrite`` deletes exactly the files aectorch wrote (evaluations included) and never a
  user's; a new run into a folder with files it would overwrite is refused.
- Commands check their outputs before they work; evaluations name the checkpoint they were made
  from, and ``report`` refuses one that the run's checkpoint no longer is.
- Options that would do nothing are errors; one-line errors keep the choices and the hint.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from aectorch.evaluate import main as evaluate
from aectorch.report.__main__ import main as report
from aectorch.runs import Run
from aectorch.runtime import RunExists, load_checkpoint, run_experiment
from aectorch.runtime.presets import REARING
from tests.runtime.test_distributed import _single
from tests.end_to_end.test_rearing_report import _run as _rearing_run
from tests.end_to_end.test_rearing_report import main as rearing_report
from tests.end_to_end.test_roll_adaptation_report import main as adaptation_report
from tests.end_to_end.test_moving_objects_study import main as tracking_report
from tests.runtime.test_train import QUIET, TINY, _cfg, textures  # noqa: F401  (the fixture)


def _error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr[-3000:]
    return lines[0]


def _files(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# --- resume ----------------------------------------------------------------------------------


@pytest.mark.integration
def test_a_resume_refuses_another_config_group_and_keeps_the_record_of_the_start(tmp_path, textures):
    run = tmp_path / "R"
    args = [*TINY, *QUIET, f"env.textures={textures}", f"hydra.run.dir={run}", "train.iterations=4"]
    done = _single(*args, "rearing=monocular", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    start = _files(run / ".hydra")
    before = _files(run)
    for group, started in (("rearing=strabismus", "rearing=monocular"), ("+experiment=accommodation", "no experiment")):
        again = _single(*args, "train.iterations=6", "train.resume=auto", group, cwd=tmp_path)
        line = _error_line(again.stderr)
        assert again.returncode == 2 and group in line and f"started with {started}" in line, line
        assert _files(run) == before  # nothing written
    # The same group continues the run; Hydra's record of the resume goes beside the start's.
    done = _single(*args, "train.iterations=6", "train.resume=auto", "rearing=monocular", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 6
    assert {k: v for k, v in _files(run / ".hydra").items() if not k.startswith("resumed/")} == start
    assert "train.resume=auto" in (run / ".hydra" / "resumed" / "overrides.yaml").read_text()


@pytest.mark.integration
def test_a_group_whose_keys_contradict_the_stored_run_is_refused_without_hydras_record(textures):
    """A run of `run_experiment` has no ``.hydra/``: the group's own keys are compared."""
    from aectorch.runtime.checkpoint import check_resume_groups
    from aectorch.runtime.config import to_experiment_config, to_container

    def reared(condition):
        node = to_container(_cfg(textures))
        node["perturbations"] = REARING[condition]
        return to_experiment_config(node)

    with pytest.raises(ValueError, match=r"rearing=strabismus sets perturbations=.*strabismus.*but the resumed run "
                                         r"has perturbations=.*monocular_deprivation"):
        check_resume_groups(reared("strabismus"), reared("monocular"), {"rearing": "strabismus"}, None)
    check_resume_groups(reared("monocular"), reared("monocular"), {"rearing": "monocular"}, None)


@pytest.mark.integration
def test_resume_auto_without_a_folder_to_resume_is_refused(tmp_path):
    for extra, key in (([], "hydra.run.dir"), (["-m", "seed=0"], "hydra.sweep.dir")):
        done = _single(*extra, "train.resume=auto", cwd=tmp_path)
        line = _error_line(done.stderr)
        assert done.returncode == 2 and f"train.resume=auto needs {key}=<folder>" in line, line
    assert not any(tmp_path.iterdir())  # no outputs/ nor multirun/ folder made


def test_a_relaunched_sweep_is_told_to_give_another_sweep_folder(tmp_path, capsys):
    from aectorch.runtime.launch import RunFolderGuard

    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "checkpoint.pt").write_bytes(b"not a checkpoint")
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}, "train": {"resume": None, "overwrite": False}})
    with pytest.raises(SystemExit) as stopped:
        RunFolderGuard().on_multirun_start(config)
    line = _error_line(capsys.readouterr().err)
    assert stopped.value.code == 2 and "hydra.sweep.dir=" in line and "hydra.run.dir" not in line, line


# --- the run folder: overwrite, clobbering, writability ---------------------------------------


@pytest.mark.integration
def test_overwrite_deletes_what_aectorch_wrote_evaluations_included_and_nothing_else(tmp_path, textures):
    from aectorch.runs import file_sha256

    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    assert evaluate([f"checkpoint={run / 'checkpoint.pt'}", f"textures={textures}", f"out={run / 'tracking.json'}",
                     "depths=[1.0]", "tracking=[0]", "skip=1", "progress=false"]) == 0
    source = json.loads((run / "tracking.json").read_text())["source"]
    assert source == {"checkpoint": "checkpoint.pt", "iteration": 2, "sha256": file_sha256(run / "checkpoint.pt")}
    assert Run(run).evaluation("tracking.json")["iteration"] == 2  # made from the run's checkpoint: read
    stale = (run / "tracking.json").read_bytes()
    (run / "figures").mkdir()
    mine = {"figures/mine.png": b"a user's figure", "notes.txt": b"a user's notes", "tb/mine.txt": b"mine"}
    (run / "tb").mkdir()
    for name, data in mine.items():
        (run / name).write_bytes(data)

    run_experiment(_cfg(textures, "train.iterations=4", "train.overwrite=true"), run)
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 4
    assert not (run / "tracking.json").exists()  # the old run's evaluation went with it
    assert {name: (run / name).read_bytes() for name in mine} == mine  # the user's files stayed

    # An old evaluation put back is refused by report: it was made from another checkpoint.
    (run / "tracking.json").write_bytes(stale)
    with pytest.raises(ValueError, match=r"tracking.json was made from checkpoint.pt at iteration 2, but the run's "
                                         r"checkpoint.pt is another checkpoint now"):
        Run(run).evaluation("tracking.json")


@pytest.mark.integration
def test_report_tracking_refuses_an_evaluation_of_another_checkpoint(tmp_path, textures, capsys):
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    assert evaluate([f"checkpoint={run / 'checkpoint.pt'}", f"textures={textures}", f"out={run / 'tracking.json'}",
                     "depths=[1.0]", "tracking=[0]", "skip=1", "progress=false"]) == 0
    run_experiment(_cfg(textures, "train.iterations=4", "train.resume=auto"), run)  # checkpoint.pt moves on
    capsys.readouterr()
    assert tracking_report([str(run)]) == 2
    line = _error_line(capsys.readouterr().err)
    assert str(run / "tracking.json") in line and "iteration 2" in line and "evaluate it again" in line, line


@pytest.mark.integration
def test_a_new_run_does_not_overwrite_a_users_files_in_its_folder(tmp_path, textures):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("my: own config\n")
    (run / "summary.json").write_text('{"mine": true}\n')
    before = _files(run)
    with pytest.raises(RunExists, match=r"holds config.yaml, summary.json but no checkpoint.pt, which a new run "
                                        r"would overwrite; nothing was written"):
        run_experiment(_cfg(textures, "train.iterations=2"), run)
    assert _files(run) == before


@pytest.mark.integration
def test_a_run_folder_that_cannot_be_made_or_written_is_one_line(tmp_path, monkeypatch):
    from aectorch.runtime import launch

    (tmp_path / "a_file").write_text("x")
    done = _single(*QUIET, f"hydra.run.dir={tmp_path / 'a_file' / 'run'}", cwd=tmp_path)
    line = _error_line(done.stderr)
    assert done.returncode == 2 and line.startswith("error: hydra.run.dir: ") and "not a folder" in line, line
    # A read-only folder (this test may run as root, whom permissions do not stop: os.access says it).
    monkeypatch.setattr(launch.os, "access", lambda path, mode: False)
    with pytest.raises(ValueError, match=r"hydra.run.dir: cannot write into .*read-only"):
        launch._check_writable(tmp_path / "run", "hydra.run.dir")


# --- commands check their inputs and outputs first --------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, textures) -> Path:
    run = tmp_path_factory.mktemp("evaluated") / "run"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    return run / "checkpoint.pt"


@pytest.mark.integration
@pytest.mark.parametrize("args, message", [
    (["out={tmp}/missing/e.json"], "out: no such folder '{tmp}/missing'"),
    (["out={tmp}"], "out: '{tmp}' is a folder"),
    (["out={tmp}/e.txt"], "out must end in .json"),
    (["out={tmp}/e.json", "figure={tmp}/missing/e.png"], "figure: no such folder"),
    (["out={tmp}/e.json", "depth_speed=-0.01"], "depth_speed acts only in the tracking test: give tracking=[speeds]"),
    (["out={tmp}/e.json", "tracking=fast"], "tracking must be a list such as [1.0,2.0], got 'fast'"),
    (["out={tmp}/e.json", "checkpoint={run}"], "checkpoint: '{run}' is a folder, not a checkpoint file; give its "
                                               "checkpoint, checkpoint={run}/checkpoint.pt"),
])
def test_evaluate_refuses_bad_arguments_before_the_trials(checkpoint, tmp_path, capsys, args, message):
    given = [a.format(tmp=tmp_path, run=checkpoint.parent) for a in args]
    code = evaluate([f"checkpoint={checkpoint}", *given, "depths=[1.0]", "progress=false"])
    line = _error_line(capsys.readouterr().err)
    assert code == 2 and line.startswith("error: " + message.format(tmp=tmp_path, run=checkpoint.parent)), line
    assert not any(p.suffix == ".json" for p in tmp_path.rglob("*"))


@pytest.mark.integration
def test_evaluate_refuses_an_output_it_cannot_write(checkpoint, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(os, "access", lambda path, mode: False)  # (root is not stopped by permissions)
    assert evaluate([f"checkpoint={checkpoint}", f"out={tmp_path / 'e.json'}", "progress=false"]) == 2
    assert _error_line(capsys.readouterr().err).startswith(f"error: out: cannot write '{tmp_path / 'e.json'}'")


@pytest.mark.integration
def test_a_damaged_checkpoint_is_named_as_damaged(checkpoint, tmp_path, capsys):
    import random

    data = checkpoint.read_bytes()
    for name, damaged in (("truncated.pt", data[: len(data) // 2]),
                          ("random.pt", random.Random(0).randbytes(4096))):
        path = tmp_path / name
        path.write_bytes(damaged)
        assert evaluate([f"checkpoint={path}", f"out={tmp_path / 'e.json'}", "progress=false"]) == 2
        line = _error_line(capsys.readouterr().err)
        assert f"cannot read the checkpoint '{path}': it is damaged (truncated?) or not a torch checkpoint" in line, line


# --- options that do nothing; one-line errors keep choices and hints ---------------------------


def test_the_accommodation_start_without_the_accommodation_cue_is_refused(textures):
    with pytest.raises(ValueError, match=r"env.accommodation_start_D=0.0 serves the accommodation cue, which the "
                                         r"learner does not learn .*add \+experiment=accommodation"):
        _cfg(textures, "env.accommodation_start_D=0")


@pytest.mark.integration
@pytest.mark.parametrize("override, expected", [
    ("rearing=monocularr", "rearing is one of: anisometropia_early, anisometropia_late, horizontal, monocular,"),
    ("+experiment=roll", "experiment is one of: accommodation, "),
    ("learner.cues.accommodation.actions_deg=[0.1]",
     "learner.cues.accommodation.actions_deg exists with +experiment=accommodation"),
])
def test_train_py_errors_keep_the_choices_and_the_hint(tmp_path, override, expected):
    from aectorch.runtime.presets import GROUPS

    done = _single(override, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    line = _error_line(done.stderr)
    assert done.returncode == 2 and expected in line, line
    group = override.lstrip("+").split("=")[0]
    if group in GROUPS:  # every option, in the one line
        assert all(option in line for option in GROUPS[group]), line


# --- report ----------------------------------------------------------------------------------


def test_report_rearing_names_an_unfinished_job_instead_of_leaving_its_condition_out(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    _rearing_run(sweep / "0", "normal", 0, None, 10.0)
    (sweep / "1").mkdir()
    OmegaConf.save(OmegaConf.create({"seed": 0, "perturbations": REARING["monocular"]}), sweep / "1" / "config.yaml")
    (sweep / "1" / "metrics.jsonl").write_text('{"iteration": 2}\n')
    assert rearing_report([str(sweep)]) == 2
    line = _error_line(capsys.readouterr().err)
    assert f"{sweep} holds unfinished runs (1: no summary.json)" in line, line


@pytest.mark.parametrize("change", ["9999", "-5"])
def test_report_adaptation_refuses_a_change_outside_the_run(tmp_path, capsys, change):
    run = tmp_path / "run"
    run.mkdir()
    OmegaConf.save(OmegaConf.create({"train": {"recent_window": 4}}), run / "config.yaml")
    lines = [{"iteration": i, "vergence_recent_deg": 0.1, "pursuit_recent_deg": 0.1, "depth_recent_m": 0.01}
             for i in range(10, 110, 10)]
    (run / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    assert adaptation_report([str(run), "--change", change]) == 2
    line = _error_line(capsys.readouterr().err)
    assert f"--change {change} is outside {run}'s logged iterations (10 to 100)" in line, line


def test_report_checks_its_outputs_before_any_work(tmp_path, capsys):
    (tmp_path / "a_file").write_text("x")
    for given, message in ((tmp_path / "a_file" / "t.json", "is a file, so"), (tmp_path, "is a folder")):
        # (the run folder is missing too: the output is checked first)
        assert report(["ablation", "x=missing_run", "--json", str(given)]) == 2
        line = _error_line(capsys.readouterr().err)
        assert line.startswith("error: --json: ") and message in line, line


# --- the text says what the code does ----------------------------------------------------------


def test_the_help_texts_and_the_readme_say_the_defaults():
    import re

    from aectorch.envs import IDS
    from aectorch.evaluate import EvaluateConfig
    from aectorch.runtime.command import usage

    root = Path(__file__).resolve().parents[2]
    readme = (root / "README.md").read_text()
    assert all(name.split("/")[-1] in readme for name in IDS), [n for n in IDS if n.split("/")[-1] not in readme]
    doc = (root / "aectorch" / "cli" / "train.py").read_text().split('"""')[1]  # (what train.py runs)
    assert "PPO by default" in doc and not re.search(r"eye movements \(natural actor-critic\)", doc)
    text = " ".join(usage(EvaluateConfig, "aectorch.evaluate").split())
    assert "greedy (argmax actions" not in text and "whose own default is mean" in text


@pytest.mark.integration
def test_a_start_killed_before_its_first_checkpoint_starts_again(tmp_path, textures):
    """Its own start record (provenance.json) without a checkpoint: a requeued job starts afresh."""
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=2"), run)
    (run / "checkpoint.pt").unlink()  # as a kill -9 before the first checkpoint leaves it
    run_experiment(_cfg(textures, "train.iterations=2", "train.resume=auto"), run)
    assert load_checkpoint(run / "checkpoint.pt")["iteration"] == 2


@pytest.mark.integration
def test_an_evaluation_written_before_the_hash_is_checked_by_its_iteration(tmp_path, textures):
    """An evaluation from an earlier aectorch (a ``checkpoint`` and an ``iteration``, no ``source``)
    left by the run that a later run in the folder replaced."""
    run = tmp_path / "run"
    run_experiment(_cfg(textures, "train.iterations=4"), run)
    (run / "tracking.json").write_text(json.dumps({"checkpoint": str(run / "checkpoint.pt"), "iteration": 2,
                                                   "tracking": {}}))
    with pytest.raises(ValueError, match=r"tracking.json was made from checkpoint.pt at iteration 2, but the run's "
                                         r"checkpoint.pt holds iteration 4"):
        Run(run).evaluation("tracking.json")
    (run / "tracking.json").write_text(json.dumps({"checkpoint": str(run / "checkpoint.pt"), "iteration": 4}))
    assert Run(run).evaluation("tracking.json")["iteration"] == 4


def test_every_figure_a_run_draws_is_one_that_overwrite_deletes():
    import re

    from aectorch.runtime.outputs import FIGURE_FILES

    source = (Path(__file__).resolve().parents[2] / "aectorch" / "runtime" / "finish.py").read_text()
    drawn = set(re.findall(r'"(\w+\.png)"', source))
    assert drawn and drawn <= set(FIGURE_FILES), drawn - set(FIGURE_FILES)


@pytest.mark.integration
def test_the_groups_a_run_started_with_are_kept_in_its_provenance_for_resumes_of_sweep_jobs(tmp_path, textures):
    """A sweep's job has no ``.hydra/`` of its start after a relaunch (Hydra rewrites it): the
    groups come from ``provenance.json``'s first session."""
    from aectorch.runtime import prepare_run
    from aectorch.runtime.config import to_container, to_experiment_config

    run = tmp_path / "run"
    node = to_container(_cfg(textures, "train.iterations=2"))
    node["perturbations"] = REARING["monocular"]
    started = {"preset": "default", "experiment": None, "plasticity": "decay", "rearing": "monocular"}
    run_experiment(to_experiment_config(node), run, groups=started)
    assert Run(run).provenance["sessions"][0]["groups"] == started
    node = to_container(_cfg(textures, "train.iterations=4", f"train.resume={run}"))
    node["perturbations"] = REARING["monocular"]  # as rearing=monocular composes it
    resume = to_experiment_config(node)
    with pytest.raises(ValueError, match=r"plasticity=floor contradicts the resumed run, started with plasticity=decay"):
        prepare_run(resume, {"train.resume", "train.iterations", "plasticity"}, groups={"plasticity": "floor"})
    prepare_run(resume, {"train.resume", "train.iterations", "rearing"}, groups={"rearing": "monocular"})
