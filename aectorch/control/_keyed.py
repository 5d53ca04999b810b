"""`Keyed`: a network as a TensorDict module for TorchRL's losses (imported with TorchRL only:
`aectorch.control.ppo` needs it when a PPO agent is built, and tensordict is an optional extra)."""

from __future__ import annotations

from tensordict.nn import TensorDictModuleBase
from torch import nn

__all__ = ["Keyed"]


class Keyed(TensorDictModuleBase):
    """``tensordict[out_key] = network(tensordict[in_key])``: what ``TensorDictModule(network,
    [in_key], [out_key])`` (and TorchRL's `ValueOperator`) computes, the same tensor, without their
    per-call machinery (argument dispatch, and the output's `TensorDict.from_any`, which looks up
    pandas on the import path each time).

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> value = Keyed(torch.nn.Linear(3, 1), "observation", "state_value")
        >>> out = value(TensorDict({"observation": torch.ones(2, 3)}, batch_size=[2]))
        >>> out["state_value"].shape, value.in_keys, value.out_keys
        (torch.Size([2, 1]), ['observation'], ['state_value'])
    """

    def __init__(self, network: nn.Module, in_key: str, out_key: str) -> None:
        super().__init__()
        self.network = network
        self.in_keys, self.out_keys = [in_key], [out_key]

    def forward(self, tensordict):
        tensordict.set(self.out_keys[0], self.network(tensordict.get(self.in_keys[0])))
        return tensordict
