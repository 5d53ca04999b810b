"""Hydra's ConfigStore for `train.py`: the schema as ``train`` and the groups of named settings
(`aectorch.runtime.presets`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from aectorch.runtime.config import ExperimentConfig
from aectorch.runtime.presets import GROUPS

__all__ = ["register_configs"]


def _nested(dotted: dict[str, Any]) -> dict:
    out: dict = {}
    for key, value in dotted.items():
        *parents, leaf = key.split(".")
        node = out
        for parent in parents:
            node = node.setdefault(parent, {})
        node[leaf] = value
    return out


@dataclass
class _TrainNode(ExperimentConfig):
    # Hydra's defaults list: the groups apply after the schema's own values.
    defaults: list[Any] = field(default_factory=lambda: ["_self_", {"preset": "default"}, {"guard": "default"},
                                                         {"plasticity": "decay"}, {"rearing": None}])


def register_configs() -> None:
    """Register the configs with Hydra's ConfigStore: ``train`` and the groups ``preset``
    (``default``, ``paper``), ``experiment`` (``roll_perturbation``, ``accommodation``, ``slip``),
    ``plasticity`` (:data:`PLASTICITY`), ``rearing`` (:data:`REARING`), all from
    `aectorch.runtime.presets.GROUPS`, and ``guard`` (``default``: Hydra's
    callback `aectorch.runtime.launch.RunFolderGuard`, which refuses a new run over an existing
    one before Hydra writes into its folder)."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="train", node=_TrainNode)
    store.store(group="guard", name="default", package="_global_",
                node={"hydra": {"callbacks": {"run_folder_guard": {"_target_": "aectorch.runtime.launch.RunFolderGuard"}}}})
    for group, options in GROUPS.items():
        for name, values in options.items():
            store.store(group=group, name=name, node=_nested(values), package="_global_")
