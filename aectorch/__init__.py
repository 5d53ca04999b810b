"""aectorch: active efficient coding in PyTorch.

Batched sparse coding (OMP / MP), learned binocular dictionaries, and (in later
modules) natural actor-critic eye control and depth learning for a simulated
HOAP-3 head.
"""

__version__ = "0.1.0"
