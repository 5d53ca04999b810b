"""The long-training study's commands (experiments/long_training) at a tiny size: a run trained in
two stages, each evaluated, the same command again doing nothing, and the curves' table and figure."""

from __future__ import annotations

import json

import pytest

from tests.end_to_end import EXPERIMENTS, TINY, noise_images, run_script

STUDY = EXPERIMENTS / "long_training"


@pytest.mark.integration
def test_stages_train_evaluate_each_stage_and_curves_read_them(tmp_path):
    photos = noise_images(tmp_path / "photos", 2, 48, seed=3, prefix="p")
    run = tmp_path / "runs" / "tiny_s0"
    command = [str(STUDY / "stages.py"), str(run), "--seed", "0", "--stages", "4,8", "--eval", f"choose={photos}",
               "--depths", "1.0", *TINY]
    done = run_script(*command)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "tiny_s0: stage 8 done" in done.stdout
    for stage in (4, 8):
        assert (run / f"ckpt_{stage}.pt").is_file()
        result = json.loads((run / f"choose_{stage}.json").read_text())
        assert result["iteration"] == stage and result["trials"] == 2
    # the same command again: every stage is there, nothing is trained or evaluated again
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    again = run_script(*command)
    assert again.returncode == 0 and {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before
    figure, numbers = tmp_path / "curves.png", tmp_path / "curves.json"
    shown = run_script(str(STUDY / "curves.py"), f"a={run}", f"b={run},{run}", "--sets", "choose", "--plot", str(figure),
                  "--json", str(numbers))
    assert shown.returncode == 0, shown.stderr
    rows = [line for line in shown.stdout.splitlines() if line.startswith("| a |") or line.startswith("| b |")]
    assert len(rows) == 4 and figure.stat().st_size > 0
    curves = json.loads(numbers.read_text())
    first = json.loads((run / "choose_4.json").read_text())
    assert curves["choose"]["b"]["4"]["vergence"]["mean"] == pytest.approx(first["vergence_mae_deg"])
    assert curves["choose"]["b"]["4"]["vergence"]["sd"] == 0.0


@pytest.mark.integration
def test_stages_refuse_bad_arguments_before_any_work(tmp_path):
    for args, message in ((["--stages", "8,4"], "positive and increasing"),
                          (["--stages", "4", "--eval", "choose"], "NAME=FOLDER"),
                          (["--stages", "4", "--eval", f"choose={tmp_path / 'none'}"], "no such folder"),
                          (["--stages", "4", "seed"], "key=value")):
        done = run_script(str(STUDY / "stages.py"), str(tmp_path / "run"), *args)
        assert done.returncode == 2 and message in done.stderr, done.stderr
        assert not (tmp_path / "run").exists()


def test_calibration_compares_the_adapted_run_with_the_scratch_run_from_the_window_peak(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("calibration", STUDY / "calibration.py")
    calibration = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(calibration)

    def write(run, rows):
        run.mkdir()
        (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))

    def row(iteration, vergence, depth=0.05, pursuit=0.1):
        return {"iteration": iteration, "vergence_recent_deg": vergence, "depth_recent_m": depth,
                "pursuit_recent_deg": pursuit}

    # before the change the window holds no key (no event yet); just after it, the old fixations
    adapted = [{"iteration": 90}, row(110, 0.10), row(120, 0.40), row(130, 0.30), row(140, 0.22), row(150, 0.21)]
    write(tmp_path / "a", adapted)
    write(tmp_path / "s", [row(10, 0.5), row(50, 0.2, depth=0.1)])
    out = calibration.pair(tmp_path / "a", tmp_path / "s", change=100)
    assert out["vergence"]["adapted"] == 0.21 and out["vergence"]["scratch"] == 0.2
    assert out["vergence"]["ratio"] == pytest.approx(1.05)
    assert out["vergence"]["iterations_to_1.2x"] == 40  # 0.22 <= 0.24 at 140, past the peak at 120 (not 110)
    assert out["depth"]["ratio"] == pytest.approx(0.5) and out["pursuit"]["first_after_change"] == 0.1
    assert "relearned_after" not in out
    # --cue: when a cue closed before the change learns again (its TD error logged again)
    adapted[3]["stereo/td_error"] = 0.02
    (tmp_path / "a" / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in adapted))
    assert calibration.pair(tmp_path / "a", tmp_path / "s", change=100, cue="stereo")["relearned_after"] == 30
    assert calibration.reward_fall([{"iteration": 90, "stereo/reward": -1.0}, {"iteration": 110, "stereo/reward": -1.3},
                                    {"iteration": 300, "stereo/reward": -5.0}], 100, "stereo") == pytest.approx(0.3)
    assert calibration.pair(tmp_path / "a", tmp_path / "s", change=100, cue="parallax")["relearned_after"] is None
    # a run without a short window (no event) is refused, naming the file and the key
    write(tmp_path / "plain", [{"iteration": 10, "vergence_mae_deg": 0.1}])
    with pytest.raises(SystemExit, match="vergence_recent_deg"):
        calibration.pair(tmp_path / "plain", tmp_path / "s", change=100)
    # --update keeps the other labels of the file; without it the file holds the pairs given
    table = tmp_path / "cal.json"
    table.write_text(json.dumps({"roll": {"kept": True}, "tilt": {"old": True}}))
    calibration.main(["tilt=" + f"{tmp_path / 'a'}:{tmp_path / 's'}", "--change", "100", "--json", str(table), "--update"])
    stored = json.loads(table.read_text())
    assert stored["roll"] == {"kept": True} and stored["tilt"]["vergence"]["adapted"] == 0.21
    calibration.main(["tilt=" + f"{tmp_path / 'a'}:{tmp_path / 's'}", "--change", "100", "--json", str(table)])
    assert list(json.loads(table.read_text())) == ["tilt"]
    calibration.main(["tilt, seed 0=" + f"{tmp_path / 'a'}:{tmp_path / 's'}", "--change", "100",
                      "--plot", str(tmp_path / "cal.png")])
    assert (tmp_path / "cal.png").stat().st_size > 1000
    with pytest.raises(SystemExit):
        calibration.main(["tilt=" + f"{tmp_path / 'a'}:{tmp_path / 's'}", "--change", "100", "--update"])


def test_swap_takes_one_cue_s_part_from_the_donor_and_nothing_else(tmp_path):
    import importlib.util

    import torch

    spec = importlib.util.spec_from_file_location("swap", STUDY / "swap.py")
    swap = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(swap)

    def state(value):
        return {"iteration": int(value), "learner": {
            f"cues.{cue}.{part}.w": torch.full((2, 3), value + i) for i, (cue, part) in
            enumerate((c, p) for c in ("parallax", "stereo") for p in ("agent", "encoder"))}}

    base, donor = state(0.0), state(10.0)
    out, count = swap.swap(base, donor, "parallax", "agent")
    assert count == 1 and out["iteration"] == 0
    assert torch.equal(out["learner"]["cues.parallax.agent.w"], donor["learner"]["cues.parallax.agent.w"])
    for key in ("cues.parallax.encoder.w", "cues.stereo.agent.w", "cues.stereo.encoder.w"):
        assert torch.equal(out["learner"][key], base["learner"][key]), key
    with pytest.raises(ValueError, match="the cues: parallax, stereo"):
        swap.swap(base, donor, "parallx", "agent")
    donor["learner"]["cues.stereo.encoder.w"] = torch.zeros(3, 3)
    with pytest.raises(ValueError, match="shape"):
        swap.swap(base, donor, "stereo", "encoder")
    torch.save(base, tmp_path / "b.pt"), torch.save(state(10.0), tmp_path / "d.pt")
    swap.main([str(tmp_path / "b.pt"), str(tmp_path / "d.pt"), str(tmp_path / "o.pt"), "--cue", "stereo", "--part",
               "encoder"])
    written = torch.load(tmp_path / "o.pt")
    assert float(written["learner"]["cues.stereo.encoder.w"][0, 0]) == 13.0
    with pytest.raises(SystemExit):  # never over an existing file
        swap.main([str(tmp_path / "b.pt"), str(tmp_path / "d.pt"), str(tmp_path / "o.pt"), "--cue", "stereo",
                   "--part", "encoder"])
