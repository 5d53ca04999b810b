"""Depth MLP training: aectorch's Levenberg-Marquardt versus MINPACK, torch-levenberg-marquardt and Adam.

The problem is the paper's depth network (sec. 2.4) on synthetic eye angles from the
geometry: distance d ~ U[1, 3] m, q = [atan(0.1/d), 2 atan(0.03/d), -atan(0.1/d),
2 atan(0.03/d)] in degrees plus 0.02 degrees of Gaussian noise per angle. The network is
`DepthMLP` (4-10-1, tansig, mapminmax), float64, with the same normalisation and the same
Nguyen-Widrow initial weights for every method of a seed. Compared, each in the same
process, for N training samples (medians over --seeds seeds):

  * ``aectorch-lm``: `fit_levenberg_marquardt` with its defaults, MATLAB trainlm's (15 % random
    validation split, max_fail 6, best validation weights, 1000 epochs at most) but for the
    damping factors, x1/3 / x2 (issue 21).
  * ``aectorch-lm-trainlm`` (not run unless named): the same with trainlm's factors,
    ``mu_dec=0.1, mu_inc=10``.
  * ``scipy-minpack``: ``scipy.optimize.least_squares(method="lm")`` on the same parameters
    through a numpy residual/Jacobian wrapper of the torch model (Jacobian by torch.func),
    on the same training samples (85 %), no validation (MINPACK has no early stopping),
    at most --minpack-max-nfev function evaluations; "epochs" are its Jacobian evaluations.
  * ``torch-levenberg-marquardt``: the PyPI package (``LevenbergMarquardtModule``, damping
    1e-3 x0.1 / x10, Cholesky), one full-batch ``training_step`` per epoch, with the same
    split and the same validation rule (max_fail 6, best weights restored) written here.
    It damps ``J^T J / N`` (mean, not sum) and gives up after 10 attempts per step.
  * ``adam``: ``torch.optim.Adam`` (full batch, float32 as users train it, lr --adam-lr = 3e-2,
    the best of 1e-2, 3e-2 and 1e-1 in a pilot at N = 5000), at most --adam-epochs epochs, the
    same split, best validation weights, patience 50 epochs.

--validation sets the validation fraction for every method (default 0.15, trainlm's); with 0
all N samples are fitted, there is no early stopping and each method keeps its last weights.

Reported: train MAE (on the fitted samples), test MAE on --test-size fresh samples, both in
mm, the test MAE relative to the noise floor (the MAE of the Bayes-optimal estimator, the
posterior median of d given q under the known prior and noise), epochs and wall time; and the
training MSE, also relative to MINPACK's from the same start when scipy-minpack is run.

Usage:
    python benchmarks/depth.py                 # N = 500, 5000, 50000; 5 seeds; 1 thread
    python benchmarks/depth.py --quick         # N = 500, 5000; 3 seeds
    python benchmarks/depth.py --sizes 5000 --seeds 2 --methods aectorch-lm adam
    # issue 21: training MSE against MINPACK's, validation off, 1000 epochs
    python benchmarks/depth.py --validation 0 --max-epochs 1000 --sizes 1000 --seeds 3 \
        --methods aectorch-lm aectorch-lm-trainlm scipy-minpack --json benchmarks/results/depth_minpack.json

Writes a table to stdout and JSON to benchmarks/results/depth.json (--json).
"""

from __future__ import annotations

import argparse
import collections
import copy
import importlib.metadata
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.machine import machine_info  # noqa: E402

from aectorch.depth import DepthMLP, fit_levenberg_marquardt, nguyen_widrow_  # noqa: E402

F64 = torch.float64
NOISE_DEG = 0.02
METHODS = ("aectorch-lm", "scipy-minpack", "torch-levenberg-marquardt", "adam")
EXTRA_METHODS = ("aectorch-lm-trainlm",)  # run only when named in --methods
TRAINLM_FACTORS = {"mu_dec": 0.1, "mu_inc": 10.0}


def eye_angles_deg(distance_m: torch.Tensor) -> torch.Tensor:
    pursuit = torch.atan(0.1 / distance_m)
    vergence = 2 * torch.atan(0.03 / distance_m)
    return torch.rad2deg(torch.stack([pursuit, vergence, -pursuit, vergence], -1))


def depth_data(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    d = torch.rand(n, generator=g, dtype=F64) * 2 + 1
    return eye_angles_deg(d) + NOISE_DEG * torch.randn(n, 4, generator=g, dtype=F64), d[:, None]


def bayes_floor_mm(q: torch.Tensor, d: torch.Tensor, grid: int = 4001) -> float:
    """MAE (mm) of the posterior median of d given q: the best any estimator can do."""
    from scipy.special import logsumexp

    d_grid = np.linspace(1.0, 3.0, grid)
    f = eye_angles_deg(torch.from_numpy(d_grid)).numpy()
    estimate = np.empty(len(q))
    qn = q.numpy()
    for s in range(0, len(qn), 500):
        loglik = -((qn[s : s + 500, None, :] - f[None]) ** 2).sum(-1) / (2 * NOISE_DEG**2)
        cdf = np.cumsum(np.exp(loglik - logsumexp(loglik, axis=1, keepdims=True)), axis=1)
        estimate[s : s + 500] = [np.interp(0.5, c, d_grid) for c in cdf]
    return float(np.abs(estimate - d[:, 0].numpy()).mean() * 1e3)


def mae_mm(model: torch.nn.Module, q: torch.Tensor, d: torch.Tensor) -> float:
    dtype = next(model.parameters()).dtype
    with torch.no_grad():
        return float((model(q.to(dtype)).double() - d).abs().mean() * 1e3)


def split(n: int, seed: int, fraction: float = 0.15) -> tuple[torch.Tensor, torch.Tensor]:
    """The split `fit_levenberg_marquardt(seed=seed, validation_fraction=fraction)` draws."""
    from aectorch.depth.levenberg_marquardt import _split

    return _split(n, fraction, torch.Generator().manual_seed(seed))


# ------------------------------------------------------------------------------------------ methods


def run_aectorch(model, q, d, seed, args, **factors):
    result = fit_levenberg_marquardt(
        model, q, d, seed=seed, max_epochs=args.max_epochs, validation_fraction=args.validation, **factors
    )
    return {"epochs": result.epochs, "stop": result.stop_reason, "best_epoch": result.best_epoch,
            "mu": result.mu, "gradient": result.gradient}  # fmt: skip


def run_aectorch_trainlm(model, q, d, seed, args):
    return run_aectorch(model, q, d, seed, args, **TRAINLM_FACTORS)


def run_minpack(model, q, d, seed, args):
    from scipy.optimize import least_squares
    from torch.func import functional_call, jacrev, vmap

    train, _ = split(len(q), seed, args.validation)
    x, t = q[train], d[train]
    names, params = zip(*model.named_parameters())
    sizes = [p.numel() for p in params]
    buffers = dict(model.named_buffers())

    def residuals(theta, xs, ts):
        values = {n: v.view(p.shape) for n, v, p in zip(names, theta.split(sizes), params)}
        return (functional_call(model, (values, buffers), (xs,)) - ts).reshape(-1)

    per_sample = vmap(jacrev(lambda th, xi, ti: residuals(th, xi[None], ti[None])), in_dims=(None, 0, 0))
    with torch.no_grad():
        fun = lambda th: residuals(torch.from_numpy(th), x, t).numpy()  # noqa: E731
        jac = lambda th: per_sample(torch.from_numpy(th), x, t).reshape(len(x), -1).numpy()  # noqa: E731
        theta0 = torch.cat([p.detach().reshape(-1) for p in params]).numpy()
        out = least_squares(fun, theta0, jac=jac, method="lm", max_nfev=args.minpack_max_nfev)
        theta = torch.from_numpy(out.x)
        for p, v in zip(params, theta.split(sizes)):
            p.copy_(v.view(p.shape))
    stop = {0: "max_nfev", 1: "gtol", 2: "ftol", 3: "xtol", 4: "ftol+xtol"}.get(out.status, str(out.status))
    return {"epochs": int(out.njev), "nfev": int(out.nfev), "njev": int(out.njev), "stop": stop}


def run_torch_lm(model, q, d, seed, args):
    from torch_levenberg_marquardt.damping import StandardDampingStrategy
    from torch_levenberg_marquardt.loss import MSELoss
    from torch_levenberg_marquardt.training import LevenbergMarquardtModule

    train, val = split(len(q), seed, args.validation)
    x, t, xv, tv = q[train], d[train], q[val], d[val]
    validate = len(val) > 0  # without a split: no early stopping, the last weights
    module = LevenbergMarquardtModule(
        model,
        loss_fn=MSELoss(),
        damping_strategy=StandardDampingStrategy(starting_value=1e-3, dec_factor=0.1, inc_factor=10.0),
        solve_method="cholesky",
    )
    with torch.no_grad():
        best = (float((model(xv) - tv).square().mean()) if validate else 0.0, module.flat_params.clone(), 0)
    fails, epoch, stop = 0, 0, "max_epochs"
    for epoch in range(1, args.max_epochs + 1):
        _, _, stop_training, _ = module.training_step(x, t)
        with torch.no_grad():
            v = float((model(xv) - tv).square().mean()) if validate else -float(epoch)  # no split: each is best
        if v < best[0]:
            best, fails = (v, module.flat_params.clone(), epoch), 0
        elif v > best[0]:
            fails += 1
        if stop_training:
            stop = "max_damping"
            break
        if fails >= 6:
            stop = "max_fail"
            break
    with torch.no_grad():
        module.flat_params.copy_(best[1])
    return {"epochs": epoch, "stop": stop, "best_epoch": best[2]}


def run_adam(model, q, d, seed, args):
    model.float()
    train, val = split(len(q), seed, args.validation)
    x, t, xv, tv = q[train].float(), d[train].float(), q[val].float(), d[val].float()
    validate = len(val) > 0  # without a split: no early stopping, the last weights
    optimizer = torch.optim.Adam(model.parameters(), lr=args.adam_lr)
    with torch.no_grad():
        best = (float((model(xv) - tv).square().mean()) if validate else 0.0, copy.deepcopy(model.state_dict()), 0)
    epoch, stop = 0, "max_epochs"
    for epoch in range(1, args.adam_epochs + 1):
        optimizer.zero_grad()
        (model(x) - t).square().mean().backward()
        optimizer.step()
        with torch.no_grad():
            v = float((model(xv) - tv).square().mean()) if validate else -float(epoch)  # no split: each is best
        if v < best[0]:
            best = (v, copy.deepcopy(model.state_dict()), epoch)
        elif epoch - best[2] >= 50:
            stop = "patience"
            break
    model.load_state_dict(best[1])
    return {"epochs": epoch, "stop": stop, "best_epoch": best[2]}


RUNNERS = {
    "aectorch-lm": run_aectorch,
    "aectorch-lm-trainlm": run_aectorch_trainlm,
    "scipy-minpack": run_minpack,
    "torch-levenberg-marquardt": run_torch_lm,
    "adam": run_adam,
}


def torch_lm_available() -> str | None:
    """None if the package imports, else why not (reported in the table)."""
    try:
        import torch_levenberg_marquardt  # noqa: F401
    except Exception as error:  # noqa: BLE001 - any import failure is reported, not raised
        return f"{type(error).__name__}: {error}"
    return None


# ------------------------------------------------------------------------------------------ driver


def initial_model(q: torch.Tensor, d: torch.Tensor, seed: int) -> DepthMLP:
    model = DepthMLP(dtype=F64).set_normalisation(q, d)
    return nguyen_widrow_(model, torch.Generator().manual_seed(seed))


def warm_up(methods: list[str], args) -> None:
    """First calls of torch.func / autograd pay one-off set-up costs (seconds); not timed."""
    q, d = depth_data(200, seed=12345)
    for name in methods:
        RUNNERS[name](initial_model(q, d, 0), q, d, 0, argparse.Namespace(**{**vars(args), "max_epochs": 3,
                      "adam_epochs": 3, "minpack_max_nfev": 3}))  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 5000, 50000])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS + EXTRA_METHODS)
    parser.add_argument("--max-epochs", type=int, default=1000, help="LM epochs at most (trainlm default)")
    parser.add_argument("--validation", type=float, default=0.15, help="validation fraction, 0 = none (trainlm: 0.15)")
    parser.add_argument("--adam-epochs", type=int, default=1000)
    parser.add_argument("--adam-lr", type=float, default=3e-2)
    parser.add_argument("--minpack-max-nfev", type=int, default=1000)
    parser.add_argument("--test-size", type=int, default=10000)
    parser.add_argument("--quick", action="store_true", help="N = 500, 5000; 3 seeds")
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "depth.json")
    args = parser.parse_args()
    if not 0.0 <= args.validation < 1.0:
        parser.error(f"--validation must be in [0, 1), got {args.validation}")
    if args.quick:
        args.sizes, args.seeds = [s for s in args.sizes if s <= 5000] or [500, 5000], min(args.seeds, 3)

    from threadpoolctl import threadpool_limits

    torch.set_num_threads(args.threads)
    threadpool_limits(args.threads)
    unavailable = torch_lm_available() if "torch-levenberg-marquardt" in args.methods else None
    methods = [m for m in args.methods if not (m == "torch-levenberg-marquardt" and unavailable)]
    q_test, d_test = depth_data(args.test_size, seed=10**6)
    floor = bayes_floor_mm(q_test, d_test)
    print(f"noise floor (Bayes posterior median) on {args.test_size} test samples: {floor:.3f} mm", flush=True)
    warm_up(methods, args)

    rows = []
    for n in args.sizes:
        for seed in range(args.seeds):
            q, d = depth_data(n, seed=seed)
            train, _ = split(n, seed, args.validation)
            start = initial_model(q, d, seed)
            for name in methods:
                model = copy.deepcopy(start)
                t0 = time.perf_counter()
                info = RUNNERS[name](model, q, d, seed, args)
                seconds = time.perf_counter() - t0
                row = {
                    "method": name,
                    "N": n,
                    "seed": seed,
                    "train_mae_mm": mae_mm(model, q[train], d[train]),
                    "test_mae_mm": mae_mm(model, q_test, d_test),
                    "train_mse": train_mse(model, q[train], d[train]),
                    "seconds": seconds,
                    **info,
                }
                row["test_over_floor"] = row["test_mae_mm"] / floor
                rows.append(row)
                print(
                    f"N={n:>6} seed={seed} {name:<26} train MSE {row['train_mse']:.4e}  "
                    f"train {row['train_mae_mm']:7.3f} mm  test "
                    f"{row['test_mae_mm']:7.3f} mm  x{row['test_over_floor']:.3f} floor  "
                    f"{row['epochs']:>5} epochs  {seconds:8.3f} s  {row['stop']}",
                    flush=True,
                )
    add_minpack_ratios(rows)
    summary = summarise(rows)
    print_table(summary, floor, unavailable, args)
    print_minpack_table(rows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        **machine_info(),
        "scipy": importlib.metadata.version("scipy"),
        "torch_levenberg_marquardt": package_version("torch-levenberg-marquardt"),
        "torch_levenberg_marquardt_unavailable": unavailable,
        "threads": args.threads,
        "seeds": args.seeds,
        "noise_deg": NOISE_DEG,
        "test_size": args.test_size,
        "noise_floor_mae_mm": floor,
        "max_epochs": args.max_epochs,
        "validation_fraction": args.validation,
        "lm_factors": {"aectorch-lm": lm_default_factors(), "aectorch-lm-trainlm": TRAINLM_FACTORS},
        "adam_epochs": args.adam_epochs,
        "adam_lr": args.adam_lr,
        "minpack_max_nfev": args.minpack_max_nfev,
        "network": "DepthMLP 4-10-1 tansig, mapminmax, Nguyen-Widrow init, float64 (Adam float32)",
    }
    args.json.write_text(json.dumps({"meta": meta, "summary": summary, "rows": rows}, indent=2))
    print(f"\nwrote {args.json}")


def train_mse(model: torch.nn.Module, q: torch.Tensor, d: torch.Tensor) -> float:
    dtype = next(model.parameters()).dtype
    with torch.no_grad():
        return float((model(q.to(dtype)).double() - d).square().mean())


def add_minpack_ratios(rows: list[dict]) -> None:
    """Each row's training MSE over MINPACK's on the same N and seed (same start), when it ran."""
    reference = {(r["N"], r["seed"]): r["train_mse"] for r in rows if r["method"] == "scipy-minpack"}
    for r in rows:
        if (r["N"], r["seed"]) in reference:
            r["train_mse_over_minpack"] = r["train_mse"] / reference[(r["N"], r["seed"])]


def lm_default_factors() -> dict[str, float]:
    import inspect

    defaults = inspect.signature(fit_levenberg_marquardt).parameters
    return {k: defaults[k].default for k in ("mu_dec", "mu_inc")}


def summarise(rows: list[dict]) -> list[dict]:
    groups = collections.defaultdict(list)
    for r in rows:
        groups[(r["N"], r["method"])].append(r)
    out = []
    for (n, method), group in groups.items():
        keys = ["train_mae_mm", "test_mae_mm", "test_over_floor", "epochs", "seconds", "train_mse"]
        keys += ["train_mse_over_minpack"] if all("train_mse_over_minpack" in r for r in group) else []
        med = {k: statistics.median(r[k] for r in group) for k in keys}
        stops = collections.Counter(r["stop"] for r in group).most_common()
        row = {"N": n, "method": method, "seeds": len(group), **med, "stops": dict(stops)}
        if "train_mse_over_minpack" in med:
            row["within_5_percent_of_minpack"] = sum(r["train_mse_over_minpack"] <= 1.05 for r in group)
        out.append(row)
    return out


def print_table(summary: list[dict], floor: float, unavailable: str | None, args) -> None:
    print(f"\nMedians of {args.seeds} seeds, {args.threads} thread(s); noise floor {floor:.2f} mm (test MAE of the Bayes estimator)\n")
    ratio = any("train_mse_over_minpack" in r for r in summary)
    extra = (" train MSE / MINPACK |", "---:|") if ratio else ("", "")
    print(f"| N | method | train MAE (mm) | test MAE (mm) | test / floor |{extra[0]} epochs | wall (s) | stop |")
    print(f"|---:|---|---:|---:|---:|{extra[1]}---:|---:|---|")
    for r in summary:
        stops = ", ".join(f"{k} {v}" if len(r["stops"]) > 1 else k for k, v in r["stops"].items())
        cell = ""
        if ratio:
            cell = f" {r['train_mse_over_minpack']:.3f} |" if "train_mse_over_minpack" in r else " |"
        print(
            f"| {r['N']:,} | {r['method']} | {r['train_mae_mm']:.2f} | {r['test_mae_mm']:.2f} | "
            f"{r['test_over_floor']:.3f} |{cell} {r['epochs']:g} | {r['seconds']:.3f} | {stops} |"
        )
    if unavailable:
        print(f"| | torch-levenberg-marquardt | not run: {unavailable} | | | | | |")


def print_minpack_table(rows: list[dict]) -> None:
    """Per seed, each method's training MSE against MINPACK's from the same start (issue 21)."""
    if not any("train_mse_over_minpack" in r for r in rows):
        return
    print("\nPer seed, training MSE against MINPACK's (epochs: Jacobian evaluations; nfev: MINPACK's function evaluations)\n")
    print("| N | seed | method | train MSE | / MINPACK | stop | epochs | nfev | final mu | gradient | test / floor | wall (s) |")
    print("|---:|---:|---|---:|---:|---|---:|---:|---:|---:|---:|---:|")
    for r in sorted(rows, key=lambda r: (r["N"], r["seed"])):
        mu = f"{r['mu']:.1e}" if "mu" in r else ""
        gradient = f"{r['gradient']:.1e}" if "gradient" in r else ""
        print(
            f"| {r['N']:,} | {r['seed']} | {r['method']} | {r['train_mse']:.4e} | {r['train_mse_over_minpack']:.3f} | "
            f"{r['stop']} | {r['epochs']} | {r.get('nfev', '')} | {mu} | {gradient} | {r['test_over_floor']:.3f} | "
            f"{r['seconds']:.2f} |"
        )


def package_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


if __name__ == "__main__":
    main()
