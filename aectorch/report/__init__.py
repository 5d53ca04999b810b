"""The generic tables and plots of finished runs: ``python -m aectorch.report <command> ...``.

Every command reads run folders through `aectorch.runs` and prints markdown (``--help`` on each);
the last four compute on checkpoints, images or the head's geometry. A study's own tables live
beside it, in ``experiments/<study>/`` (its ``report.py`` runs on `aectorch.report.command`):

- ``table RUN... [--eval FILE]``: one row per run (training time, the final training window, an
  evaluation's MAEs, medians, the fractions on target and failed, the near trials), mean +- sd;
- ``compare NAME=RUN,RUN... [--evals SET=FILE...] [--json OUT] [--plot PNG]``: groups of runs
  side by side (mean and sd over each group's runs), and their learning curves;
- ``curves RUN... [--names] [--keys] [--from] [--to] [--every] [--plot PNG]``: ``metrics.jsonl``
  of runs side by side, iteration by iteration, with their perturbation events;
- ``band RUN... --eval FILE --low M --high M``: the trials of a band of distances, mean over runs;
- ``trials A.json B.json [--tolerance DEG] [--json OUT]``: two evaluations of the same trials;
- ``ablation LABEL=RUN[:SUFFIX]... [--json OUT]``: each run's ``final_textures`` and
  ``final_choose`` evaluations in one row;
- ``code LABEL=RUN,RUN...|RUN... [--cue CUE] [--plot PNG]``: the learned code's read-outs of
  groups of runs beside their random start;
- ``matcher [--textures DIR] [--depths M...] [--free] [--json OUT]``: the classical matcher
  through the same trials (it computes);
- ``offsets LABEL=CHECKPOINT|LABEL=JSON... [--textures DIR] [--json OUT] [--plot PNG]``: the offset
  diagnostic, computed on checkpoints or read from measurements it wrote;
- ``depth-readout CHECKPOINT [--photos DIR] [--calibration N...]``: read-outs of depth from the
  same eye movements; ``depth-tolerance``: the eye precision a depth error needs (geometry only).

The thresholds (on target within ``WITHIN_DEG``, failed beyond ``BEYOND_DEG``) are the
evaluation's, `aectorch.evaluation.summary`.
"""

from aectorch.report.code import code_table
from aectorch.report.compare import compare_groups, compare_trials, curves_table, group_table
from aectorch.report.tables import ablation_table, band, band_line, results_table

__all__ = ["ablation_table", "band", "band_line", "code_table", "compare_groups", "compare_trials", "curves_table",
           "group_table", "results_table"]
