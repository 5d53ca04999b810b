"""Evaluation of a trained :class:`~aectorch.framework.JointLearner`, separate from training.

Learning is frozen and the policies are greedy (``policy="sampled"`` draws the actions as in
training instead, for analysis). Two tests:

- **the paper's test**: every texture x distance runs one full trial (a leftward and a rightward
  fixation of ``h`` iterations) from the standard start state; the pursuit and vergence errors
  at the last iteration of each fixation (eq. 9) and the depth MLP's error on the trial's ``q``
  are collected (:func:`run_trials` gives them as tensors);
- **the earlier models' vergence test**: the left eye is put at its optimal pan and the right
  eye at a random vergence offset (uniform in ``+-offset_deg``), then ``steps`` greedy
  iterations run; the vergence error at the last step is summarised as RMSE, median and 4 x IQR
  in degrees and in pixels (at the camera's degrees per pixel).

Each fixation's last 5 iterations' mean errors are reported beside its final state's (``last5``):
a fixation that ends in a limit cycle of one small action is a coin toss at its last iteration.

:func:`offset_sweep` is a diagnostic: a cue's coding reward and greedy increment against the
offset of its eye movement from the optimum (where the code stops telling offsets apart, and
whether the policy stops at the target). :func:`adaptation` reads a perturbed run's recovery off
its metrics (`adaptation.py`). :func:`depth_readouts` compares read-outs of the same trials'
eye movements with the head's exact geometry, :func:`depth_tolerance` the eye error a depth error
needs (`depth_readout.py`). `aectorch.baselines.Matcher`, a classical
cross-correlation matcher, runs through the same trials as the accuracy anchor.

Each trial also records what its eyes saw at its start (`views.py`: the contrast and the energy at
each of the coder's scales), so that a failed trial can be explained by its view.

The library (`summary.py`, `trials.py`, `evaluation.py`, `views.py`) needs only the framework and the
simulation; the command line, on a checkpoint written by ``train.py``, is `__main__.py`::

    python -m aectorch.evaluate checkpoint=outputs/run/checkpoint.pt textures=photos/ out=eval.json
"""

from aectorch.evaluation.adaptation import adaptation, recovery_of
from aectorch.evaluation.depth_readout import depth_readouts, depth_tolerance
from aectorch.evaluation.evaluation import evaluate
from aectorch.evaluation.offsets import capture_range, limit_cycle, offset_summary, offset_sweep
from aectorch.evaluation.summary import (
    BEYOND_DEG, LAST_ITERATIONS, WITHIN_DEG, fractions, movements, per_trial_rows, summarise,
)
from aectorch.evaluation.trials import EVAL_BATCH_SIZE, frozen_iterations, run_trials
from aectorch.evaluation.views import view_statistics

__all__ = ["BEYOND_DEG", "EVAL_BATCH_SIZE", "LAST_ITERATIONS", "WITHIN_DEG", "adaptation", "depth_readouts",
           "capture_range", "depth_tolerance", "evaluate", "fractions", "frozen_iterations", "limit_cycle", "movements", "offset_summary", "offset_sweep", "per_trial_rows",
           "recovery_of", "run_trials", "summarise", "view_statistics"]
