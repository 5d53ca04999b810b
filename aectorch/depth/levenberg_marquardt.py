"""Levenberg-Marquardt training of a small `nn.Module` on a sum of squared errors, as MATLAB's trainlm.

The paper trains its depth network with Levenberg-Marquardt (sec. 2.4, ref. [9])
in MATLAB, i.e. ``trainlm``. This module reproduces trainlm's algorithm and
defaults so that the same data give the same kind of network, with one
exception, the damping factors (see below):

* Every epoch: the Jacobian ``J`` of all training residuals ``e = model(x) - t``
  with respect to the flattened trainable parameters (`torch.func`), then
  ``JtJ = J^T J`` and ``g = J^T e``; then, starting from the current ``mu``,
  solve the damped normal equations ``(J^T J + mu I) dx = -J^T e`` by Cholesky
  and try ``x + dx``: if the training error decreases the step is taken and
  ``mu *= mu_dec``; if not (or if the matrix is not positive definite), ``mu *=
  mu_inc`` and the solve is retried within the same epoch, until the error
  decreases or ``mu > mu_max``.
* The default factors are ``mu_dec = 1/3`` and ``mu_inc = 2``, not trainlm's
  ``0.1`` and ``10`` (pass ``mu_dec=0.1, mu_inc=10.0`` for trainlm's exact
  schedule); they are the bounds of Nielsen's update (H. B. Nielsen, "Damping
  parameter in Marquardt's method", 1999; Madsen, Nielsen & Tingleff, "Methods
  for non-linear least squares problems", 2004, sec. 3.2: at most x1/3 after a
  success, x2 after a first failure). With trainlm's factors ``mu_dec *
  mu_inc = 1``, so ``mu`` only takes the values ``1e-3 * 10**k``: once the
  error creeps along a flat, curved valley, each epoch tries ``mu / 10``,
  fails, and steps with ``mu``, over-damped, and the error falls very slowly.
  On the depth network (1,000 samples, validation off,
  1,000 epochs) the training MSE ended about 7 % above MINPACK's in 2 of 3 seeds
  with ``stop_reason="max_epochs"`` (no stopping rule ended it early; ``mu``
  1e-5 to 1e-4, gradient 5e-5, both far from their limits), and on seed 0,
  688 of the 1,000 steps were taken at ``mu = 1e-3`` after ``1e-4`` had failed.
  As ``2 * 1/3 < 1``, a failure after a success lands between the two values
  and ``mu`` can settle anywhere (there: 10-50x lower); the same runs end at
  0.95-1.04x MINPACK's MSE (10 of 10 seeds; trainlm's factors 0.98-1.07x, 7 of
  10 within 1.05x) and get there in fewer epochs; with a validation split the
  test error is unchanged (`benchmarks/test_depth.py`, docs/performance.md).
* The damping is ``mu I`` (Levenberg's form, as trainlm), not Marquardt's
  ``mu diag(J^T J)`` that MINPACK (``scipy.optimize.least_squares(method="lm")``)
  uses with its own trust-region rule: same fixed point, different path.
* Stops, checked at the start of each epoch in trainlm's order: the training MSE
  reaches ``goal`` ("goal"), ``max_epochs`` ("max_epochs"), the gradient norm of
  the training MSE, ``2 ||J^T e|| / n``, falls to ``min_grad`` ("min_grad"),
  ``mu >= mu_max`` ("max_mu"), or the validation MSE has risen ``max_fail``
  epochs in a row since its best ("max_fail"). Whatever the reason, the model
  gets the weights of the best validation epoch (the last ones without a
  validation split), as trainlm returns ``best.net``.
* The work is done in float64 by default (``dtype``), whatever the model's
  dtype; the result is copied back into the model's own parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import torch
from torch import nn
from torch.func import functional_call, jacfwd, jacrev, vmap

from aectorch._checks import check_int, check_real, is_real
from aectorch.depth.mlp import nguyen_widrow_

__all__ = ["LevenbergMarquardtResult", "fit_levenberg_marquardt", "STOP_REASONS"]

#: The values of `LevenbergMarquardtResult.stop_reason`.
STOP_REASONS = ("goal", "max_epochs", "min_grad", "max_mu", "max_fail")

_MU_FLOOR = 1e-20  # trainlm: mu = max(mu * mu_dec, 1e-20)


@dataclass
class LevenbergMarquardtResult:
    """What `fit_levenberg_marquardt` returns.

    Attributes:
        epochs: epochs run (trainlm's ``tr.num_epochs``).
        stop_reason: one of ``"goal"``, ``"max_epochs"``, ``"min_grad"``,
            ``"max_mu"``, ``"max_fail"``.
        train_loss: training MSE after each epoch, ``epochs + 1`` values
            (index 0: before training).
        val_loss: validation MSE after each epoch, ``epochs + 1`` values, or
            empty without a validation split.
        best_epoch: the epoch whose weights the model holds now.
        mu: damping at the end.
        gradient: ``2 ||J^T e|| / n`` at the last epoch, the gradient norm of the training MSE.
        train_indices, val_indices: which samples were used for training and
            for validation (sorted; `val_indices` empty without a split).
    """

    epochs: int
    stop_reason: str
    train_loss: list[float]
    val_loss: list[float]
    best_epoch: int
    mu: float
    gradient: float
    train_indices: torch.Tensor = field(repr=False)
    val_indices: torch.Tensor = field(repr=False)


def _check_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    if not (is_real(value) and (value >= 0 if allow_zero else value > 0)):
        raise ValueError(f"{name} must be a finite {'non-negative' if allow_zero else 'positive'} number, got {value!r}")


def _validate_arguments(
    max_epochs, validation_fraction, goal, min_grad, mu, mu_dec, mu_inc, mu_max, max_fail, init, jacobian, chunk_size
) -> None:
    check_int(max_epochs, "max_epochs", 0)
    check_int(max_fail, "max_fail")
    if chunk_size is not None:
        check_int(chunk_size, "chunk_size")
    if not (isinstance(validation_fraction, (int, float)) and 0.0 <= validation_fraction < 1.0):
        raise ValueError(f"validation_fraction must be in [0, 1), got {validation_fraction!r}")
    _check_positive("goal", goal, allow_zero=True)
    _check_positive("min_grad", min_grad, allow_zero=True)
    _check_positive("mu", mu)
    _check_positive("mu_max", mu_max)
    if not (is_real(mu_dec) and 0.0 < mu_dec < 1.0):
        raise ValueError(f"mu_dec must be in (0, 1), got {mu_dec!r}")
    check_real(mu_inc, "mu_inc", above=1.0)
    if init not in (None, "nguyen-widrow"):
        raise ValueError(f"init must be None or 'nguyen-widrow', got {init!r}")
    if jacobian not in ("reverse", "forward"):
        raise ValueError(f"jacobian must be 'reverse' or 'forward', got {jacobian!r}")


def _validate_data(inputs: torch.Tensor, targets: torch.Tensor) -> None:
    for name, value in (("inputs", inputs), ("targets", targets)):
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        if value.ndim < 1 or value.shape[0] < 1:
            raise ValueError(f"{name} must have shape [N >= 1, ...], got {tuple(value.shape)}")
        if not value.is_floating_point():
            raise TypeError(f"{name} must be floating point, got {value.dtype}")
        if not torch.isfinite(value).all():
            bad = int((~torch.isfinite(value)).sum())
            raise ValueError(f"{name} must be finite, got {bad} NaN/inf value(s)")
    if inputs.shape[0] != targets.shape[0]:
        raise ValueError(
            f"inputs and targets must have the same number of samples (first dimension), "
            f"got inputs {tuple(inputs.shape)} and targets {tuple(targets.shape)}"
        )


def _split(n: int, fraction: float, generator: torch.Generator | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Random train/validation indices; ``round(fraction * n)`` validation samples (dividerand)."""
    n_val = int(math.floor(fraction * n + 0.5))
    if fraction > 0 and n_val < 1:
        raise ValueError(
            f"validation_fraction={fraction} of {n} samples gives no validation sample: "
            f"pass at least {math.ceil(0.5 / fraction)} samples or validation_fraction=0.0"
        )
    if n - n_val < 1:
        raise ValueError(f"validation_fraction={fraction} of {n} samples leaves no training sample")
    perm = torch.randperm(n, generator=generator)
    return perm[n_val:].sort().values, perm[:n_val].sort().values


class _Residuals:
    """The model as a function of one flat parameter vector: predictions, SSE, normal equations."""

    def __init__(self, model: nn.Module, dtype: torch.dtype, jacobian: str, chunk_size: int | None) -> None:
        self.model = model
        named = [(n, p) for n, p in model.named_parameters() if p.requires_grad]
        if not named:
            raise ValueError(f"model must have at least one trainable parameter, got none in {type(model).__name__}")
        self.names = [n for n, _ in named]
        self.shapes = [p.shape for _, p in named]
        self.sizes = [p.numel() for _, p in named]
        self.trainable = [p for _, p in named]
        cast = lambda t: t.detach().to(dtype) if t.is_floating_point() else t.detach()  # noqa: E731
        # Frozen parameters and buffers (the normalisation ranges) are constants, in `dtype` too.
        self.constants = {n: cast(p) for n, p in model.named_parameters() if not p.requires_grad}
        self.constants.update({n: cast(b) for n, b in model.named_buffers()})
        self.theta0 = torch.cat([cast(p).reshape(-1) for p in self.trainable])
        self.jacobian = jacobian
        self.chunk_size = chunk_size

    def unflatten(self, theta: torch.Tensor) -> dict[str, torch.Tensor]:
        return {n: t.view(s) for n, t, s in zip(self.names, theta.split(self.sizes), self.shapes)}

    def predict(self, theta: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return functional_call(self.model, (self.unflatten(theta), self.constants), (x,))

    def sse(self, theta: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return (self.predict(theta, x) - t).square().sum()

    def _jacobian(self, theta: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.jacobian == "reverse":
            # One reverse pass per sample, vmapped: cheap when outputs per sample are few.
            def one(theta_, x_, t_):
                r = (self.predict(theta_, x_.unsqueeze(0)).squeeze(0) - t_).reshape(-1)
                return r, r

            jac, r = vmap(jacrev(one, has_aux=True), in_dims=(None, 0, 0))(theta, x, t)
        else:
            # Forward mode over the whole batch: exact even for models that mix samples.
            def full(theta_):
                r = (self.predict(theta_, x) - t).reshape(-1)
                return r, r

            jac, r = jacfwd(full, has_aux=True)(theta)
        return jac.reshape(-1, theta.numel()), r.reshape(-1)

    def normal_equations(
        self, theta: torch.Tensor, x: torch.Tensor, t: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(J^T J, J^T e, e^T e)`` over all samples, accumulated over row chunks."""
        n = x.shape[0]
        step = n if self.chunk_size is None else self.chunk_size
        jtj = theta.new_zeros(theta.numel(), theta.numel())
        jte = theta.new_zeros(theta.numel())
        sse = theta.new_zeros(())
        for start in range(0, n, step):
            jac, r = self._jacobian(theta, x[start : start + step], t[start : start + step])
            jtj.addmm_(jac.t(), jac)
            jte.addmv_(jac.t(), r)
            sse += r.dot(r)
        return jtj, jte, sse

    @torch.no_grad()
    def write_back(self, theta: torch.Tensor) -> None:
        for p, value in zip(self.trainable, theta.split(self.sizes)):
            p.copy_(value.view(p.shape).to(p.dtype))


def fit_levenberg_marquardt(
    model: nn.Module,
    inputs: torch.Tensor,
    targets: torch.Tensor,
    *,
    max_epochs: int = 1000,
    validation_fraction: float = 0.15,
    seed: int | None = None,
    goal: float = 0.0,
    min_grad: float = 1e-7,
    mu: float = 1e-3,
    mu_dec: float = 1 / 3,
    mu_inc: float = 2.0,
    mu_max: float = 1e10,
    max_fail: int = 6,
    init: str | None = None,
    normalise: bool = True,
    dtype: torch.dtype | None = torch.float64,
    jacobian: str = "reverse",
    chunk_size: int | None = None,
    progress: bool = False,
    callback: Callable[[int, float, float], None] | None = None,
) -> LevenbergMarquardtResult:
    """Train `model` in place on the sum of squared errors with Levenberg-Marquardt (MATLAB trainlm).

    Defaults are trainlm's except the damping factors: ``mu = 1e-3``, ``x1/3``
    after a successful step, ``x2`` after a failed one (trainlm: ``x0.1`` and
    ``x10``; pass ``mu_dec=0.1, mu_inc=10.0`` for its exact schedule), retried
    within the epoch until the error decreases or ``mu > mu_max = 1e10``; 1000
    epochs, goal 0, ``min_grad = 1e-7``, and a random 15 % validation split with
    ``max_fail = 6``. See the module docstring for the algorithm, the stop
    reasons and why the factors differ from trainlm's.

    Before training, if ``normalise`` and the model has a ``set_normalisation``
    method (`DepthMLP` has), it is called with all `inputs` and `targets`, the
    validation samples included, as MATLAB configures mapminmax on all the data
    given to ``train`` before dividing it. With ``init="nguyen-widrow"`` the
    weights are then drawn by `nguyen_widrow_` from the `seed`; with ``None``
    the model's current weights are the starting point.

    Args:
        model: any small module; trainable parameters are all those with
            ``requires_grad``. With ``jacobian="reverse"`` (default), samples must
            be independent (no batch statistics): the Jacobian is one vmapped
            reverse pass per sample. ``"forward"`` differentiates the whole batch
            in forward mode (one pass per parameter), exact for any model.
        inputs: `[N, ...]`, what ``model`` takes.
        targets: `[N, ...]`, the shape of ``model(inputs)``; `[N]` is accepted
            for an output of `[N, 1]`.
        max_epochs: trainlm ``epochs``.
        validation_fraction: fraction of samples (rounded) held out for early
            stopping; 0.0 turns validation off.
        seed: seeds the split and the Nguyen-Widrow weights (``None``: torch's
            global generator).
        goal: stop when the training MSE is at most this.
        min_grad: stop when ``2 ||J^T e|| / n_train`` is at most this.
        mu, mu_dec, mu_inc, mu_max: the damping schedule: start, factor after
            a successful step, factor after a failed one, ceiling. Defaults
            ``1e-3, 1/3, 2, 1e10``; trainlm's are ``1e-3, 0.1, 10, 1e10``.
        max_fail: validation epochs without improvement before stopping.
        init: ``None`` (keep the weights) or ``"nguyen-widrow"``.
        normalise: call ``model.set_normalisation(inputs, targets)`` if it exists.
        dtype: the dtype of the computation (float64 by default); ``None`` uses
            the model's parameters' dtype.
        jacobian: ``"reverse"`` or ``"forward"`` (see `model`).
        chunk_size: compute ``J^T J`` over chunks of this many samples to bound
            memory (``None``: all at once; ``J`` is ``[N * outputs, n_params]``).
        progress: show a tqdm progress bar.
        callback: called after every epoch with ``(epoch, train_mse, val_mse)``.

    Returns:
        A `LevenbergMarquardtResult`; the model holds the best weights.

    Example:
        >>> import torch
        >>> from aectorch.depth import DepthMLP, fit_levenberg_marquardt
        >>> g = torch.Generator().manual_seed(0)
        >>> x = torch.rand(200, 1, generator=g) * 4 - 2
        >>> y = torch.sin(x)
        >>> model = DepthMLP(in_features=1, hidden=5, out_features=1)
        >>> result = fit_levenberg_marquardt(model, x, y, max_epochs=50, seed=0, init="nguyen-widrow")
        >>> result.epochs, result.stop_reason, len(result.train_loss)
        (50, 'max_epochs', 51)
        >>> with torch.no_grad():
        ...     print(float((model(x) - y).abs().max()) < 1e-2)
        True
    """
    if not isinstance(model, nn.Module):
        raise TypeError(f"model must be an nn.Module, got {type(model).__name__}")
    _validate_arguments(
        max_epochs, validation_fraction, goal, min_grad, mu, mu_dec, mu_inc, mu_max, max_fail, init, jacobian, chunk_size
    )
    _validate_data(inputs, targets)
    try:
        first = next(p for p in model.parameters() if p.requires_grad)
    except StopIteration:
        raise ValueError(f"model must have at least one trainable parameter, got none in {type(model).__name__}") from None
    device = first.device
    dtype = first.dtype if dtype is None else dtype
    if not dtype.is_floating_point:
        raise ValueError(f"dtype must be a floating-point dtype, got {dtype}")
    n = inputs.shape[0]
    generator = None if seed is None else torch.Generator().manual_seed(int(seed))
    train_idx, val_idx = _split(n, float(validation_fraction), generator)

    # The output shape does not depend on the weights: check it before touching the model.
    with torch.no_grad():
        out_shape = (n, *model(inputs[:1].to(device=device, dtype=first.dtype)).shape[1:])
    if targets.shape != out_shape and not (targets.ndim == 1 and out_shape == (n, 1)):
        raise ValueError(f"targets must have the shape of model(inputs), {out_shape}, got {tuple(targets.shape)}")
    if normalise and callable(getattr(model, "set_normalisation", None)):
        model.set_normalisation(  # type: ignore[operator]  # callable: checked above
            inputs.to(device=device, dtype=first.dtype), targets.to(device=device, dtype=first.dtype))
    if init == "nguyen-widrow":
        nguyen_widrow_(model, generator)

    problem = _Residuals(model, dtype, jacobian, chunk_size)
    x = inputs.to(device=device, dtype=dtype)
    t = targets.to(device=device, dtype=dtype).reshape(out_shape)
    with torch.no_grad():
        if not torch.isfinite(problem.predict(problem.theta0, x)).all():
            raise ValueError("model(inputs) is not finite with the initial weights")

    x_train, t_train = x[train_idx.to(device)], t[train_idx.to(device)]
    validate = val_idx.numel() > 0
    x_val, t_val = x[val_idx.to(device)], t[val_idx.to(device)]
    n_res = t_train.numel()
    n_val_res = max(t_val.numel(), 1)

    with torch.no_grad():
        return _train(
            problem, x_train, t_train, x_val, t_val, validate, n_res, n_val_res, train_idx, val_idx,
            max_epochs=max_epochs, goal=goal, min_grad=min_grad, mu=float(mu), mu_dec=mu_dec, mu_inc=mu_inc,
            mu_max=mu_max, max_fail=max_fail, progress=progress, callback=callback,
        )  # fmt: skip


def _stop_reason(epoch: int, perf: float, gradient: float, mu: float, val_fail: int | None, *, max_epochs: int,
                 goal: float, min_grad: float, mu_max: float, max_fail: int) -> str | None:
    """trainlm's stopping criteria, in its order, before each epoch (``val_fail`` None: no
    validation set); ``None`` to go on."""
    if perf <= goal:
        return "goal"
    if epoch == max_epochs:
        return "max_epochs"
    if gradient <= min_grad:
        return "min_grad"
    if mu >= mu_max:
        return "max_mu"
    if val_fail is not None and val_fail >= max_fail:
        return "max_fail"
    return None


def _damped_step(problem: "_Residuals", theta: torch.Tensor, jtj: torch.Tensor, jte: torch.Tensor, sse: torch.Tensor,
                 mu: float, eye: torch.Tensor, x_train: torch.Tensor, t_train: torch.Tensor, *, mu_dec: float,
                 mu_inc: float, mu_max: float) -> tuple[torch.Tensor, float, bool]:
    """Raise ``mu`` until a damped Gauss-Newton step lowers the training error (then lower it):
    ``(theta, mu, accepted)``."""
    while mu <= mu_max:
        factor, info = torch.linalg.cholesky_ex(jtj + mu * eye)
        if int(info) == 0:  # not positive definite counts as a failed step, as in trainlm
            candidate = theta + torch.cholesky_solve(-jte[:, None], factor)[:, 0]
            sse_new = float(problem.sse(candidate, x_train, t_train))
            if math.isfinite(sse_new) and sse_new < float(sse):
                return candidate, max(mu * mu_dec, _MU_FLOOR), True
        mu *= mu_inc
    return theta, mu, False


def _train(
    problem: _Residuals,
    x_train: torch.Tensor,
    t_train: torch.Tensor,
    x_val: torch.Tensor,
    t_val: torch.Tensor,
    validate: bool,
    n_res: int,
    n_val_res: int,
    train_idx: torch.Tensor,
    val_idx: torch.Tensor,
    *,
    max_epochs: int,
    goal: float,
    min_grad: float,
    mu: float,
    mu_dec: float,
    mu_inc: float,
    mu_max: float,
    max_fail: int,
    progress: bool,
    callback: Callable[[int, float, float], None] | None,
) -> LevenbergMarquardtResult:
    from tqdm.auto import tqdm

    theta = problem.theta0.clone()
    eye = torch.eye(theta.numel(), dtype=theta.dtype, device=theta.device)
    jtj, jte, sse = problem.normal_equations(theta, x_train, t_train)
    perf = float(sse) / n_res
    gradient = 2.0 * float(jte.norm()) / n_res
    vperf = float(problem.sse(theta, x_val, t_val)) / n_val_res if validate else math.nan
    train_loss, val_loss = [perf], ([vperf] if validate else [])
    best_theta, best_vperf, best_epoch, val_fail = theta, vperf, 0, 0

    bar = tqdm(total=max_epochs, disable=not progress, desc="Levenberg-Marquardt", leave=False)
    epoch, reason = 0, "max_epochs"
    try:
        for epoch in range(max_epochs + 1):
            reason = _stop_reason(  # type: ignore[assignment]  # a str at the last epoch
                epoch, perf, gradient, mu, val_fail if validate else None, max_epochs=max_epochs,
                goal=goal, min_grad=min_grad, mu_max=mu_max, max_fail=max_fail)
            if reason is not None:
                break
            theta, mu, accepted = _damped_step(problem, theta, jtj, jte, sse, mu, eye, x_train, t_train,
                                               mu_dec=mu_dec, mu_inc=mu_inc, mu_max=mu_max)

            if accepted:
                jtj, jte, sse = problem.normal_equations(theta, x_train, t_train)
                perf = float(sse) / n_res
                gradient = 2.0 * float(jte.norm()) / n_res
                if validate:
                    vperf = float(problem.sse(theta, x_val, t_val)) / n_val_res
            train_loss.append(perf)
            if validate:
                val_loss.append(vperf)
                if vperf < best_vperf:
                    best_theta, best_vperf, best_epoch, val_fail = theta, vperf, epoch + 1, 0
                elif vperf > best_vperf:
                    val_fail += 1
            elif accepted:
                best_theta, best_epoch = theta, epoch + 1
            bar.update(1)
            bar.set_postfix(mse=f"{perf:.3g}", mu=f"{mu:.0e}", val_fail=val_fail, refresh=False)
            if callback is not None:
                callback(epoch + 1, perf, vperf)
    finally:
        bar.close()

    problem.write_back(best_theta)
    return LevenbergMarquardtResult(
        epochs=epoch,
        stop_reason=reason,
        train_loss=train_loss,
        val_loss=val_loss,
        best_epoch=best_epoch,
        mu=mu,
        gradient=gradient,
        train_indices=train_idx,
        val_indices=val_idx,
    )
