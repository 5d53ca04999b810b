"""Dataclass configs used by Hydra (`train.py`).

Each component has one dataclass whose docstring explains every field and whose
``__post_init__`` rejects impossible values with a message naming the field. Hydra
composes the command line onto these dataclasses (type checks), and
``OmegaConf.to_object`` then builds the dataclass, which runs the value checks.

Until the joint learning framework (simulator, eye control, depth) lands, the only
experiment is the binocular sparse-coding demonstration of `aectorch.demo`, whose
config `DemoConfig` is registered with Hydra's ConfigStore under the name ``"train"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["DemoConfig", "register_configs"]

_ALGORITHMS = ("mp", "omp")


def _require_int(owner: str, name: str, value: object, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{owner}.{name} must be an int >= {minimum}, got {value!r}")


@dataclass
class DemoConfig:
    """Binocular sparse-coding demonstration: learn coarse and fine dictionaries from stereo pairs.

    Every step draws ``batch_size`` new pink-noise textures and a random horizontal disparity per
    texture, codes the stereo pairs with a `BinocularEncoder`, and takes one dictionary-learning
    step on minus the mean reconstruction error (the AEC reward).

    Attributes:
        steps: number of dictionary-learning steps (>= 1).
        batch_size: stereo pairs per step, B (>= 1); the step is the mean of the B updates.
        lr: dictionary learning rate (finite, >= 0; 0 trains nothing, a baseline).
        max_disparity_px: disparities are drawn uniformly from the integers in
            [-max_disparity_px, +max_disparity_px], in pixels of the 320 x 240 image (>= 0).
            The coarse scale sees them divided by 8, the fine scale divided by 2.
        algorithm: sparse coder, ``"mp"`` (the paper's matching pursuit) or ``"omp"``.
        log_every: TensorBoard logging and progress-bar refresh interval in steps (>= 1).
        seed: seeds the initial atoms, the textures and the disparities (>= 0).
        device: torch device string for the encoder and the images (``"cpu"``, ``"cuda"``, ...).
        threads: CPU threads for torch (``torch.set_num_threads``, >= 1).
    """

    steps: int = 450
    batch_size: int = 16
    lr: float = 0.05
    max_disparity_px: int = 8
    algorithm: str = "mp"
    log_every: int = 10
    seed: int = 0
    device: str = "cpu"
    threads: int = 1

    def __post_init__(self) -> None:
        owner = type(self).__name__
        _require_int(owner, "steps", self.steps, 1)
        _require_int(owner, "batch_size", self.batch_size, 1)
        _require_int(owner, "max_disparity_px", self.max_disparity_px, 0)
        _require_int(owner, "log_every", self.log_every, 1)
        _require_int(owner, "seed", self.seed, 0)
        _require_int(owner, "threads", self.threads, 1)
        if isinstance(self.lr, bool) or not isinstance(self.lr, (int, float)) or not (
            math.isfinite(self.lr) and self.lr >= 0
        ):
            raise ValueError(f"{owner}.lr must be a finite float >= 0, got {self.lr!r}")
        if self.algorithm not in _ALGORITHMS:
            raise ValueError(
                f"{owner}.algorithm must be one of {', '.join(map(repr, _ALGORITHMS))}, "
                f"got {self.algorithm!r}"
            )
        try:
            torch.device(self.device)
        except (RuntimeError, TypeError) as err:
            raise ValueError(
                f"{owner}.device must be a torch device string such as 'cpu' or 'cuda', "
                f"got {self.device!r}"
            ) from err


def register_configs() -> None:
    """Register the structured configs with Hydra's ConfigStore (``config_name="train"``)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="train", node=DemoConfig)
