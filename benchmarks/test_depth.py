"""Training the depth MLP: aectorch's Levenberg-Marquardt against MINPACK, torch-levenberg-marquardt
and Adam, every method of a seed from the same weights (docs/performance.md says what each is).

``validation`` 0.15 is trainlm's split; 0 fits every sample without early stopping, and each
method's training MSE is divided by MINPACK's from the same start. ``AECTORCH_BENCH_SEEDS`` sets
the number of seeds.
"""

import copy
import functools
import os
import statistics
import time

import numpy as np
import pytest
import torch

from aectorch.depth import DepthMLP, fit_levenberg_marquardt, nguyen_widrow_
from aectorch.depth.levenberg_marquardt import _split
from benchmarks import harness

F64, NOISE_DEG = torch.float64, 0.02
EPOCHS = harness.size(5, 1000)
CASES = harness.size([(0.15, 200), (0.0, 200)], [(0.15, 500), (0.15, 5000), (0.15, 50000), (0.0, 1000)])


def eye_angles_deg(d: torch.Tensor) -> torch.Tensor:
    pursuit, vergence = torch.atan(0.1 / d), 2 * torch.atan(0.03 / d)
    return torch.rad2deg(torch.stack([pursuit, vergence, -pursuit, vergence], -1))


def depth_data(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    d = torch.rand(n, generator=g, dtype=F64) * 2 + 1
    return eye_angles_deg(d) + NOISE_DEG * torch.randn(n, 4, generator=g, dtype=F64), d[:, None]


@functools.cache
def held_out() -> tuple[torch.Tensor, torch.Tensor, float]:
    """Fresh samples and the noise floor on them: the MAE (mm) of the posterior median of d given q."""
    from scipy.special import logsumexp

    q, d = depth_data(harness.size(500, 10000), seed=10**6)
    grid = np.linspace(1.0, 3.0, 4001)
    angles = eye_angles_deg(torch.from_numpy(grid)).numpy()
    estimate = []
    for chunk in np.array_split(q.numpy(), max(1, len(q) // 500)):
        loglik = -((chunk[:, None, :] - angles[None]) ** 2).sum(-1) / (2 * NOISE_DEG**2)
        cdf = np.cumsum(np.exp(loglik - logsumexp(loglik, axis=1, keepdims=True)), axis=1)
        estimate += [np.interp(0.5, c, grid) for c in cdf]
    return q, d, float(np.abs(np.array(estimate) - d[:, 0].numpy()).mean() * 1e3)


def run_lm(model, q, d, seed, validation, **factors):
    fit = fit_levenberg_marquardt(model, q, d, seed=seed, max_epochs=EPOCHS, validation_fraction=validation, **factors)
    return {"epochs": fit.epochs, "stop": fit.stop_reason}


def run_minpack(model, q, d, seed, validation):
    from scipy.optimize import least_squares
    from torch.func import functional_call, jacrev, vmap

    train, _ = _split(len(q), validation, torch.Generator().manual_seed(seed))
    x, t = q[train], d[train]
    names, params = zip(*model.named_parameters())
    sizes, buffers = [p.numel() for p in params], dict(model.named_buffers())

    def residuals(theta, xs, ts):
        values = {n: v.view(p.shape) for n, v, p in zip(names, theta.split(sizes), params)}
        return (functional_call(model, (values, buffers), (xs,)) - ts).reshape(-1)

    per_sample = vmap(jacrev(lambda th, xi, ti: residuals(th, xi[None], ti[None])), in_dims=(None, 0, 0))
    with torch.no_grad():
        out = least_squares(lambda th: residuals(torch.from_numpy(th), x, t).numpy(),
                            torch.cat([p.detach().reshape(-1) for p in params]).numpy(),
                            jac=lambda th: per_sample(torch.from_numpy(th), x, t).reshape(len(x), -1).numpy(),
                            method="lm", max_nfev=EPOCHS)
        for p, v in zip(params, torch.from_numpy(out.x).split(sizes)):
            p.copy_(v.view(p.shape))
    return {"epochs": int(out.njev), "stop": {0: "max_nfev", 1: "gtol", 2: "ftol", 3: "xtol"}.get(out.status, "ftol+xtol")}


def run_early_stopped(step, model, q, d, seed, validation, patience=6):
    """``step(x, t)`` once per epoch (True: it gives up), then the best validation weights (no split: the last)."""
    train, val = _split(len(q), validation, torch.Generator().manual_seed(seed))
    loss = lambda: float((model(q[val].to(next(model.parameters()).dtype)) - d[val]).square().mean())  # noqa: E731
    best, fails, stop = (float("inf"), None), 0, "max_epochs"
    for epoch in range(1, EPOCHS + 1):
        gave_up = step(q[train], d[train])
        with torch.no_grad():
            value = loss() if len(val) else -float(epoch)
        best, fails = ((value, copy.deepcopy(model.state_dict())), 0) if value < best[0] else (best, fails + 1)
        if gave_up or fails >= patience:
            stop = "max_damping" if gave_up else "max_fail"
            break
    model.load_state_dict(best[1])
    return {"epochs": epoch, "stop": stop}


def run_torch_lm(model, q, d, seed, validation):
    import torch_levenberg_marquardt as lm
    module = lm.training.LevenbergMarquardtModule(
        model, loss_fn=lm.loss.MSELoss(), solve_method="cholesky",
        damping_strategy=lm.damping.StandardDampingStrategy(starting_value=1e-3, dec_factor=0.1, inc_factor=10.0))
    return run_early_stopped(lambda x, t: module.training_step(x, t)[2], model, q, d, seed, validation)


def run_adam(model, q, d, seed, validation):
    model.float()
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-2)

    def step(x, t):
        optimizer.zero_grad()
        (model(x.float()) - t.float()).square().mean().backward()
        optimizer.step()
        return False

    return run_early_stopped(step, model, q, d, seed, validation, patience=50)


METHODS = {"aectorch-lm": run_lm, "aectorch-lm-trainlm": functools.partial(run_lm, mu_dec=0.1, mu_inc=10.0),
           "scipy-minpack": run_minpack, "torch-levenberg-marquardt": run_torch_lm, "adam": run_adam}


@functools.cache
def fitted(method: str, n: int, seed: int, validation: float) -> dict:
    q, d = depth_data(n, seed)
    model = nguyen_widrow_(DepthMLP(dtype=F64).set_normalisation(q, d), torch.Generator().manual_seed(seed))
    start = time.perf_counter()
    info = METHODS[method](model, q, d, seed, validation)
    seconds = time.perf_counter() - start
    train, _ = _split(n, validation, torch.Generator().manual_seed(seed))
    q_test, d_test, floor = held_out()
    with torch.no_grad():
        fit, test = (model(x.to(next(model.parameters()).dtype)).double() for x in (q[train], q_test))
    return {**info, "seconds": seconds, "train_mse": float((fit - d[train]).square().mean()),
            "train_mae_mm": float((fit - d[train]).abs().mean() * 1e3),
            "test_over_floor": float((test - d_test).abs().mean() * 1e3) / floor}


@pytest.mark.parametrize(("validation", "size"), CASES)
@pytest.mark.parametrize("method", list(METHODS))
def test_depth(benchmark, method, validation, size):
    pytest.importorskip("torch_levenberg_marquardt") if method == "torch-levenberg-marquardt" else None
    seeds = range(int(os.environ.get("AECTORCH_BENCH_SEEDS", 0)) or harness.size(1, 5 if validation else 3))
    runs = benchmark.pedantic(lambda: [fitted.__wrapped__(method, size, seed, validation) for seed in seeds])
    row = {"variant": f"{method}, N={size}, validation {validation}", "method": method, "N": size,
           "validation": validation, "seeds": len(seeds), "stops": sorted({r["stop"] for r in runs}),
           **{k: statistics.median(r[k] for r in runs) for k in ("train_mae_mm", "test_over_floor", "epochs",
                                                                  "seconds", "train_mse")}}
    if validation == 0:
        ratios = [r["train_mse"] / fitted("scipy-minpack", size, s, 0.0)["train_mse"] for r, s in zip(runs, seeds)]
        row.update(train_mse_over_minpack=statistics.median(ratios), per_seed_train_mse_over_minpack=ratios)
    assert all(np.isfinite(r["train_mse"]) for r in runs)
    harness.record("depth", [row], benchmark)
