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
        `NaturalActorCritic.update`): ``None`` for a single process, whose means need no sum over
        processes (`ProcessGroupShard`: its all-reduce :meth:`sum`)."""
        return None

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
        """The whole batch's iteration record (`aectorch.framework.IterationRecord`): this
        process's, since it holds the whole batch."""
        return record

    def barrier(self) -> None:
        """Wait for every rank (nothing to wait for in one process)."""
