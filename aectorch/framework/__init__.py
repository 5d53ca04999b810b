"""The paper's joint learning framework (sections 2-3), batched over B environments.

- :class:`JointLearner` (`joint.py`): the schedule of the environment's cues (steps k1 and k2)
  over an `aectorch.sim.ActiveDepthEnv`, composing
- one :class:`CueLearner` per cue (`cue.py`; by default motion parallax drives pursuit and stereo
  drives vergence), each an encoder, an agent, the pending transition and the cue's symmetry,
  built from the cue's :class:`CueConfig`;
- an `aectorch.depth.DepthLearner`: the depth MLP, its replay buffer of trials and fit cadence;
- :class:`LearnerConfig` (`config.py`): the hyperparameters, with one `CueConfig` per cue;
- :class:`Shard` (`shard.py`): this process's slice of the batch (world size 1 without
  ``torch.distributed``).
"""

from aectorch.coding.patches import DEFAULT_SCALES
from aectorch.depth.learner import MIN_DEPTH_TRIALS
from aectorch.framework.config import DEFAULT_ACTIONS_DEG, PAPER_ACTIONS_DEG, CueConfig, LearnerConfig, default_cues
from aectorch.framework.cue import CueLearner, CueRecord
from aectorch.framework.joint import IterationRecord, JointLearner
from aectorch.framework.shard import Shard

__all__ = ["DEFAULT_ACTIONS_DEG", "DEFAULT_SCALES", "MIN_DEPTH_TRIALS", "PAPER_ACTIONS_DEG", "CueConfig", "CueLearner",
           "CueRecord", "IterationRecord", "JointLearner", "LearnerConfig", "Shard", "default_cues"]
