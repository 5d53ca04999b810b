"""The fused CPU kernels (``coder_cpu.cpp`` for the coder, ``render_cpu.cpp`` for the renderer), built on first use.

`omp` and `matching_pursuit` run on CPU through the operator ``torch.ops.aectorch.sparse_code``
when it is available: one C++ loop per signal instead of ~20-45 tensor ops per coding step
(docs/performance.md measures both). It is compiled once per machine with
`torch.utils.cpp_extension` (g++ and ninja, both of which `torch.compile` on CPU needs too)
into a cache folder, keyed by the source, the torch version and the CPU, and loaded from there
afterwards in well under a second. ``scripts/setup.sh`` builds it at install time. The same
library holds ``torch.ops.aectorch.render_trilinear``, the torch renderer's mipmapped path fused
into one loop per pixel (`aectorch.sim.render_torch.render_rays` uses it on CPU).

A library already built is loaded directly (no lock, no compiler). A build holds an exclusive
``flock`` on ``build.lock`` in its folder, which the kernel releases when the holder dies, so a
build killed half-way (``kill -9``, a closed terminal, a scheduler's pre-emption) cannot wedge the
next process: it takes over, saying so in one line, and a process that waits for a live build
says so every 10 s. The folder is keyed by the sources' content, the flags, torch, Python and the
CPU, and the sources are copied into it, so a second checkout (a worktree, a copy in a job's
scratch space) reuses the same build.

If it cannot be built (no compiler, say), the coders fall back to the pure-torch code with one
warning that says why; results agree within float rounding (tests/coding/test_batch_omp.py). Set
``AECTORCH_NATIVE=0`` to never use it, and ``AECTORCH_CACHE`` to move the cache
(default ``~/.cache/aectorch``). On x86-64 the kernels are compiled for this CPU
(``-march=native``); ``AECTORCH_NATIVE_MARCH`` names another target, e.g. ``x86-64-v3`` (AVX2,
no AVX-512) to measure what a machine without AVX-512 would run (``make bench ISA=avx2``).

The kernels' float32 matrix products (the coders' correlations, the Gram matrix) run in oneDNN
(torch's ``mkldnn::_linear_pointwise``), not in torch's ``@`` (MKL on x86): on an AMD CPU with
AVX-512, MKL runs its AVX2 code and oneDNN about twice as fast (at AVX2 they ran at about the
same rate; ``benchmarks/test_loop.py`` records both rates). The two libraries sum in different
orders, so the codes agree with the torch code's within rounding (and are the same bits on any
number of threads). ``AECTORCH_ONEDNN=0`` keeps torch's product (read once per process); float64
always uses it.

Example:
    >>> from aectorch.ops import native
    >>> isinstance(native.available(), bool)
    True
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import sys
import threading
import time
import warnings
from pathlib import Path

import torch

from aectorch._checks import check_int

log = logging.getLogger("aectorch")

__all__ = ["available", "get_threads", "load", "set_threads", "sparse_code", "SOURCE", "SOURCES"]

#: The C++ source of the coder's kernels (OMP, MP, the encoder, patches, the dictionary's steps).
SOURCE = Path(__file__).with_name("coder_cpu.cpp")
#: Every source built into the library: the coder's and the renderer's trilinear kernel.
SOURCES = (SOURCE, Path(__file__).with_name("render_cpu.cpp"))

_lock = threading.Lock()
_state: dict[str, object] = {}


def _cpu_signature() -> str:
    # -march=native code must not run on another CPU: the build folder is keyed by its flags.
    try:
        text = Path("/proc/cpuinfo").read_text()
        flags = next((line for line in text.splitlines() if line.startswith("flags")), "")
    except OSError:
        flags = ""
    return platform.machine() + flags


def _flags() -> list[str]:
    # No fused multiply-add contraction: residual updates round like torch's addcmul, so an exactly
    # cancelled correlation is 0 here too (not the product's rounding error). OpenMP: the kernels'
    # loops split over threads of their own (`set_threads`).
    flags = ["-O3", "-ffp-contract=off", "-fopenmp"]
    if platform.machine() in ("x86_64", "AMD64"):
        march = os.environ.get("AECTORCH_NATIVE_MARCH", "native")
        if not march or not all(c.isalnum() or c in "-_." for c in march):
            raise ValueError(f"AECTORCH_NATIVE_MARCH must name a -march target such as native or x86-64-v3, "
                             f"got {march!r}")
        flags.append(f"-march={march}")
    return flags


def _build_dir() -> tuple[str, Path]:
    """The library's name and folder: keyed by the sources' content, the flags, torch, Python and
    the CPU, never by where the checkout lies (a worktree or a copy reuses the same build)."""
    key = hashlib.sha256(
        b"".join(source.read_bytes() for source in SOURCES) + " ".join(_flags()).encode()
        + torch.__version__.encode() + sys.version.encode() + _cpu_signature().encode()
    ).hexdigest()[:16]
    root = Path(os.environ.get("AECTORCH_CACHE", Path.home() / ".cache" / "aectorch"))
    return f"aectorch_kernels_{key}", root / "native" / key


#: Written into the build folder after a build succeeded: only then is the library loaded
#: without a lock (a build killed while linking can leave a partial file).
_DONE = "built"
#: How often a process waiting for another's build says so.
_WAIT_NOTE_S = 10.0


class _BuildLock:
    """An exclusive ``flock`` on ``<folder>/build.lock`` while building.

    The kernel releases it when its holder dies (``kill -9``, an OOM kill, a closed terminal), so
    a dead holder cannot keep it; the file records the holder's pid and start time for the
    messages. A process that waits says so every ``_WAIT_NOTE_S`` seconds, with the holder's pid
    and how long it has waited.
    """

    def __init__(self, folder: Path) -> None:
        self.path = folder / "build.lock"
        self.file = None
        self.previous: dict | None = None  # the last holder's record, if it did not finish

    def __enter__(self) -> "_BuildLock":
        import fcntl  # (POSIX; imported here so that the module itself imports anywhere)

        self.file = open(self.path, "a+")
        start = time.monotonic()
        noted = start
        while True:
            try:
                fcntl.flock(self.file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                now = time.monotonic()
                if now - noted >= _WAIT_NOTE_S:
                    noted = now
                    log.warning("aectorch: waiting for %s to finish building the fused CPU kernels (%.0f s so far)",
                                self._holder(), now - start)
                time.sleep(0.2)
        self.file.seek(0)
        text = self.file.read().strip()
        try:
            self.previous = json.loads(text) if text else None
        except ValueError:
            self.previous = {"pid": None}
        self.file.seek(0)
        self.file.truncate()
        self.file.write(json.dumps({"pid": os.getpid(), "started": time.time()}))
        self.file.flush()
        return self

    def _holder(self) -> str:
        try:
            pid = json.loads(Path(self.path).read_text() or "{}").get("pid")
        except (OSError, ValueError):
            pid = None
        return f"process {pid}" if pid else "another process"

    def __exit__(self, *exc) -> bool:
        import fcntl

        self.file.seek(0)
        self.file.truncate()  # a finished holder leaves no record
        self.file.flush()
        fcntl.flock(self.file.fileno(), fcntl.LOCK_UN)
        self.file.close()
        return False


def _build(name: str, folder: Path, verbose: bool) -> None:
    """Build the library in ``folder`` (holding `_BuildLock`) and load it."""
    import shutil

    from torch.utils import cpp_extension

    with _BuildLock(folder) as lock:
        library = folder / f"{name}.so"
        if (folder / _DONE).exists() and library.exists():  # another process built it while we waited
            torch.ops.load_library(str(library))
            return
        if lock.previous:
            log.warning("aectorch: the kernel build of process %s did not finish (it is no longer running); "
                        "building again", lock.previous.get("pid"))
        log.warning("aectorch: compiling the fused CPU kernels (once per machine, about a minute)...")
        # torch's own file baton, left behind by a build that was killed: nobody else builds here now.
        (folder / "lock").unlink(missing_ok=True)
        # The sources are copied in, so build.ninja names this folder, not the checkout's path.
        sources = folder / "src"
        sources.mkdir(exist_ok=True)
        copies = []
        for source in SOURCES:
            shutil.copyfile(source, sources / source.name)
            copies.append(str(sources / source.name))
        cpp_extension.load(
            name=name, sources=copies, build_directory=str(folder), extra_cflags=_flags(),
            extra_ldflags=["-fopenmp"], is_python_module=False, verbose=verbose,
        )
        (folder / _DONE).write_text(name + "\n")


def load(verbose: bool = False) -> bool:
    """Build (once per machine) and load the kernels; True if ``torch.ops.aectorch.sparse_code`` works.

    A library already built (for these sources, flags, torch and CPU) is loaded directly, without
    a lock or a compiler; a build holds `_BuildLock`. Never raises: a failure is reported once as a
    `RuntimeWarning` and the coders and the renderer use torch.
    """
    with _lock:
        if "ok" in _state:
            return bool(_state["ok"])
        _state["ok"] = False
        if os.environ.get("AECTORCH_NATIVE", "1").strip().lower() in ("0", "false", "no", "off"):
            return False
        try:
            name, folder = _build_dir()
            folder.mkdir(parents=True, exist_ok=True)
            library = folder / f"{name}.so"
            if (folder / _DONE).exists() and library.exists():
                torch.ops.load_library(str(library))
            else:
                _build(name, folder, verbose)
            _register_fake()
            _state["ok"] = True
        except Exception as exc:  # noqa: BLE001 - any build or load failure means: use torch
            warnings.warn(
                f"aectorch: the fused CPU kernels are not available ({type(exc).__name__}: "
                f"{str(exc).strip().splitlines()[-1] if str(exc).strip() else exc!r}); omp, "
                "matching_pursuit and the renderer use the slower pure-torch code. Set AECTORCH_NATIVE=0 "
                "to silence this.", RuntimeWarning, stacklevel=3)
        return bool(_state["ok"])


def set_threads(threads: int) -> None:
    """Threads of the fused kernels' loops (OpenMP, their own pool; default 1).

    Independent of ``torch.set_num_threads``: ``train.threads=0`` gives the kernels every core
    and keeps torch's own operations, which are too small to pay for a second thread, on one.
    A fork's child (a multiprocessing pool, a DataLoader's worker) starts with one kernel thread:
    libgomp cannot use the parent's threads there. Does nothing when the kernels are not available.
    """
    check_int(threads, "threads")
    if load():
        torch.ops.aectorch.set_kernel_threads(threads)


def get_threads() -> int:
    """The fused kernels' threads (1 when they are not available)."""
    return int(torch.ops.aectorch.kernel_threads()) if load() else 1


def available() -> bool:
    """Whether the kernel is loaded (building it on the first call)."""
    return load()


def _register_fake() -> None:
    @torch.library.register_fake("aectorch::sparse_code")
    def _(signals, dictionary, gram, k, orthogonal, block):
        m = signals.shape[0]
        return signals.new_empty(m, k, dtype=torch.long), signals.new_empty(m, k)

    @torch.library.register_fake("aectorch::encode")
    def _(signals, dictionary, gram, k, orthogonal, block, groups):  # gram: None, or [N, N]
        m, n = signals.shape[0], dictionary.shape[1]
        return (signals.new_empty(m, k, dtype=torch.long), signals.new_empty(m, k), signals.new_empty(signals.shape),
                signals.new_empty(m), signals.new_empty(groups, n))

    @torch.library.register_fake("aectorch::reconstruct_error")
    def _(signals, atoms_t, indices, coefficients):
        return signals.new_empty(signals.shape), signals.new_empty(signals.shape[0])

    @torch.library.register_fake("aectorch::sparse_gradient")
    def _(signals, reconstruction, indices, coefficients, num_atoms):
        return signals.new_empty(num_atoms, signals.shape[1])

    @torch.library.register_fake("aectorch::gram")
    def _(atoms):
        return atoms.new_empty(atoms.shape[1], atoms.shape[1])

    @torch.library.register_fake("aectorch::pooled_power")
    def _(indices, coefficients, num_atoms):
        return coefficients.new_empty(indices.shape[0], num_atoms)

    @torch.library.register_fake("aectorch::pair_patches")
    def _(images, offset, p, stride, g, eps, rounding):
        return images.new_empty(images.shape[0] // 2, g * g, 2 * p * p)

    @torch.library.register_fake("aectorch::learn_steps_")
    def _(atoms, signals, reconstructions, indices, coefficients, lr, mirrors, partners):
        return None

    @torch.library.register_fake("aectorch::pyramid_blur")
    def _(images, centre, side):
        return images.new_empty(images.shape[0], images.shape[1] - 2, images.shape[2] - 2)

    @torch.library.register_fake("aectorch::render_trilinear")
    def _(poses, plane_x, texture_index, atlas, xs, ys, steps, scene, tex_h, tex_w, levels, lod_bias, samples,
          plane_y=None):
        return poses.new_empty(poses.shape[0], poses.shape[1], xs.shape[0])


def sparse_code(signals: torch.Tensor, dictionary: torch.Tensor, gram: torch.Tensor, k: int,
            orthogonal: bool, block: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(indices [M, k], coefficients [M, k])`` of MP or OMP on CPU signals `[M, P]`.

    Raises:
        RuntimeError: the kernel could not be built or loaded (see `load`).
    """
    if not load():
        raise RuntimeError("the fused CPU coder kernel is not available (see aectorch.ops.native.load)")
    return torch.ops.aectorch.sparse_code(signals, dictionary, gram, k, orthogonal, block)
