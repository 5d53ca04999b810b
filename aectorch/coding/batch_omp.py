"""Batched greedy sparse coding: orthogonal matching pursuit (OMP) and matching pursuit (MP).

Both work in the Gram-matrix form: the correlations of all signals with all atoms,
``alpha = X D``, are computed once with one matrix product, and every later step
updates them through rows of ``G = D^T D`` instead of touching the signals again
(Batch-OMP, Rubinstein, Zibulevsky & Elad 2008).

Implementation notes (why the code looks the way it does):

* OMP keeps, per signal, the inverse ``Linv`` of the Cholesky factor of the Gram
  matrix of the chosen atoms. Adding atom ``lam`` appends one row to it, and the
  correlation update of step i is ``alpha -= u_i * y_i`` with
  ``u_i = G[:, I] Linv[i]^T`` (the correlations of the i-th orthonormalised atom)
  and ``y_i = alpha[lam] / L_ii`` (the signal's coordinate along it, equal to
  ``Linv[i] . alpha0[I]``); the coefficients are ``Linv^T y`` at the end. Nothing
  grows with i except those k x k triangles, and the sum over chosen atoms is one
  ``embedding_bag`` over rows of G, which never materialises ``[M, k, N]``.
* The small per-signal state (``Linv``, ``y``, indices) is stored batch-last,
  ``[k, k, M]``, so its tiny reductions run along contiguous, vectorised memory.
* ``argmax |alpha|`` is computed with ``amax`` over a packed key (magnitude bits
  with the reversed atom index in the low bits), because on CPU ``argmax`` is not
  vectorised and costs several times more than ``amax``. The result is exactly
  ``torch.argmax``'s (first index on ties); see `_select`.
* On CPU, signals are processed in blocks of ``block_size`` rows so that the
  ``[block, N]`` working set stays in the L2 cache; this is tiling, not a loop
  over signals. The blocks reuse workspace buffers and run under
  ``inference_mode``, because at this size torch's per-op dispatch and fresh
  page-faulted tensors cost as much as the arithmetic (docs/performance.md).
  Under ``torch.compile`` and on CUDA the whole batch is one block.
* On CPU (float32/float64) the default ``backend="auto"`` runs instead the fused C++ kernel
  ``torch.ops.aectorch.sparse_code`` (``coder_cpu.cpp``, built on first use by
  `aectorch.ops.native`): the same algorithm, one loop per signal over its correlations
  in L1, 2.5-4x faster than the torch code here (docs/performance.md). ``backend="torch"``
  forces the code above, which is also the CUDA path and the fallback when no compiler is
  available. The two agree within float rounding (tests/coding/test_batch_omp.py).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import torch
import torch.nn.functional as F

from aectorch._checks import is_int
from aectorch.ops.backend import BACKENDS, check_backend, default_backend, fused_kernels_apply, native_loaded, \
    native_supports, use_backend
from aectorch.coding.sparse_code import SparseCode

__all__ = ["omp", "matching_pursuit", "gram_matrix", "use_backend", "DEFAULT_BLOCK_SIZE", "BACKENDS"]

#: Rows per block on CPU. 512 x 288 float32 correlations are 0.6 MB: they and the
#: per-step temporaries fit a 2 MB L2 cache (benchmarks/test_coding.py measures it).
DEFAULT_BLOCK_SIZE = 512

_INDEX_BITS = 29  # spare mantissa bits of float64 over float32


def gram_matrix(dictionary: torch.Tensor) -> torch.Tensor:
    """The Gram matrix ``G = D^T D`` of a dictionary `[P, N]`, shape `[N, N]`.

    Without a graph to build, on CPU it comes from the fused kernels' ``aectorch::gram`` (the same
    product in two blocks of rows, on two of the kernels' threads; torch's own operations run on
    one thread in training), else from ``D^T @ D``.
    """
    if not (torch.is_grad_enabled() and dictionary.requires_grad) and dictionary.ndim == 2 \
            and fused_kernels_apply(dictionary):
        return torch.ops.aectorch.gram(dictionary)
    return dictionary.t() @ dictionary


def _validate(
    signals: torch.Tensor,
    dictionary: torch.Tensor,
    sparsity: int,
    gram: torch.Tensor | None,
    check_finite: bool,
    backend: str = "auto",
) -> None:
    if not isinstance(signals, torch.Tensor):
        raise TypeError(f"signals must be a torch.Tensor, got {type(signals).__name__}")
    if not isinstance(dictionary, torch.Tensor):
        raise TypeError(f"dictionary must be a torch.Tensor, got {type(dictionary).__name__}")
    if not signals.is_floating_point():
        raise TypeError(f"signals must be a floating-point tensor, got dtype {signals.dtype}")
    if dictionary.dtype != signals.dtype:
        raise TypeError(
            f"dictionary dtype {dictionary.dtype} does not match signals dtype {signals.dtype}"
        )
    if dictionary.device != signals.device:
        raise ValueError(
            f"dictionary is on {dictionary.device} but signals are on {signals.device}"
        )
    if dictionary.ndim != 2:
        raise ValueError(f"dictionary must have shape [P, N], got {tuple(dictionary.shape)}")
    if signals.ndim < 1 or signals.shape[-1] != dictionary.shape[0]:
        raise ValueError(
            f"signals must have shape [..., P] with P = dictionary.shape[0] = "
            f"{dictionary.shape[0]}, got {tuple(signals.shape)}"
        )
    if not is_int(sparsity):
        raise TypeError(f"sparsity must be an int, got {type(sparsity).__name__}")
    dim, num_atoms = dictionary.shape
    if sparsity < 1 or sparsity > dim or sparsity > num_atoms:
        raise ValueError(
            f"sparsity must be in [1, min(P, N)] = [1, {min(dim, num_atoms)}] for a dictionary "
            f"of shape [P={dim}, N={num_atoms}], got {sparsity}"
        )
    check_backend(backend)
    if backend == "native" and not native_supports(signals):
        raise ValueError(
            "backend='native' needs float32 or float64 signals on CPU and a built kernel "
            f"(got {signals.dtype} on {signals.device}; kernel available: {native_loaded()}); "
            "see aectorch.ops.native"
        )
    if gram is not None and tuple(gram.shape) != (num_atoms, num_atoms):
        raise ValueError(
            f"gram must have shape [N, N] = [{num_atoms}, {num_atoms}], got {tuple(gram.shape)}"
        )
    if check_finite and not torch.compiler.is_compiling():
        if not bool(torch.isfinite(signals).all()):
            raise ValueError("signals contain non-finite values (NaN or inf)")
        if not bool(torch.isfinite(dictionary).all()):
            raise ValueError("dictionary contains non-finite values (NaN or inf)")
        norms = dictionary.norm(dim=0)
        worst = (norms - 1).abs().max()
        if bool(worst > 1e-3):
            raise ValueError(
                "dictionary columns must have unit norm (max |norm - 1| = "
                f"{float(worst):.3g}); normalise them, e.g. SparseDictionary.renormalize_()"
            )


def _reversed_index(num_atoms: int, mask: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    return mask - torch.arange(num_atoms, device=device, dtype=dtype)


def _index_mask(num_atoms: int) -> int:
    """All-ones mask wide enough for the atom indices 0 .. num_atoms - 1."""
    return (1 << max(1, (num_atoms - 1).bit_length())) - 1


class _Workspace(NamedTuple):
    """Reused `[block, N]` buffers of the eager CPU path.

    Fresh tensors of this size come from ``mmap`` and are page-faulted in on every
    step; reusing them is worth about a third of the run time on CPU.
    """

    alpha: torch.Tensor  # correlations, the signals' dtype
    rows: torch.Tensor  # gathered Gram rows (MP)
    key: torch.Tensor  # int32 argmax keys (float32 only)
    reversed_index: torch.Tensor  # [N] int32, low bits of the keys

    @staticmethod
    def make(rows: int, num_atoms: int, dtype: torch.dtype, device: torch.device) -> "_Workspace":
        def empty(dt: torch.dtype) -> torch.Tensor:
            return torch.empty(rows, num_atoms, dtype=dt, device=device)

        index = _reversed_index(num_atoms, _index_mask(num_atoms), torch.int32, device)
        return _Workspace(empty(dtype), empty(dtype), empty(torch.int32), index)

    def view(self, m: int) -> "_Workspace":
        return _Workspace(self.alpha[:m], self.rows[:m], self.key[:m], self.reversed_index)


def _select(alpha: torch.Tensor, ws: _Workspace | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Index and value of the largest ``|alpha|`` per row of `[M, N]`.

    Exactly ``alpha.abs().argmax(-1)`` (first index on ties), and ``alpha`` there.
    """
    num_atoms = alpha.shape[-1]
    if alpha.dtype != torch.float32 or alpha.is_cuda or num_atoms >= 2**_INDEX_BITS:
        lam = alpha.abs().argmax(-1)
    elif ws is None:
        lam = _argmax_abs_float64_key(alpha)
    else:
        return _argmax_abs_int32_key(alpha, ws.key, ws.reversed_index)
    return lam, alpha.gather(-1, lam[:, None])[:, 0]


def _argmax_abs_float64_key(alpha: torch.Tensor) -> torch.Tensor:
    # Branch-free, for torch.compile. float32 -> float64 is exact and leaves the low
    # 29 mantissa bits zero. Positive doubles order like their int64 bit patterns,
    # so OR-ing the reversed index into those bits makes amax pick the largest
    # magnitude, then the smallest index.
    mask = 2**_INDEX_BITS - 1
    key = alpha.abs().to(torch.float64).view(torch.int64)
    best = key.bitwise_or_(_reversed_index(alpha.shape[-1], mask, torch.int64, alpha.device)).amax(-1)
    return mask - best.bitwise_and(mask)


def _argmax_abs_int32_key(
    alpha: torch.Tensor, key: torch.Tensor, reversed_index: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    # Half the memory traffic of the float64 key: the reversed index replaces the
    # low mantissa bits of |alpha| itself. That rounds magnitudes to 23 - bits
    # mantissa bits, so a candidate is checked against the exact maximum, and the
    # rare rows where rounding decided (two magnitudes within ~1e-4 relative) are
    # recomputed exactly.
    mask = _index_mask(alpha.shape[-1])
    torch.bitwise_and(alpha.view(torch.int32), 0x7FFFFFFF ^ mask, out=key)
    key.bitwise_or_(reversed_index)
    lam = (mask - key.amax(-1).bitwise_and_(mask)).long()
    value = alpha.gather(-1, lam[:, None])[:, 0]
    # (aminmax and vector_norm(inf) are not vectorised along rows on CPU; amax/amin are)
    best = torch.maximum(alpha.amax(-1), alpha.amin(-1).neg_())
    rows = (value.abs() != best).nonzero()[:, 0]
    if rows.numel() > 0:
        lam[rows] = alpha[rows].abs().argmax(-1)
        value[rows] = alpha[rows, lam[rows]]
    return lam, value


def _correlations(x: torch.Tensor, dictionary: torch.Tensor, ws: _Workspace | None) -> torch.Tensor:
    return x @ dictionary if ws is None else torch.mm(x, dictionary, out=ws.alpha)


def _mp_block(
    x: torch.Tensor, dictionary: torch.Tensor, gram: torch.Tensor, k: int, ws: _Workspace | None = None
) -> SparseCode:
    alpha = _correlations(x, dictionary, ws)  # [M, N]
    indices, coefficients = [], []
    for i in range(k):
        lam, c = _select(alpha, ws)
        if i < k - 1:
            rows = gram.index_select(0, lam) if ws is None else torch.index_select(gram, 0, lam, out=ws.rows)
            alpha.addcmul_(rows, c[:, None], value=-1.0)
        indices.append(lam)
        coefficients.append(c)
    return SparseCode(torch.stack(indices, 1), torch.stack(coefficients, 1))


def _omp_block(
    x: torch.Tensor, dictionary: torch.Tensor, gram: torch.Tensor, k: int, ws: _Workspace | None = None
) -> SparseCode:
    m, n = x.shape[0], gram.shape[0]
    eps = torch.finfo(x.dtype).eps
    alpha = _correlations(x, dictionary, ws)  # [M, N] correlations of the residuals with the atoms
    diag, flat_gram = gram.diagonal(), gram.reshape(-1)
    linv = x.new_zeros(k, k, m)  # inverse Cholesky factor of G[I, I], batch-last
    y = x.new_zeros(k, m)  # coordinates along the orthonormalised chosen atoms
    support = torch.zeros(m, k, dtype=torch.long, device=x.device)
    offsets = torch.zeros(k, m, dtype=torch.long, device=x.device)  # I_j * N
    live = x.new_ones(m)  # 1 until the coding of that signal stops
    # Views made once: slicing costs a dispatch per step too.
    triangles = [linv[:i, :i] for i in range(k)]
    rows = [linv[i, : i + 1] for i in range(k)]
    for i in range(k):
        lam, a = _select(alpha, ws)
        if i == 0:
            lkk = diag[lam]
        else:
            g = flat_gram.take(offsets[:i] + lam)  # G[I_j, lam]: [i, M]
            w = (triangles[i] * g).sum(1)  # Linv G[I, lam]
            lkk = diag[lam] - w.square().sum(0)  # squared norm of lam's new direction
        # scikit-learn's stops: residual correlation below eps, or an atom dependent
        # on the chosen ones. (A chosen atom's correlation is zeroed below, so it is
        # chosen again only when every correlation is 0, which the first rule stops.)
        live = live * ((a * a >= eps) & (lkk > eps))
        inv = torch.where(live > 0, lkk, 1.0).rsqrt_()  # 1 / L_ii (1 once stopped)
        scale = inv * live
        lam.mul_(live.long())  # index 0 in unused slots
        if i > 0:
            rows[i][:i] = (triangles[i] * w[:, None]).sum(0).mul_(scale).neg_()  # -(w^T Linv) / L_ii
        rows[i][i] = inv
        support[:, i] = lam
        offsets[i] = lam * n
        y[i] = a * scale  # q_i . x = q_i . r_{i-1} = alpha[lam] / L_ii
        if i < k - 1:
            u = F.embedding_bag(
                support[:, : i + 1], gram, per_sample_weights=rows[i].t().contiguous(), mode="sum"
            )
            alpha.addcmul_(u, y[i][:, None], value=-1.0)  # alpha -= (D^T q_i) y_i
            alpha.scatter_(1, lam[:, None], 0.0)  # exact in arithmetic; no rounding residue
    gamma = (linv * y[:, None, :]).sum(0)  # Linv^T y: [k, M]
    return SparseCode(support, gamma.t().contiguous())


def _run(
    block_fn: Callable[..., SparseCode],
    signals: torch.Tensor,
    dictionary: torch.Tensor,
    sparsity: int,
    gram: torch.Tensor | None,
    block_size: int | None,
    backend: str = "auto",
) -> SparseCode:
    # The support and the coefficients are constants for autograd (the paper's
    # dictionary gradient holds them fixed); see SparseCode.reconstruct.
    lead = signals.shape[:-1]
    x = signals.detach().reshape(-1, signals.shape[-1])
    dictionary = dictionary.detach()
    gram = gram_matrix(dictionary) if gram is None else gram.detach()
    m = x.shape[0]
    if backend != "torch" and native_supports(x):
        block = max(m, 1) if block_size is None else block_size
        # The operator itself (not native.sparse_code, which loads it): torch.compile traces this.
        code = SparseCode(*torch.ops.aectorch.sparse_code(x, dictionary, gram, sparsity, block_fn is _omp_block, block))
    elif m == 0 or x.is_cuda or torch.compiler.is_compiling():
        code = block_fn(x, dictionary, gram, sparsity)
    else:
        # inference_mode trims the per-op dispatch cost, which dominates small
        # blocks; the results are cloned out of it so autograd can use them.
        with torch.inference_mode():
            step = m if block_size is None else max(1, min(block_size, m))
            ws = _Workspace.make(step, gram.shape[0], x.dtype, x.device)
            parts = [
                block_fn(x[s : s + step], dictionary, gram, sparsity, ws.view(min(step, m - s)))
                for s in range(0, m, step)
            ]
            code = parts[0] if len(parts) == 1 else SparseCode(
                torch.cat([p.indices for p in parts]), torch.cat([p.coefficients for p in parts])
            )
        code = SparseCode(code.indices.clone(), code.coefficients.clone())
    return SparseCode(
        code.indices.reshape(*lead, sparsity), code.coefficients.reshape(*lead, sparsity)
    )


def omp(
    signals: torch.Tensor,
    dictionary: torch.Tensor,
    sparsity: int,
    *,
    gram: torch.Tensor | None = None,
    check: bool = True,
    block_size: int | None = DEFAULT_BLOCK_SIZE,
    backend: str | None = None,
) -> SparseCode:
    """Batched orthogonal matching pursuit (Batch-OMP, Gram-matrix form).

    Greedily picks, for every signal, the atom most correlated with the current
    residual, then re-fits all chosen coefficients by least squares. Gives the
    same support and coefficients as scikit-learn's
    ``orthogonal_mp_gram(G, D.T @ x, n_nonzero_coefs=sparsity)``, including its
    early stops (a residual already zero, or a dependent atom), whose unused
    slots get coefficient 0.

    Args:
        signals: signals as rows, shape `[..., P]`; any leading batch dimensions.
        dictionary: unit-norm atoms as columns, shape `[P, N]`, same dtype and
            device as `signals`.
        sparsity: number of atoms k per signal, ``1 <= k <= min(P, N)``.
        gram: optional precomputed ``dictionary.T @ dictionary``, `[N, N]`.
        check: validate values (finite, unit-norm atoms); costs a pass over the
            data and a host sync, so hot loops that validated once may pass False.
            Shapes are always checked. Skipped automatically under torch.compile.
        block_size: rows per cache-sized block on CPU (``None``: one block).
        backend: ``"auto"`` (the fused C++ kernel for float32/float64 on CPU when it is
            available, else torch), ``"native"`` (that kernel or a ValueError) or ``"torch"``
            (pure torch ops; the CUDA path). ``None``: the `use_backend` default, ``"auto"``
            unless changed. See `aectorch.ops.native`.

    Returns:
        `SparseCode` with `indices` `[..., k]` (LongTensor) and `coefficients` `[..., k]`.

    Example:
        >>> import torch
        >>> from aectorch.coding import omp
        >>> D = torch.nn.functional.normalize(torch.randn(200, 288, dtype=torch.float64), dim=0)
        >>> x = 2.0 * D[:, 5] - 0.5 * D[:, 40]
        >>> code = omp(x[None], D, sparsity=10)
        >>> sorted(code.indices[0, :2].tolist()), code.coefficients[0, 2:].abs().max().item()
        ([5, 40], 0.0)
    """
    backend = default_backend() if backend is None else backend
    _validate(signals, dictionary, sparsity, gram, check, backend)
    return _run(_omp_block, signals, dictionary, sparsity, gram, block_size, backend)


def matching_pursuit(
    signals: torch.Tensor,
    dictionary: torch.Tensor,
    sparsity: int,
    *,
    gram: torch.Tensor | None = None,
    check: bool = True,
    block_size: int | None = DEFAULT_BLOCK_SIZE,
    backend: str | None = None,
) -> SparseCode:
    """Batched plain matching pursuit (Mallat & Zhang 1993), the paper's coder.

    Each of the k steps picks the atom with the largest ``|correlation|`` with
    the residual, takes that correlation as its coefficient, and updates all
    residual correlations through the Gram matrix
    (``alpha -= c * G[lam]``). Earlier coefficients are never re-fitted, and an
    atom may be chosen more than once (its slots are summed by `SparseCode`).

    Args:
        signals: signals as rows, shape `[..., P]`.
        dictionary: unit-norm atoms as columns, shape `[P, N]`.
        sparsity: number of steps k, ``1 <= k <= min(P, N)``.
        gram: optional precomputed ``dictionary.T @ dictionary``, `[N, N]`.
        check: validate values (see `omp`).
        block_size: rows per cache-sized block on CPU (``None``: one block).
        backend: ``"auto"``, ``"native"`` or ``"torch"`` (see `omp`).

    Returns:
        `SparseCode` with `indices` and `coefficients` of shape `[..., k]`.

    Example:
        >>> import torch
        >>> from aectorch.coding import matching_pursuit
        >>> D = torch.nn.functional.normalize(torch.randn(200, 288), dim=0)
        >>> code = matching_pursuit(torch.randn(113, 200), D, sparsity=10)
        >>> code.coefficients.shape
        torch.Size([113, 10])
    """
    backend = default_backend() if backend is None else backend
    _validate(signals, dictionary, sparsity, gram, check, backend)
    return _run(_mp_block, signals, dictionary, sparsity, gram, block_size, backend)
