"""The paper's joint learning framework (sections 2-3), batched over B environments.

- :class:`JointLearner` (`joint.py`): the schedule of steps k1 and k2 over an
  `aectorch.sim.ActiveDepthEnv`, composing
- two :class:`CueLearner` s (`cue.py`): one per depth cue (motion parallax drives pursuit, stereo
  drives vergence), each an encoder, an actor-critic, the pending transition and the cue's
  symmetry;
- an `aectorch.depth.DepthLearner`: the depth MLP, its replay buffer of trials and fit cadence;
- :class:`LearnerConfig` (`config.py`): the hyperparameters;
- :class:`Shard` (`shard.py`): this process's slice of the batch (world size 1 without
  ``torch.distributed``).
"""

from aectorch.coding.patches import DEFAULT_SCALES
from aectorch.depth.learner import MIN_DEPTH_TRIALS
from aectorch.framework.config import DEFAULT_ACTIONS_DEG, PAPER_ACTIONS_DEG, LearnerConfig, default_control
from aectorch.framework.cue import CueLearner, CueRecord
from aectorch.framework.joint import IterationRecord, JointLearner
from aectorch.framework.shard import Shard

__all__ = ["DEFAULT_ACTIONS_DEG", "DEFAULT_SCALES", "MIN_DEPTH_TRIALS", "PAPER_ACTIONS_DEG", "CueLearner", "CueRecord",
           "IterationRecord", "JointLearner", "LearnerConfig", "Shard", "default_control"]
