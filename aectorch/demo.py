"""Binocular sparse-coding demonstration: dictionaries learned from synthetic stereo pairs.

A stand-in for the full experiment until the joint learning framework lands. Each step draws
pink-noise textures (1/f^alpha amplitude spectrum, like natural images), makes stereo pairs
from them by shifting the right eye's window by a random horizontal disparity, codes the pairs
with a `BinocularEncoder` and takes one dictionary-learning step on the AEC reward (minus the
summed coarse + fine reconstruction errors). `run_demo` writes a figure, metrics and the
trained encoder into a run folder.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path

import torch
from torch import Tensor

from aectorch.coding import BinocularEncoder
from aectorch.config import DemoConfig
from aectorch.sim.textures import pink_noise_images

__all__ = ["pink_noise_images", "stereo_pair", "evaluate_disparities", "run_demo"]

IMAGE_HEIGHT, IMAGE_WIDTH = 240, 320
_SHOWN_ATOMS = 32


def stereo_pair(
    textures: Tensor, disparity_px: Tensor, *, size: tuple[int, int] = (IMAGE_HEIGHT, IMAGE_WIDTH)
) -> tuple[Tensor, Tensor]:
    """Cut a stereo pair from each texture: a central window and the same window shifted sideways.

    ``left[b, y, x] = textures[b, top + y, x0 + x]`` and
    ``right[b, y, x] = textures[b, top + y, x0 + x + disparity_px[b]]``, where ``(top, x0)`` is
    the corner of the central window. A positive disparity therefore moves the right eye's
    window to the right (its image content appears shifted left).

    Args:
        textures: grey textures at least as wide as the window plus twice the largest |disparity|.
        disparity_px: integer horizontal disparity per texture, in pixels.
        size: (height, width) of the output images (default 240 x 320).

    Returns:
        left, right: the two eyes' images, same dtype and device as `textures`.

    Shape:
        - textures: `[B, H, W]` with ``H >= size[0]`` and ``W >= size[1] + 2 max|d|``.
        - disparity_px: `[B]`, integer dtype.
        - left, right: `[B, size[0], size[1]]`.

    Example:
        >>> tex = torch.arange(2 * 4 * 12.0).reshape(2, 4, 12)
        >>> left, right = stereo_pair(tex, torch.tensor([0, 2]), size=(2, 6))
        >>> right[1, 0] - left[1, 0]
        tensor([2., 2., 2., 2., 2., 2.])
    """
    if textures.ndim != 3:
        raise ValueError(f"textures must be [B, H, W], got shape {tuple(textures.shape)}")
    b, h, w = textures.shape
    if disparity_px.shape != (b,):
        raise ValueError(
            f"disparity_px must have shape [B] = [{b}], got {tuple(disparity_px.shape)}"
        )
    if disparity_px.dtype.is_floating_point or disparity_px.dtype.is_complex:
        raise TypeError(f"disparity_px must be an integer tensor, got {disparity_px.dtype}")
    out_h, out_w = size
    top, x0 = (h - out_h) // 2, (w - out_w) // 2
    if out_h > h or out_w > w:
        raise ValueError(f"textures of shape {tuple(textures.shape)} are smaller than {size}")
    if b:
        d_min, d_max = disparity_px.aminmax()
        if int(d_min) < -x0 or int(d_max) > w - out_w - x0:
            raise ValueError(
                f"disparity_px must lie in [{-x0}, {w - out_w - x0}] for textures {w} px wide "
                f"and a {out_w} px window, got [{int(d_min)}, {int(d_max)}]"
            )
    rows = textures[:, top : top + out_h]
    left = rows[:, :, x0 : x0 + out_w]
    columns = x0 + torch.arange(out_w, device=textures.device) + disparity_px.to(textures.device)[:, None]
    right = rows.gather(2, columns[:, None, :].expand(b, out_h, out_w))
    return left, right


def _textures(batch: int, max_disparity_px: int, generator: torch.Generator, device) -> Tensor:
    return pink_noise_images(
        batch, IMAGE_HEIGHT, IMAGE_WIDTH + 2 * max_disparity_px, generator=generator, device=device
    )


@torch.no_grad()
def evaluate_disparities(encoder: BinocularEncoder, textures: Tensor, max_disparity_px: int) -> Tensor:
    """Mean reconstruction error per |disparity| and scale, on fixed textures.

    For every d in 0..max_disparity_px the textures are coded at disparities +d and -d (once
    for d = 0) and the per-scale errors are averaged over textures and signs.

    Returns:
        `[max_disparity_px + 1, n_scales]` errors (the per-scale reward is minus this).
    """
    rows = []
    for d in range(max_disparity_px + 1):
        signs = (1,) if d == 0 else (1, -1)
        errs = []
        for s in signs:
            disparity = torch.full((textures.shape[0],), s * d, dtype=torch.long, device=textures.device)
            out = encoder(*stereo_pair(textures, disparity), check=False)
            errs.append(out.errors.mean(0))
        rows.append(torch.stack(errs).mean(0))
    return torch.stack(rows)


def _moving_average(values: list[float], window: int) -> tuple[list[int], list[float]]:
    window = max(1, min(window, len(values)))
    csum = [0.0]
    for v in values:
        csum.append(csum[-1] + v)
    avg = [(csum[i + window] - csum[i]) / window for i in range(len(values) - window + 1)]
    return list(range(window - 1, len(values))), avg


def _atom_mosaic(atoms: Tensor, columns: int = 8, patch: int = 10) -> Tensor:
    """Tile binocular atoms `[2 p^2, n]` as left|right pairs in a grid, NaN as separators."""
    n = atoms.shape[1]
    rows = math.ceil(n / columns)
    cell_h, cell_w = patch + 2, 2 * patch + 3  # 1 px gap between eyes, 2 px between atoms
    mosaic = torch.full((rows * cell_h, columns * cell_w), float("nan"))
    for i in range(n):
        atom = atoms[:, i].float().cpu()
        atom = atom / atom.abs().max().clamp_min(1e-12)
        left, right = atom[: patch * patch], atom[patch * patch :]
        r, c = divmod(i, columns)
        y, x = r * cell_h + 1, c * cell_w + 1
        mosaic[y : y + patch, x : x + patch] = left.reshape(patch, patch)
        mosaic[y : y + patch, x + patch + 1 : x + 2 * patch + 1] = right.reshape(patch, patch)
    return mosaic


def _write_figure(path: Path, cfg: DemoConfig, rewards: list[float], before: Tensor,
                  after: Tensor, scale_names: list[str], atoms: Tensor, atom_ids: list[int]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 8.5), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 1.1])
    ax_a = fig.add_subplot(grid[0, 0])
    ax_b = fig.add_subplot(grid[0, 1])
    ax_c = fig.add_subplot(grid[1, :])

    steps = list(range(1, len(rewards) + 1))
    window = max(5, len(rewards) // 15)
    ax_a.plot(steps, rewards, color="0.7", lw=0.8, label="per step (batch mean)")
    idx, avg = _moving_average(rewards, window)
    ax_a.plot([steps[i] for i in idx], avg, color="C0", lw=2, label=f"moving average ({window} steps)")
    ax_a.set(xlabel="training step", ylabel="reward  -(e$^C$ + e$^F$)",
             title="(a) reward during training")
    ax_a.legend(loc="lower right")
    ax_a.grid(alpha=0.3)

    d = list(range(before.shape[0]))
    for j, name in enumerate(scale_names):
        ax_b.plot(d, (-before[:, j]).tolist(), "--o", color=f"C{j}", ms=4, label=f"{name}, before")
        ax_b.plot(d, (-after[:, j]).tolist(), "-o", color=f"C{j}", ms=4, label=f"{name}, after")
    ax_b.set(xlabel="|disparity| (px of the 320 x 240 image)", ylabel="reward of the scale  -e$^j$",
             title=f"(b) reward vs disparity on {cfg.batch_size} held-out textures")
    ax_b.legend(ncol=2, fontsize=9)
    ax_b.grid(alpha=0.3)

    mosaic = _atom_mosaic(atoms)
    cmap = plt.get_cmap("gray").with_extremes(bad="white")
    ax_c.imshow(mosaic.numpy(), cmap=cmap, vmin=-1, vmax=1, interpolation="nearest")
    ax_c.set_axis_off()
    ax_c.set_title(f"(c) the {len(atom_ids)} most used coarse atoms after training, "
                   "each as left | right 10 x 10 half")

    fig.suptitle(
        f"aectorch binocular sparse-coding demo: {cfg.steps} steps x {cfg.batch_size} stereo pairs, "
        f"{cfg.algorithm.upper()}, lr {cfg.lr}, disparity uniform in ±{cfg.max_disparity_px} px"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_demo(cfg: DemoConfig, run_dir: str | Path = ".", *, progress: bool = True) -> dict:
    """Train a `BinocularEncoder` on random stereo pairs and write figure, metrics and weights.

    Args:
        cfg: the demo's config.
        run_dir: folder for ``figures/demo.png``, ``metrics.json``, ``encoder.pt`` and the
            TensorBoard events (``tensorboard/``).
        progress: show a tqdm progress bar.

    Returns:
        The metrics also written to ``metrics.json``.
    """
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    device = torch.device(cfg.device)
    # Atoms are drawn on the CPU (SparseDictionary's contract); images on the run's device.
    init_gen = torch.Generator().manual_seed(cfg.seed)
    data_gen = torch.Generator(device=device).manual_seed(cfg.seed + 1)
    eval_gen = torch.Generator(device=device).manual_seed(cfg.seed + 2)

    encoder = BinocularEncoder(algorithm=cfg.algorithm, lr=cfg.lr, generator=init_gen, device=device)
    scale_names = [s.name for s in encoder.scales]
    eval_textures = _textures(cfg.batch_size, cfg.max_disparity_px, eval_gen, device)
    before = evaluate_disparities(encoder, eval_textures, cfg.max_disparity_px).cpu()

    writer = SummaryWriter(log_dir=str(run_dir / "tensorboard"))
    rewards: list[Tensor] = []
    errors: list[Tensor] = []
    start = time.perf_counter()
    bar = tqdm(range(1, cfg.steps + 1), desc="learning dictionaries", unit="step",
               disable=not progress, dynamic_ncols=True)
    with torch.no_grad():
        for step in bar:
            textures = _textures(cfg.batch_size, cfg.max_disparity_px, data_gen, device)
            disparity = torch.randint(-cfg.max_disparity_px, cfg.max_disparity_px + 1,
                                      (cfg.batch_size,), generator=data_gen, device=device)
            out = encoder(*stereo_pair(textures, disparity), check=False)
            encoder.learn_(out, lr=cfg.lr)
            rewards.append(out.reward.mean())
            errors.append(out.errors.mean(0))
            if step % cfg.log_every == 0 or step == cfg.steps:
                reward, errs = float(rewards[-1]), errors[-1].tolist()
                writer.add_scalar("reward", reward, step)
                for name, e in zip(scale_names, errs):
                    writer.add_scalar(f"error/{name}", e, step)
                bar.set_postfix(reward=f"{reward:.3f}")
    bar.close()
    train_seconds = time.perf_counter() - start
    writer.close()

    after = evaluate_disparities(encoder, eval_textures, cfg.max_disparity_px).cpu()
    reward_list = torch.stack(rewards).tolist()
    window = min(len(reward_list), max(1, cfg.steps // 10))
    first, last = reward_list[:window], reward_list[-window:]

    # Atoms to show: the coarse atoms used most on the held-out textures at zero disparity.
    coarse = encoder.dictionaries[scale_names[0]]
    with torch.no_grad():
        zero = torch.zeros(eval_textures.shape[0], dtype=torch.long, device=device)
        usage = encoder(*stereo_pair(eval_textures, zero)).features[:, : coarse.num_atoms].sum(0)
    atom_ids = usage.argsort(descending=True)[:_SHOWN_ATOMS].tolist()
    atoms = coarse.atoms.detach()[:, atom_ids].cpu()

    figure = run_dir / "figures" / "demo.png"
    _write_figure(figure, cfg, reward_list, before, after, scale_names, atoms, atom_ids)

    metrics = {
        "config": asdict(cfg),
        "train_seconds": round(train_seconds, 3),
        "reward_first_steps": sum(first) / len(first),
        "reward_last_steps": sum(last) / len(last),
        "reward_window_steps": window,
        "reward_per_step": reward_list,
        "eval_disparity_px": list(range(cfg.max_disparity_px + 1)),
        "eval_error_before": {n: before[:, j].tolist() for j, n in enumerate(scale_names)},
        "eval_error_after": {n: after[:, j].tolist() for j, n in enumerate(scale_names)},
        "eval_reward_before": (-before.sum(1)).tolist(),
        "eval_reward_after": (-after.sum(1)).tolist(),
    }
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    torch.save(encoder.state_dict(), run_dir / "encoder.pt")

    r_after = metrics["eval_reward_after"]
    print(
        f"trained {cfg.steps} steps x {cfg.batch_size} pairs in {train_seconds:.1f} s: "
        f"reward {metrics['reward_first_steps']:.3f} (first {window} steps) -> "
        f"{metrics['reward_last_steps']:.3f} (last {window})\n"
        f"held-out reward at |d| = 0 / {cfg.max_disparity_px} px: "
        f"before {metrics['eval_reward_before'][0]:.3f} / {metrics['eval_reward_before'][-1]:.3f}, "
        f"after {r_after[0]:.3f} / {r_after[-1]:.3f}\n"
        f"figure:   {figure}\nmetrics:  {run_dir / 'metrics.json'}\n"
        f"encoder:  {run_dir / 'encoder.pt'}\ntensorboard: {run_dir / 'tensorboard'}"
    )
    return metrics
