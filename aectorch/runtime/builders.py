"""Building a run's parts from its `ExperimentConfig`: textures, environments, learner, threads."""

from __future__ import annotations

import logging
import os

import torch

from aectorch.framework import JointLearner, Shard
from aectorch.runtime.config import ExperimentConfig
from aectorch.sim import PROCEDURAL_TEXTURES, ActiveDepthEnv, TextureBank

log = logging.getLogger("aectorch")

__all__ = ["available_threads", "build_env", "build_learner", "build_textures", "compile_hot_path",
           "dictionaries", "set_threads", "trial_options"]


def set_threads(threads: int, processes: int = 1) -> None:
    """``train.threads``: N >= 1 gives torch and the fused kernels N threads each; 0 gives the fused
    kernels (rendering, sparse coding) every core of this process's share and torch's own operations one
    (they are too small to pay for a second thread: docs/performance.md)."""
    from aectorch.ops import native

    torch.set_num_threads(threads or 1)
    native.set_threads(threads or available_threads(processes))


def available_threads(processes: int = 1) -> int:
    """``train.threads=0``: the cores this process may use, shared among ``processes`` (>= 1)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    return max(1, cores // max(1, processes))


def build_textures(folder: str | None, split: str, cfg: ExperimentConfig) -> TextureBank:
    """``TextureBank.from_folder(folder)``, or ``TextureBank.default(split)`` when ``folder`` is None
    (of ``env.num_textures`` textures for the training split)."""
    kwargs = dict(dtype=cfg.env.torch_dtype)
    num = cfg.env.num_textures if split == "train" else None
    if folder is None:
        return TextureBank.default(split, num=num, **kwargs)
    if folder in PROCEDURAL_TEXTURES:
        return TextureBank.from_spec(folder, split=split, num=num, **kwargs)
    return TextureBank.from_folder(folder, progress=None if cfg.train.progress else False, **kwargs)


def trial_options(cfg: ExperimentConfig) -> dict:
    """The keyword arguments of `aectorch.evaluation.evaluate` and `run_trials` that ``cfg`` sets:
    the run's trial protocol and the evaluation's batch size."""
    return dict(protocol=cfg.env.protocol, batch_size=cfg.eval.batch_size)


def _start(value: float, spread: float) -> float | tuple[float, float]:
    """A start angle for `ActiveDepthEnv`: the value, or the range ``value +- spread``."""
    return (value - spread, value + spread) if spread > 0 else value


def build_env(cfg: ExperimentConfig, shard: Shard | None = None) -> ActiveDepthEnv:
    """The training environments of ``cfg.env``, seeded from ``cfg.seed`` (this process's slice of
    the whole batch: ``shard``, default the whole batch)."""
    e = cfg.env
    return ActiveDepthEnv(
        e.num_envs,
        textures=build_textures(e.textures, "train", cfg),
        protocol=e.protocol,
        distances_m=e.distances_m,
        pursuit_start_deg=_start(e.pursuit_start_deg, e.pursuit_start_spread_deg),
        vergence_start_deg=_start(e.vergence_start_deg, e.vergence_start_spread_deg),
        pursuit_start_error_deg=e.pursuit_start_error_deg,
        layout=e.scene,
        seed=cfg.seed,
        device=e.device,
        dtype=e.torch_dtype,
        batch_slice=(shard.start, shard.total) if shard is not None and shard.world_size > 1 else None,
    )


def build_learner(cfg: ExperimentConfig, device: str | torch.device | None = None,
                  shard: Shard | None = None) -> JointLearner:
    """A fresh :class:`JointLearner` of ``cfg.learner``, its generator seeded from ``cfg.seed``."""
    return JointLearner(
        cfg.learner,
        generator=torch.Generator().manual_seed(cfg.seed),
        dtype=cfg.env.torch_dtype,
        device=cfg.env.device if device is None else device,
        shard=shard or Shard.single(cfg.env.num_envs),
    )


def dictionaries(learner: JointLearner) -> dict[str, torch.Tensor]:
    """Copies of the learner's dictionaries ``{"parallax/coarse": atoms [P, N], ...}`` on the CPU."""
    return {name: atoms.detach().cpu().clone() for name, atoms in learner.dictionaries().items()}


def compile_hot_path(learner: JointLearner, env: ActiveDepthEnv | None = None) -> list[str]:
    """``train.compile``: compile every cue's encoder (patch extraction, pursuit, pooling, errors)
    and the torch renderer (about 20 elementwise passes per pixel in eager mode, fused when
    compiled), where that pays: on CUDA, or wherever the fused CPU kernels are not used.

    On CPU with the fused kernels (`aectorch.ops.fused_kernels_apply`) those hot paths
    are the kernels themselves, which ``torch.compile`` can only call as opaque operators:
    compiling the encoders measured 0.87x eager at ``train.py`` level on a
    2-core AMD EPYC (docs/performance.md), so there nothing is compiled and the flag changes
    nothing. Returns the names of what was compiled.
    """
    from aectorch.ops.backend import fused_kernels_apply

    probe = next(iter(learner.dictionaries().values()))
    if fused_kernels_apply(probe.detach()):
        log.info("train.compile: nothing compiled: on CPU the hot paths are the fused kernels, which torch.compile "
                 "does not speed up (docs/performance.md)")
        return []
    compiled = []
    for name, cue in learner.cues.items():
        cue.encoder.compile()
        compiled.append(f"{name} encoder")
    if env is not None and isinstance(env.renderer, torch.nn.Module):
        env.renderer.compile(dynamic=False)
        compiled.append("renderer")
    return compiled
