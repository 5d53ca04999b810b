"""Env-iterations per second of ``python train.py`` itself: ``(long - short) x B / (wall(long) -
wall(short))`` over fresh processes, so start-up cancels (at the tiny size: one process of one
iteration). ``AECTORCH_BENCH_BASELINE=<commit>`` runs that commit's ``train.py`` (a git worktree,
this Python) beside today's in every round; ``isa=avx2`` runs both under `harness.AVX2`.
"""

import os
import statistics

import PIL.Image
import pytest

from aectorch.sim import TextureBank
from benchmarks import harness

pytestmark = pytest.mark.integration  # python train.py processes

SCALES = "[wide,coarse,fine]"
VARIANTS = {
    "defaults": [],
    # the earlier defaults' learner, which the speed targets were set against, on today's code
    "NAC, three scales": ["learner.cues.parallax.agent=nac", "learner.cues.stereo.agent=nac",
                          f"learner.cues.parallax.scales={SCALES}", f"learner.cues.stereo.scales={SCALES}"],
}


@pytest.mark.parametrize("isa", harness.size(["native"], ["native", "avx2"]))
@pytest.mark.parametrize("variant", harness.size(["defaults"], list(VARIANTS)))
def test_train_rate(benchmark, variant, isa, tmp_path):
    if not harness.FULL:  # four small textures in place of the 100 default ones, which take seconds to make
        for i, image in enumerate(TextureBank.procedural(4, size=(96, 96), seed=0).textures):
            PIL.Image.fromarray((image * 255).byte().numpy()).save(tmp_path / f"{i}.png")
    (short, long), batch = harness.size((0, 1), (20, 520)), harness.size(2, 32)
    environment = harness.AVX2 if isa == "avx2" else {}
    baseline = os.environ.get("AECTORCH_BENCH_BASELINE")
    commits = {"today": harness.ROOT, **({baseline: harness.worktree(baseline)} if baseline else {})}
    workloads = {}
    for commit, cwd in commits.items():
        for n in (short, long) if short else (long,):
            overrides = [f"train.iterations={n}", f"env.num_envs={batch}", *VARIANTS[variant],
                         *harness.size([f"env.textures={tmp_path}"], [])]
            workloads[(commit, n)] = lambda o=overrides, c=cwd: harness.train_py(o, c, environment)
        if harness.FULL:  # once untimed: builds the native kernels and warms the caches
            harness.train_py(["train.iterations=1", *VARIANTS[variant]], cwd, environment)
    times = benchmark.pedantic(harness.interleaved, args=(workloads,), kwargs=dict(
        rounds=harness.size(1, 5), warmup=0))
    rows = []
    for commit in commits:
        rates = [(long - short) * batch / (t - (times[(commit, short)][i] if short else 0.0))
                 for i, t in enumerate(times[(commit, long)])]
        rows.append({"variant": f"{commit}, {variant}, {isa}", "commit": commit, "learner": variant, "isa": isa,
                     "B": batch, "short": short, "long": long, "rates": rates,
                     "env_iterations_per_s": statistics.median(rates)})
    if baseline:
        rows[0]["per_round_ratio_to_baseline"] = [a / b for a, b in zip(rows[0]["rates"], rows[1]["rates"])]
    assert all(rate > 0 for row in rows for rate in row["rates"])
    harness.record("train_rate", rows, benchmark)
