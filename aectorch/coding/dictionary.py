"""`SparseDictionary`: a learnable over-complete dictionary with a greedy sparse coder.

The paper's sensory coding model (sec. 2.2): signals are coded with k atoms, the
normalised reconstruction error of eq. (4) is the cost, and the atoms follow its
gradient with the support and coefficients held fixed, then are renormalised.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import torch
from torch import nn

from aectorch._checks import check_int
from aectorch.coding.batch_omp import DEFAULT_BLOCK_SIZE, _validate, gram_matrix, matching_pursuit, omp
from aectorch.coding.sparse_code import SparseCode
from aectorch.ops.backend import fused_kernels_apply

__all__ = ["SparseDictionary", "DictionaryOutput", "learn_together_", "pooled_activity", "reconstruction_error"]

_ALGORITHMS = {"omp": omp, "mp": matching_pursuit}


class DictionaryOutput(NamedTuple):
    """What `SparseDictionary.forward` returns.

    Attributes:
        code: the sparse code, `indices`/`coefficients` `[..., k]` (constants for autograd).
        reconstruction: ``D a`` per signal, `[..., P]`, differentiable w.r.t. the atoms.
        error: eq. (4) term per signal, ``||x - D a||^2 / ||x||^2``, `[...]`
            (0 for a zero signal), differentiable w.r.t. the atoms.
    """

    code: SparseCode
    reconstruction: torch.Tensor
    error: torch.Tensor


def reconstruction_error(signals: torch.Tensor, reconstruction: torch.Tensor) -> torch.Tensor:
    """Normalised squared reconstruction error per signal, the summand of eq. (4).

    ``||x - x_hat||^2 / ||x||^2``, defined as 0 when ``x`` is zero (then the code,
    and so ``x_hat``, is zero as well): never NaN, also in the backward pass.

    Shape:
        signals, reconstruction: `[..., P]`; returns `[...]`.
    """
    energy = signals.square().sum(-1)
    residual = (signals - reconstruction).square().sum(-1)
    return residual / energy.clamp_min(torch.finfo(energy.dtype).tiny)


def pooled_activity(code: SparseCode, num_atoms: int, *, reduction: str = "sum") -> torch.Tensor:
    """Pooled activity of each atom over the patches of one image pair, eq. (3).

    ``f_n = sum_i a_{i,n}^2`` over the patches i. Repeated atoms of plain MP are
    summed within a patch before squaring.

    Args:
        code: codes of patches, `indices`/`coefficients` of shape `[..., n_patches, k]`.
        num_atoms: dictionary size N.
        reduction: ``"sum"`` (eq. 3, default) or ``"mean"`` over patches (the
            convention of some earlier AEC models; it only rescales by 1/n_patches).

    Returns:
        Features `[..., N]`.

    Example:
        >>> import torch
        >>> from aectorch.coding import SparseCode, pooled_activity
        >>> code = SparseCode(torch.tensor([[[0, 2], [2, 1]]]), torch.tensor([[[1.0, 2.0], [3.0, 0.5]]]))
        >>> pooled_activity(code, 3)
        tensor([[ 1.0000,  0.2500, 13.0000]])
    """
    if reduction not in ("sum", "mean"):
        raise ValueError(f"reduction must be 'sum' or 'mean', got {reduction!r}")
    if code.indices.ndim < 2:
        raise ValueError(
            f"code must have shape [..., n_patches, k], got indices of shape {tuple(code.indices.shape)}"
        )
    power = code.to_dense(num_atoms).square()
    return power.sum(-2) if reduction == "sum" else power.mean(-2)


class SparseDictionary(nn.Module):
    """A learnable dictionary of unit-norm atoms and its greedy sparse coder.

    Args:
        num_atoms: number of atoms N (the paper: 288).
        dim: signal length P (the paper: 200, two 10x10 half-patches).
        sparsity: non-zero coefficients per signal k (the paper: 10).
        algorithm: ``"omp"`` (orthogonal matching pursuit) or ``"mp"`` (the
            paper's plain matching pursuit).
        generator: optional `torch.Generator` for the random initial atoms
            (white noise, then unit-normalised, as in the AEC lineage).
        mirror: optional symmetry of the signals, an index of length `dim` with
            ``mirror[mirror]`` the identity (e.g. `aectorch.coding.patch_permutation`). The atoms
            then come in mirror pairs: atom ``j + N/2`` is atom ``j`` permuted (N even), kept so
            by every `learn_` step (`symmetrize_`). The code of a permuted signal is then the
            code of the signal with every atom replaced by its partner (the buffer `partner`,
            ``(j + N/2) mod N``; ``None`` without a mirror), so the pooled
            activities of permuted signals are the permuted activities: ``f(x[..., mirror]) =
            f(x)[..., partner]`` (up to ties).
        dtype, device: of the atoms (default: torch's defaults).

    Shape:
        forward: signals `[..., P]` -> `DictionaryOutput` with code `[..., k]`,
        reconstruction `[..., P]` and error `[...]`.

    Example:
        >>> import torch
        >>> from aectorch.coding import SparseDictionary
        >>> d = SparseDictionary(num_atoms=288, dim=200, sparsity=10,
        ...                      generator=torch.Generator().manual_seed(0))
        >>> out = d(torch.randn(4, 49, 200))
        >>> out.error.shape
        torch.Size([4, 49])
        >>> out.error.mean().backward()   # the paper's gradient, on d.atoms.grad
        >>> d.atoms.grad.shape
        torch.Size([200, 288])
    """

    def __init__(
        self,
        num_atoms: int = 288,
        dim: int = 200,
        sparsity: int = 10,
        algorithm: str = "omp",
        *,
        generator: torch.Generator | None = None,
        mirror: torch.Tensor | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        for name, value in (("num_atoms", num_atoms), ("dim", dim), ("sparsity", sparsity)):
            check_int(value, name)
        if sparsity > min(num_atoms, dim):
            raise ValueError(
                f"sparsity={sparsity} must not exceed min(num_atoms={num_atoms}, dim={dim})"
            )
        if algorithm not in _ALGORITHMS:
            raise ValueError(f"algorithm must be one of {sorted(_ALGORITHMS)}, got {algorithm!r}")
        self.num_atoms = num_atoms
        self.dim = dim
        self.sparsity = sparsity
        self.algorithm = algorithm
        atoms = torch.randn(dim, num_atoms, generator=generator, dtype=dtype, device="cpu")
        self.atoms = nn.Parameter(atoms.to(device) if device is not None else atoms)
        # With a mirror: the signal index and each atom's partner, (j + N/2) mod N (derived, so not
        # saved; buffers so that `.to()` moves them with the atoms).
        partner = None
        if mirror is not None:
            mirror = _check_mirror(mirror, dim, num_atoms).to(self.atoms.device)
            partner = torch.arange(num_atoms, device=self.atoms.device).add(num_atoms // 2).remainder(num_atoms)
        self.register_buffer("mirror", mirror, persistent=False)
        self.register_buffer("partner", partner, persistent=False)
        self.symmetrize_()
        self.renormalize_()

    def extra_repr(self) -> str:
        return (
            f"num_atoms={self.num_atoms}, dim={self.dim}, sparsity={self.sparsity}, "
            f"algorithm={self.algorithm!r}"
        )

    @torch.no_grad()
    def symmetrize_(self) -> "SparseDictionary":
        """Project the atoms onto mirror pairs, in place: ``D <- (D + M D Pi) / 2`` (M the signal
        mirror, Pi the pairing); afterwards atom ``partner[j]`` is atom ``j`` mirrored. Does
        nothing without `mirror`. The norms of the two atoms of a pair become equal."""
        if self.mirror is not None:
            self.atoms.copy_((self.atoms + self.atoms[self.mirror][:, self.partner]) * 0.5)  # type: ignore[index]
        return self

    @torch.no_grad()
    def renormalize_(self) -> "SparseDictionary":
        """Scale every atom back to unit L2 norm, in place (a zero atom stays zero)."""
        norms = self.atoms.norm(dim=0, keepdim=True)
        self.atoms.div_(norms.clamp_min(torch.finfo(norms.dtype).tiny))
        return self

    def encode(self, signals: torch.Tensor, *, check: bool = True) -> SparseCode:
        """The sparse code of `signals` `[..., P]` (no gradient)."""
        coder = _ALGORITHMS[self.algorithm]
        atoms = self.atoms.detach()
        return coder(signals, atoms, self.sparsity, gram=gram_matrix(atoms), check=check)

    def forward(self, signals: torch.Tensor, *, check: bool = True) -> DictionaryOutput:
        """Code `signals` and reconstruct them with the current atoms (see class doc).

        Without a graph to build (grad mode off, or atoms that do not require grad), on CPU the
        reconstruction and its error come from one fused kernel (``aectorch::reconstruct_error``);
        with a graph, from torch's differentiable operations.
        """
        code = self.encode(signals, check=check)
        if not (torch.is_grad_enabled() and self.atoms.requires_grad) and signals.dtype == self.atoms.dtype \
                and fused_kernels_apply(signals):
            p = self.dim
            reconstruction, error = torch.ops.aectorch.reconstruct_error(
                signals.reshape(-1, p), self.atoms.detach().t().contiguous(), code.indices.reshape(-1, self.sparsity),
                code.coefficients.reshape(-1, self.sparsity))
            return DictionaryOutput(code, reconstruction.reshape(signals.shape), error.reshape(signals.shape[:-1]))
        reconstruction = code.reconstruct(self.atoms)
        return DictionaryOutput(code, reconstruction, reconstruction_error(signals, reconstruction))

    def forward_pooled(self, signals: torch.Tensor, *, check: bool = True,
                       reduction: str = "sum") -> tuple[DictionaryOutput, torch.Tensor]:
        """``self(signals)`` and the pooled activity of its code over the patches, eq. (3):
        `(DictionaryOutput, features [..., N])` for signals `[..., n_patches, P]`.

        The same numbers as ``out = self(signals); self.pooled_activity(out.code, reduction=...)``.
        Without a graph to build, on CPU all of it (the Gram matrix, the sparse coding, the
        reconstructions, their errors and the pooling) is one fused kernel (``aectorch::encode``),
        one pass over the signals.

        Example:
            >>> import torch
            >>> d = SparseDictionary(num_atoms=16, dim=8, sparsity=2, generator=torch.Generator().manual_seed(0))
            >>> x = torch.randn(3, 5, 8, generator=torch.Generator().manual_seed(1))
            >>> with torch.no_grad():
            ...     out, features = d.forward_pooled(x, reduction="mean")
            ...     plain = d.pooled_activity(d(x).code, reduction="mean")
            >>> features.shape, torch.allclose(features, plain)
            (torch.Size([3, 16]), True)
        """
        atoms = self.atoms
        lead = signals.shape[:-2] if isinstance(signals, torch.Tensor) else ()
        if not isinstance(signals, torch.Tensor) or signals.ndim < 2 or reduction not in ("sum", "mean") \
                or signals.shape[:-1].numel() == 0 or (torch.is_grad_enabled() and atoms.requires_grad) \
                or signals.dtype != atoms.dtype or not fused_kernels_apply(signals):
            out = self(signals, check=check)
            return out, self.pooled_activity(out.code, reduction=reduction)
        detached = atoms.detach()
        # (the kernels apply, so "auto" is what any backend setting other than "torch" checks)
        _validate(signals, detached, self.sparsity, None, check, "auto")
        patches, p, k = signals.shape[-2], self.dim, self.sparsity
        # (gram None: the kernel computes it, as aectorch::gram does, in the same pass)
        indices, coefficients, reconstruction, error, features = torch.ops.aectorch.encode(
            signals.reshape(-1, p), detached, None, k, self.algorithm == "omp", DEFAULT_BLOCK_SIZE,
            max(1, lead.numel()))
        code = SparseCode(indices.reshape(*signals.shape[:-1], k), coefficients.reshape(*signals.shape[:-1], k))
        out = DictionaryOutput(code, reconstruction.reshape(signals.shape), error.reshape(signals.shape[:-1]))
        features = features.reshape(*lead, self.num_atoms)
        return out, features if reduction == "sum" else features / patches

    def pooled_activity(self, code: SparseCode, *, reduction: str = "sum") -> torch.Tensor:
        """Eq. (3) for codes `[..., n_patches, k]` of this dictionary -> `[..., N]`.

        On CPU the squared coefficients are added straight into the ``N`` features (``k`` per
        patch, an atom picked twice in a patch by plain MP summed first) by one fused kernel
        (``aectorch::pooled_power``) instead of through a dense ``[..., n_patches, N]`` code.
        """
        if code.indices.ndim < 2 or reduction not in ("sum", "mean") or torch.is_grad_enabled() \
                and code.coefficients.requires_grad or not fused_kernels_apply(code.coefficients):
            return pooled_activity(code, self.num_atoms, reduction=reduction)
        lead, (patches, k) = code.indices.shape[:-2], code.indices.shape[-2:]
        features = torch.ops.aectorch.pooled_power(
            code.indices.reshape(-1, patches, k), code.coefficients.reshape(-1, patches, k), self.num_atoms)
        features = features.reshape(*lead, self.num_atoms)
        return features if reduction == "sum" else features / patches

    @torch.no_grad()
    def gradient(self, signals: torch.Tensor, output: DictionaryOutput, *,
                 reduce: Callable[[torch.Tensor], torch.Tensor] | None = None) -> torch.Tensor:
        """Closed-form gradient of ``output.error.mean()`` with respect to the atoms.

        ``-(2 / M) sum_i r_i a_i^T / ||x_i||^2`` over the M signals, with residuals
        ``r_i = x_i - D a_i`` and the code held fixed: exactly what autograd gives
        for ``output.error.mean().backward()``, without building a graph.

        With ``reduce`` (a sum over processes that share the batch, `aectorch.runtime.distributed`) the
        mean runs over every process's signals.

        Returns:
            `[P, N]`, like `atoms`.
        """
        x = signals.reshape(-1, self.dim)
        reconstruction = output.reconstruction.detach().reshape(-1, self.dim)
        if x.dtype == reconstruction.dtype == output.code.coefficients.dtype and fused_kernels_apply(x):
            # From the k active atoms of each signal (a scatter-add), not the dense [P, M] x [M, N] product.
            k = output.code.indices.shape[-1]
            total = torch.ops.aectorch.sparse_gradient(
                x, reconstruction, output.code.indices.reshape(-1, k), output.code.coefficients.reshape(-1, k),
                self.num_atoms).t()
        else:
            residual = x - reconstruction
            energy = x.square().sum(-1, keepdim=True).clamp_min(torch.finfo(x.dtype).tiny)
            dense = output.code.to_dense(self.num_atoms).reshape(-1, self.num_atoms)
            total = (residual / energy).t() @ dense
        if reduce is None:
            return total * (-2.0 / x.shape[0])
        count = reduce(torch.tensor(float(x.shape[0]), dtype=x.dtype, device=x.device))
        return reduce(total.contiguous()) * (-2.0 / count)

    @torch.no_grad()
    def learn_(self, signals: torch.Tensor, output: DictionaryOutput, lr: float, *,
               reduce: Callable[[torch.Tensor], torch.Tensor] | None = None) -> torch.Tensor:
        """One gradient-descent step on the mean eq. (4) error, then renormalise.

        ``D <- normalise(D - lr * grad)`` (``reduce``: see `gradient`; with `mirror` the step is
        projected onto mirror pairs before the normalisation). For textured binocular patches
        (``||x||^2 = 2``) this is the AEC rule ``D <- D + lr * R A^T / M``.

        Returns:
            The gradient that was applied, `[P, N]`.
        """
        if not lr >= 0:
            raise ValueError(f"lr must be a non-negative float, got {lr!r}")
        grad = self.gradient(signals, output, reduce=reduce)
        if self.atoms.is_contiguous() and grad.dtype == self.atoms.dtype and fused_kernels_apply(self.atoms):
            # The step, the mirror projection and the renormalisation in one kernel (the same arithmetic).
            torch.ops.aectorch.dictionary_step_(self.atoms.detach(), grad.t(), float(lr), self.mirror, self.partner)
            torch.autograd.graph.increment_version(self.atoms)
            return grad
        self.atoms.sub_(grad, alpha=lr)
        self.symmetrize_()
        self.renormalize_()
        return grad


@torch.no_grad()
def learn_together_(dictionaries: Sequence[SparseDictionary], signals: Sequence[torch.Tensor],
                    outputs: Sequence[DictionaryOutput], lr: float, *,
                    reduce: Callable[[torch.Tensor], torch.Tensor] | None = None) -> None:
    """`SparseDictionary.learn_` of several dictionaries (a coder's scales), each on its own signals.

    On CPU with the fused kernels and no ``reduce``, one call of ``aectorch::learn_steps_`` spreads
    the dictionaries over the kernels' threads (each dictionary's gradient and step on one thread:
    the same bits as `SparseDictionary.learn_`, one after the other); otherwise they learn one by one.

    Example:
        >>> import torch
        >>> g = torch.Generator().manual_seed(0)
        >>> dicts = [SparseDictionary(16, 8, 2, generator=g) for _ in range(2)]
        >>> xs = [torch.randn(5, 8, generator=g) for _ in dicts]
        >>> with torch.no_grad():
        ...     outs = [d(x) for d, x in zip(dicts, xs)]
        >>> learn_together_(dicts, xs, outs, 0.1)
        >>> tuple(round(float(d.atoms.detach().norm(dim=0).mean()), 4) for d in dicts)
        (1.0, 1.0)
    """
    if not lr >= 0:
        raise ValueError(f"lr must be a non-negative float, got {lr!r}")
    if not len(dictionaries) == len(signals) == len(outputs):
        raise ValueError(f"learn_together_ needs one signals and one output per dictionary, got {len(dictionaries)} "
                         f"dictionaries, {len(signals)} signals and {len(outputs)} outputs")
    xs = [x.reshape(-1, d.dim) for d, x in zip(dictionaries, signals)]
    fused = reduce is None and all(
        d.atoms.is_contiguous() and fused_kernels_apply(d.atoms) and x.shape[0] > 0
        and x.dtype == out.reconstruction.dtype == out.code.coefficients.dtype == d.atoms.dtype
        for d, x, out in zip(dictionaries, xs, outputs))
    if not fused:
        for d, x, out in zip(dictionaries, signals, outputs):
            d.learn_(x, out, lr, reduce=reduce)
        return
    ks = [out.code.indices.shape[-1] for out in outputs]
    torch.ops.aectorch.learn_steps_(
        [d.atoms.detach() for d in dictionaries], xs,
        [out.reconstruction.detach().reshape(-1, d.dim) for d, out in zip(dictionaries, outputs)],
        [out.code.indices.reshape(-1, k) for out, k in zip(outputs, ks)],
        [out.code.coefficients.reshape(-1, k) for out, k in zip(outputs, ks)],
        float(lr), [d.mirror for d in dictionaries], [d.partner for d in dictionaries])
    for d in dictionaries:
        torch.autograd.graph.increment_version(d.atoms)


def _check_mirror(mirror: torch.Tensor, dim: int, num_atoms: int) -> torch.Tensor:
    if not isinstance(mirror, torch.Tensor) or mirror.dtype not in (torch.int32, torch.int64):
        raise TypeError(f"mirror must be an integer tensor (an index of length dim={dim}), got {mirror!r}")
    mirror = mirror.long().cpu()
    if mirror.shape != (dim,) or not torch.equal(mirror.sort().values, torch.arange(dim)):
        raise ValueError(f"mirror must be a permutation of range(dim={dim}), got shape {tuple(mirror.shape)}")
    if not torch.equal(mirror[mirror], torch.arange(dim)):
        raise ValueError("mirror must be an involution (mirror[mirror] == arange(dim)), as a mirror is")
    if num_atoms % 2:
        raise ValueError(f"num_atoms must be even with mirror (atoms come in mirror pairs), got {num_atoms}")
    return mirror
