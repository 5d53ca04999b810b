"""`SparseCode`: the result of OMP or MP, k (index, coefficient) pairs per signal."""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F

from aectorch._checks import check_int

__all__ = ["SparseCode"]


class SparseCode(NamedTuple):
    """k atoms and their coefficients for each signal.

    A `NamedTuple`, so it is a pytree that `torch.compile`, `torch.func` and
    `torch.utils._pytree` handle without registration.

    Slots are in the order the coder chose the atoms. A slot left unused
    because the coder stopped early (the residual was already zero, or the
    next atom was linearly dependent on the chosen ones) has coefficient
    exactly 0 and index 0. Plain matching pursuit may choose one atom twice;
    `to_dense` and `reconstruct` sum repeated atoms.

    Attributes:
        indices: atom indices, LongTensor of shape `[..., k]`.
        coefficients: coefficients, shape `[..., k]`, the signals' dtype.

    Example:
        >>> import torch
        >>> from aectorch.coding import omp
        >>> D = torch.nn.functional.normalize(torch.randn(20, 50), dim=0)
        >>> code = omp(torch.randn(4, 20), D, sparsity=3)
        >>> code.indices.shape, code.to_dense(50).shape, code.reconstruct(D).shape
        (torch.Size([4, 3]), torch.Size([4, 50]), torch.Size([4, 20]))
    """

    indices: torch.Tensor
    coefficients: torch.Tensor

    @property
    def sparsity(self) -> int:
        """The number of slots k."""
        return self.indices.shape[-1]

    def to_dense(self, num_atoms: int) -> torch.Tensor:
        """Scatter the code into a dense coefficient tensor `[..., num_atoms]` (differentiable)."""
        check_int(num_atoms, "num_atoms")
        shape = self.coefficients.shape[:-1] + (num_atoms,)
        dense = self.coefficients.new_zeros(shape)
        return dense.scatter_add(-1, self.indices, self.coefficients)

    def reconstruct(self, dictionary: torch.Tensor) -> torch.Tensor:
        """Sum of the chosen atoms weighted by their coefficients.

        Differentiable with respect to both `dictionary` and `coefficients`; the
        support (indices) is a constant. Uses `embedding_bag`, so the `[M, k, P]`
        gathered atoms are never materialised.

        Args:
            dictionary: atoms as columns, shape `[P, N]`.

        Returns:
            Reconstructed signals, shape `[..., P]`.
        """
        if dictionary.ndim != 2:
            raise ValueError(f"dictionary must have shape [P, N], got {tuple(dictionary.shape)}")
        k = self.indices.shape[-1]
        lead = self.indices.shape[:-1]
        # embedding_bag reads its table row by row: on the transposed view of a [P, N] atom matrix
        # it was 15x slower on CPU (15 ms against 1 ms for 4096 signals) than on a contiguous
        # copy, which costs one pass over the atoms.
        out = F.embedding_bag(
            self.indices.reshape(-1, k),
            dictionary.t().contiguous(),
            per_sample_weights=self.coefficients.reshape(-1, k).to(dictionary.dtype),
            mode="sum",
        )
        return out.reshape(*lead, dictionary.shape[0])

    def to(self, *args, **kwargs) -> "SparseCode":
        """Move or cast like `Tensor.to` (indices keep their integer dtype)."""
        coefficients = self.coefficients.to(*args, **kwargs)
        return SparseCode(self.indices.to(coefficients.device), coefficients)

    def detach(self) -> "SparseCode":
        """A code whose coefficients are detached from the autograd graph."""
        return SparseCode(self.indices, self.coefficients.detach())
