"""The per-environment part of a learner's state, so a checkpoint holds the whole batch.

A learner's state is the same on every process of a run (`Shard`), except what belongs to each
environment: a cue's pending transition (`CueLearner.previous`) and an agent's rollout collected
so far (`aectorch.control.PPO`). A module that keeps such state in its extra state names those
entries in its class attribute ``BATCH_STATE``; each holds tensors of the environments, batch
first (``[B, ...]``, or ``[G * B, ...]``: G blocks of B rows, as a symmetric cue's transitions
followed by their transforms), inside tuples, lists and dicts, and other values that every
process has alike (``None``, a flag).

:func:`gather_rows` joins every process's rows into the whole batch's state (in rank order), and
:func:`take_rows` takes a process's rows of it back, so a checkpoint written by N processes can be
resumed by M of them with the same whole batch (`aectorch.runtime.TrainingRun`).

    >>> import torch
    >>> from aectorch.framework.batch_state import gather_rows, take_rows
    >>> class Pending(torch.nn.Module):
    ...     BATCH_STATE = ("previous",)
    ...     def get_extra_state(self): return {"previous": self.previous}
    ...     def set_extra_state(self, state): self.previous = state["previous"]
    >>> module = Pending()
    >>> module.previous = (torch.zeros(2, 3), torch.tensor([0, 1]))
    >>> state = module.state_dict()
    >>> whole = gather_rows(module, state, lambda part: [part, part], 2)  # two processes, alike
    >>> whole["_extra_state"]["previous"][0].shape
    torch.Size([4, 3])
    >>> take_rows(module, whole, 2, 4, 4)["_extra_state"]["previous"][1]
    tensor([0, 1])
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import nn

__all__ = ["batch_keys", "gather_rows", "take_rows"]

_EXTRA = "_extra_state"  # torch.nn.Module's key of a module's extra state in its state dict


def batch_keys(module: nn.Module) -> dict[str, tuple[str, ...]]:
    """The state-dict key of each extra state that holds per-environment entries, and their names."""
    keys = {}
    for name, sub in module.named_modules():
        entries = tuple(getattr(type(sub), "BATCH_STATE", ()))
        if entries:
            keys[f"{name}.{_EXTRA}" if name else _EXTRA] = entries
    return keys


def _blocks(value: torch.Tensor, batch: int, path: str) -> int:
    if value.shape[0] % batch:
        raise ValueError(f"{path}: {value.shape[0]} rows are not blocks of the {batch} environments")
    return value.shape[0] // batch


def _join(parts: list, batches: list[int], path: str):
    first = parts[0]
    if isinstance(first, torch.Tensor):
        if first.ndim == 0:
            return first
        blocks = {_blocks(p, b, path) for p, b in zip(parts, batches)}
        if len(blocks) > 1:
            raise ValueError(f"{path}: the processes hold different numbers of blocks of rows ({sorted(blocks)})")
        (g,) = blocks
        return torch.cat([p[k * b:(k + 1) * b] for k in range(g) for p, b in zip(parts, batches)])
    if isinstance(first, (tuple, list)):
        if any(len(p) != len(first) for p in parts):
            raise ValueError(f"{path}: the processes hold different numbers of entries ({[len(p) for p in parts]})")
        joined = [_join([p[i] for p in parts], batches, f"{path}[{i}]") for i in range(len(first))]
        return type(first)(joined) if isinstance(first, tuple) else joined
    if isinstance(first, dict):
        return {key: _join([p[key] for p in parts], batches, f"{path}.{key}") for key in first}
    if any(p != first for p in parts):
        raise ValueError(f"{path}: the processes differ ({parts}) where they must agree")
    return first


def _rows(value, start: int, stop: int, total: int, path: str):
    if isinstance(value, torch.Tensor):
        if value.ndim == 0:
            return value
        return torch.cat([value[k * total + start:k * total + stop] for k in range(_blocks(value, total, path))])
    if isinstance(value, (tuple, list)):
        rows = [_rows(v, start, stop, total, f"{path}[{i}]") for i, v in enumerate(value)]
        return type(value)(rows) if isinstance(value, tuple) else rows
    if isinstance(value, dict):
        return {key: _rows(v, start, stop, total, f"{path}.{key}") for key, v in value.items()}
    return value


def _replace(module: nn.Module, state: dict, entries: Callable[[str, str], object]) -> dict:
    out = dict(state)
    for key, names in batch_keys(module).items():
        if key in state:
            extra = dict(state[key])
            for name in names:
                extra[name] = entries(key, name)
            out[key] = extra
    return out


def gather_rows(module: nn.Module, state: dict, gather_objects: Callable[[object], list], batch: int) -> dict:
    """``state`` (this process's ``module.state_dict()``, of its ``batch`` environments) with its
    per-environment entries joined over all processes, in rank order. ``gather_objects(obj)``:
    every process's ``obj`` in rank order (`Shard.gather_objects`; one process: ``[obj]``)."""
    mine = {key: {name: state[key][name] for name in names} for key, names in batch_keys(module).items() if key in state}
    everyone = gather_objects((batch, mine))
    if len(everyone) == 1:
        return state
    batches = [b for b, _ in everyone]
    return _replace(module, state, lambda key, name: _join([part[key][name] for _, part in everyone], batches,
                                                           f"{key}.{name}"))


def take_rows(module: nn.Module, state: dict, start: int, stop: int, total: int) -> dict:
    """``state`` (of a whole batch of ``total`` environments, as :func:`gather_rows` makes it) with
    its per-environment entries cut to the environments ``start .. stop - 1``."""
    if not 0 <= start < stop <= total:
        raise ValueError(f"rows {start}..{stop - 1} are not within the {total} environments of the state")
    return _replace(module, state, lambda key, name: _rows(state[key][name], start, stop, total, f"{key}.{name}"))
