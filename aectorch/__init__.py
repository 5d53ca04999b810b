"""aectorch: active efficient coding in PyTorch.

Batched sparse coding (OMP / MP) with learned binocular dictionaries, natural actor-critic eye
control, a Levenberg-Marquardt depth MLP and a simulated HOAP-3 head, composed by
:class:`JointLearner` into the joint learning framework of Wong et al. (2017).
"""

from aectorch import _opengl

_opengl.choose_default()  # before anything imports OpenGL (pyrender does): see aectorch/_opengl.py

from aectorch.framework import JointLearner, LearnerConfig  # noqa: E402

__all__ = ["JointLearner", "LearnerConfig"]
__version__ = "0.1.0"
