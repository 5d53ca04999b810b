"""Training across processes and machines with ``torch.distributed`` (``torchrun``; gloo or nccl).

Every process (rank) runs its own ``env.num_envs`` environments; together they are one batch of
``world_size * num_envs`` environments, and rank r holds the environments
``r * num_envs .. (r + 1) * num_envs - 1`` of it. A `Shard` describes that slice and carries the
three collectives the learning needs:

- `Shard.sum`, an all-reduce: the dictionary gradients (`SparseDictionary.gradient`), the
  actor-critic steps and feature statistics (`NaturalActorCritic.update`) are means over the whole
  batch, so every rank applies the same update and the learners stay identical;
- `Shard.gather`, an all-gather along the batch: the finished trials that train the depth MLP
  (every rank fits the same data, in the same global order, to the same weights), and the
  iteration records that the metrics and the watchdog read;
- `Shard.draw`: random numbers for the whole batch from the shared seed, of which each rank
  keeps its rows. The environments' textures, distances and start states and the actions'
  sampling draw this way, so two processes with B environments each make the same run as one
  process with 2B environments, up to the summation order of the reductions
  (``tests/runtime/test_distributed.py``).

`setup()` reads torchrun's environment (``RANK``, ``WORLD_SIZE``, ...) and initialises the process
group: gloo for CPU, nccl for CUDA. Without torchrun it returns a shard of world size 1
(`aectorch.framework.Shard.single`), whose collectives are the identity.
See ``docs/scaling.md`` for multi-node and Slurm use.
"""

from __future__ import annotations

import os
import torch

from aectorch.framework.shard import Shard

__all__ = ["ProcessGroupShard", "setup", "teardown", "world_from_env"]

_owned: list[bool] = []  # non-empty while a process group made by `setup` is alive


def world_from_env() -> tuple[int, int, int]:
    """``(rank, world_size, local_rank)`` from torchrun's environment (``(0, 1, 0)`` without it)."""
    return (int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1)),
            int(os.environ.get("LOCAL_RANK", 0)))


class ProcessGroupShard(Shard):
    """A `Shard` whose collectives run over torchrun's process group (gloo or nccl)."""

    @property
    def reduce(self):
        return self.sum

    def gather_record(self, record):
        """A (nested) NamedTuple or dict of per-environment tensors ``[B, ...]`` (e.g.
        `aectorch.framework.IterationRecord`) with every tensor gathered along the batch; fields
        named ``atom_counts`` (counts over the batch) are summed instead. Other values are kept."""

        def one(name, value):
            if isinstance(value, dict):
                return {key: one(key, item) for key, item in value.items()}
            if isinstance(value, tuple) and hasattr(value, "_fields"):
                return type(value)(*(one(field, getattr(value, field)) for field in value._fields))
            if isinstance(value, torch.Tensor) and value.ndim > 0:
                return self.sum(value) if name == "atom_counts" else self.gather(value)
            return value

        return one("record", record)

    def whole_batch(self, local: int) -> int:
        # This process's slice of the run's batch; environments of another size (an evaluation on
        # rank 0) are a batch of their own.
        return self.total if local == self.stop - self.start else local

    def draw(self, draws: torch.Tensor) -> torch.Tensor:
        """This rank's rows of ``draws`` ``[total, ...]`` (random numbers drawn for the whole batch)."""
        return draws[self.start : self.stop] if draws.shape[0] == self.total else draws

    def sum(self, tensor: torch.Tensor) -> torch.Tensor:
        import torch.distributed as dist

        out = tensor.detach().clone().contiguous()
        dist.all_reduce(out, op=dist.ReduceOp.SUM)
        return out

    def gather(self, tensor: torch.Tensor) -> torch.Tensor:
        import torch.distributed as dist

        part = tensor.detach().contiguous()
        parts = [torch.empty_like(part) for _ in range(self.world_size)]
        dist.all_gather(parts, part)
        return torch.cat(parts)

    def gather_objects(self, obj) -> list:
        import torch.distributed as dist

        out = [None] * self.world_size
        dist.all_gather_object(out, obj)
        return out

    def barrier(self) -> None:
        import torch.distributed as dist

        dist.barrier()


def _attempt_store(world: int):
    """Under torchrun, whose agent keeps one store for all restarts of the group: that store with a
    prefix of its own for this restart (``TORCHELASTIC_RESTART_COUNT``); ``None`` otherwise.

    torch's ``env://`` initialisation uses the agent's store without such a prefix, so after a
    restart a process could read an address that a process of the group before had left there
    and fail on "Connection refused" (in 1 of 3 restarts of a two-process gloo group here; with the
    prefix, none in 4; pytorch/pytorch#167288). ``tests/runtime/test_restarts.py`` restarts a group."""
    import datetime

    import torch.distributed as dist

    if os.environ.get("TORCHELASTIC_USE_AGENT_STORE") != str(True):
        return None
    agent = dist.TCPStore(os.environ["MASTER_ADDR"], int(os.environ["MASTER_PORT"]), world, is_master=False,
                          timeout=datetime.timedelta(minutes=30))  # torch's default for init_process_group
    return dist.PrefixStore(f"aectorch/attempt_{os.environ.get('TORCHELASTIC_RESTART_COUNT', '0')}", agent)


def setup(num_envs: int, device: str | torch.device = "cpu") -> Shard:
    """Join torchrun's process group (gloo on CPU, nccl on CUDA) and return this rank's
    `ProcessGroupShard`; ``Shard.single(num_envs)`` when the process was not started by torchrun
    with more than one process."""
    import torch.distributed as dist

    rank, world, local = world_from_env()
    if world <= 1:
        return Shard.single(num_envs)
    device = torch.device(device)
    if not dist.is_initialized():  # a group the caller made is used as it is, and left to them
        backend = "nccl" if device.type == "cuda" else "gloo"
        if device.type == "cuda":
            torch.cuda.set_device(local)
        store = _attempt_store(world)
        if store is None:
            dist.init_process_group(backend=backend)
        else:
            dist.init_process_group(backend=backend, store=store, rank=rank, world_size=world)
        _owned.append(True)
    return ProcessGroupShard(rank=rank, world_size=world, start=rank * num_envs, stop=(rank + 1) * num_envs,
                 total=world * num_envs)


def teardown() -> None:
    """Leave the process group if `setup` made it (one the caller made stays theirs)."""
    import torch.distributed as dist

    if _owned and dist.is_initialized():
        dist.destroy_process_group()
    _owned.clear()
