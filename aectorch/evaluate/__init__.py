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

The library (`summary.py`, `trials.py`, `evaluation.py`) needs only the framework and the
simulation; the command line, on a checkpoint written by ``train.py``, is `__main__.py`::

    python -m aectorch.evaluate checkpoint=outputs/run/checkpoint.pt textures=photos/ out=eval.json
"""

from aectorch.evaluate.evaluation import evaluate
from aectorch.evaluate.summary import BEYOND_DEG, WITHIN_DEG, fractions, movements, per_trial_rows, summarise
from aectorch.evaluate.trials import EVAL_BATCH_SIZE, frozen_iterations, run_trials

__all__ = ["BEYOND_DEG", "EVAL_BATCH_SIZE", "WITHIN_DEG", "evaluate", "fractions", "frozen_iterations", "movements",
           "per_trial_rows", "run_trials", "summarise"]
