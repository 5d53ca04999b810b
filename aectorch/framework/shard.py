"""``Shard``: this process's slice of the batch of environments, and the collectives learning needs.

A single process is a shard of world size 1 (:meth:`Shard.single`): its collectives are the
identity, so the learner runs one code path with or without ``torch.distributed``.
`aectorch.runtime.distributed.ProcessGroupShard` overrides the collectives with torchrun's
process group.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import torch

__all__ = ["Shard"]


@dataclass(frozen=True)
class Shard:
    """This process's slice ``[start, stop)`` of a batch of ``total`` environments.

    Attributes:
        rank, world_size: of the process group (0 and 1 for a single process).
        start, stop, total: the environments of this rank within the whole batch.
    """

    rank: int
    world_size: int
    start: int
    stop: int
    total: int

    def __post_init__(self) -> None:
        if self.world_size > 1 and type(self) is Shard:
            raise ValueError("Shard's collectives are a single process's; a shard of world_size > 1 is "
                             "aectorch.runtime.distributed.ProcessGroupShard (distributed.setup makes it)")

    @classmethod
    def single(cls, num_envs: int = 0) -> "Shard":
        """One process holding the whole batch of ``num_envs`` environments (0: of any size; a
        single process's collectives do not depend on it)."""
        return cls(rank=0, world_size=1, start=0, stop=num_envs, total=num_envs)

    def whole_batch(self, local: int) -> int:
        """The size of the whole batch when this process steps ``local`` environments."""
        return local

    @property
    def is_main(self) -> bool:
        """Rank 0 writes the run folder."""
        return self.rank == 0

    @property
    def reduce(self) -> Optional[Callable[[torch.Tensor], torch.Tensor]]:
        """The ``reduce=`` argument of the learning steps (`SparseDictionary.gradient`,
        `NaturalActorCritic.update`): :meth:`sum`, or ``None`` for a single process, whose
        means need no sum over processes."""
        return self.sum if self.world_size > 1 else None

    def sum(self, tensor: torch.Tensor) -> torch.Tensor:
        """The sum of ``tensor`` over all ranks (a new tensor; the input is not changed)."""
        return tensor.detach().clone()

    def gather(self, tensor: torch.Tensor) -> torch.Tensor:
        """Every rank's ``tensor`` ``[n, ...]`` concatenated in rank order, ``[world_size * n, ...]``."""
        return tensor

    def gather_objects(self, obj) -> list:
        """Every rank's picklable ``obj``, in rank order, on every rank."""
        return [obj]

    def draw(self, draws: torch.Tensor) -> torch.Tensor:
        """This rank's rows of ``draws`` (random numbers drawn for the whole batch: all of them)."""
        return draws

    def gather_record(self, record):
        """A (nested) NamedTuple of per-environment tensors ``[B, ...]`` (e.g.
        `aectorch.framework.IterationRecord`) with every tensor gathered along the batch; fields
        named ``atom_counts`` (counts over the batch) are summed instead. Other values are kept."""
        if self.world_size == 1:
            return record

        def one(name, value):
            if isinstance(value, tuple) and hasattr(value, "_fields"):
                return type(value)(*(one(field, getattr(value, field)) for field in value._fields))
            if isinstance(value, torch.Tensor) and value.ndim > 0:
                return self.sum(value) if name == "atom_counts" else self.gather(value)
            return value

        return one("record", record)

    def barrier(self) -> None:
        """Wait for every rank (nothing to wait for in one process)."""
