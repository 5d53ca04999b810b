"""The bank of textures for the object plane: procedural ones or folders of photographs.

The paper puts one of 100 natural-image textures on the plane in front of the robot for each
fixation, and the AEC lineage holds out 40 more textures for testing. We cannot ship or download
those photographs, so `TextureBank.default` stands in 1/f^alpha random-phase textures (the
amplitude spectrum of natural images falls roughly as 1/f) from fixed seeds: 100 for ``"train"``
and 40 different ones for ``"test"``. Any folder of PNG/JPEG photographs can replace them with
`TextureBank.from_folder`.

A `TextureBank` is a plain container of ``N`` grey textures ``[N, H, W]`` in [0, 1] with their
names; an environment draws texture indices with `TextureBank.sample_indices` and gathers the
textures with ``bank[indices]``.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor

from aectorch._checks import is_int, is_real
from aectorch.sim.textures.files import IMAGE_EXTENSIONS, check_extensions, load_grey
from aectorch.sim.textures.procedural import dead_leaves_image, pink_noise_images
from aectorch.sim.textures.storage import empty_textures

__all__ = ["TextureBank", "DEFAULT_SEEDS", "PROCEDURAL_TEXTURES", "DEFAULT_SIZES"]

#: Seeds of the procedural stand-ins for the paper's training and held-out texture sets.
DEFAULT_SEEDS: dict[str, int] = {"train": 2017, "test": 2018}
#: Names of generated texture sets that a config may give in place of a folder (`TextureBank.from_spec`).
PROCEDURAL_TEXTURES: tuple[str, ...] = ("dead-leaves",)
#: Number of textures of each default split (the AEC lineage: 100 train, 40 test).
DEFAULT_SIZES: dict[str, int] = {"train": 100, "test": 40}
_DEFAULT_ALPHA = (1.0, 1.2)
# Elements per chunk when a whole bank is checked or reduced (bounds the temporaries).
_CHUNK_ELEMENTS = 2**22
_PROGRESS_MIN_FILES = 20


class TextureBank:
    """``N`` grey textures in [0, 1] with their names, from which environments draw.

    Build one with `procedural`, `from_folder`, `default` or `from_spec`, or directly from a
    tensor. The bank holds a reference to `textures` (no copy); `to`, `subset` and `split`
    return new banks.

    Args:
        textures: floating tensor of grey textures, values finite and within [0, 1].
        names: one name per texture (default ``"texture-<i>"``).
        source: a short description of where the textures come from, shown by ``repr``.

    Attributes:
        textures: the textures, `[N, H, W]`.
        names: list of the ``N`` names (file names, or ``"pink-<seed>-<i>"``).
        source: the description given at construction.

    Shape:
        textures: `[N, H, W]` with ``N >= 1`` and ``H, W >= 2``.

    Example:
        >>> bank = TextureBank.procedural(num=4, size=(32, 48), seed=0)
        >>> bank
        TextureBank(N=4, size=(32, 48), dtype=torch.float32, device=cpu, source='procedural(seed=0, alpha=(1.0, 1.2))')
        >>> g = torch.Generator().manual_seed(0)
        >>> idx = bank.sample_indices(3, g)
        >>> bank[idx].shape
        torch.Size([3, 32, 48])
        >>> bank.names[:2] == ["pink-0-0", "pink-0-1"]
        True
    """

    def __init__(
        self, textures: Tensor, names: Sequence[str] | None = None, *, source: str = "tensor"
    ) -> None:
        _check_textures(textures)
        n = textures.shape[0]
        if names is None:
            names = [f"texture-{i}" for i in range(n)]
        else:
            if isinstance(names, str) or not isinstance(names, Sequence):
                raise TypeError(f"names must be a sequence of str, got {type(names).__name__}")
            names = list(names)
            if len(names) != n:
                raise ValueError(
                    f"names must have one entry per texture: expected {n}, got {len(names)}"
                )
            bad = [name for name in names if not isinstance(name, str)]
            if bad:
                raise TypeError(f"names must all be str, got {type(bad[0]).__name__} ({bad[0]!r})")
        if not isinstance(source, str):
            raise TypeError(f"source must be a str, got {type(source).__name__}")
        self.textures: Tensor = textures.detach()
        self.names: list[str] = names
        self.source: str = source

    # ------------------------------------------------------------------ constructors

    @classmethod
    def procedural(
        cls,
        num: int = 100,
        size: int | tuple[int, int] = (512, 512),
        alpha: float | tuple[float, float] = _DEFAULT_ALPHA,
        seed: int = 0,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> TextureBank:
        """Seeded 1/f^alpha random-phase textures (see `pink_noise_images`).

        Texture ``i`` draws its exponent (uniform in `alpha` when a range is given) and then its
        phases from one CPU generator seeded with `seed`, in float64, one texture after the
        other. So the same seed gives the same bank on every device and dtype, and the first
        ``k`` textures of a bank of ``num > k`` are the bank of ``k``. The textures are periodic
        (they come from an inverse FFT), each spans exactly [0, 1].

        Args:
            num: number of textures (>= 1).
            size: (height, width) of each texture, each >= 2 (an int means a square).
            alpha: amplitude spectral exponent, a float or a (low, high) range sampled
                uniformly per texture.
            seed: seed of the generator.
            dtype: floating dtype of the bank.
            device: device of the bank (default CPU).

        Returns:
            A bank whose names are ``"pink-<seed>-<i>"``.

        Example:
            >>> bank = TextureBank.procedural(num=3, size=16, alpha=1.0, seed=5)
            >>> len(bank), bank.size, bank.names[-1]
            (3, (16, 16), 'pink-5-2')
            >>> torch.equal(bank.textures, TextureBank.procedural(3, 16, 1.0, seed=5).textures)
            True
        """
        num = _check_count(num, "num")
        height, width = _check_size(size)
        low, high = _check_alpha(alpha)
        if not is_int(seed):
            raise TypeError(f"seed must be an int, got {type(seed).__name__} ({seed!r})")
        dtype = _check_dtype(dtype)

        generator = torch.Generator().manual_seed(seed)
        textures = torch.empty((num, height, width), dtype=dtype, device=device)
        for i in range(num):
            a = low + (high - low) * float(torch.rand((), generator=generator, dtype=torch.float64))
            texture = pink_noise_images(1, height, width, alpha=a, generator=generator,
                                        dtype=torch.float64)
            textures[i] = texture[0]
        alpha_text = f"{low}" if low == high else f"({low}, {high})"
        return cls(
            textures,
            [f"pink-{seed}-{i}" for i in range(num)],
            source=f"procedural(seed={seed}, alpha={alpha_text})",
        )

    @classmethod
    def dead_leaves(
        cls,
        num: int = 100,
        size: int | tuple[int, int] = (512, 512),
        seed: int = 0,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
        **options,
    ) -> TextureBank:
        """Seeded dead-leaves textures (`dead_leaves_image`; ``options`` are its keywords).

        Texture ``i`` is drawn from one CPU generator seeded with ``seed``, one after the other,
        so the first ``k`` textures of a bank of ``num > k`` are the bank of ``k``.

        Example:
            >>> bank = TextureBank.dead_leaves(num=2, size=32, seed=3)
            >>> len(bank), bank.names
            (2, ['leaves-3-0', 'leaves-3-1'])
        """
        num = _check_count(num, "num")
        height, width = _check_size(size)
        if not is_int(seed):
            raise TypeError(f"seed must be an int, got {type(seed).__name__} ({seed!r})")
        dtype = _check_dtype(dtype)
        generator = torch.Generator().manual_seed(seed)
        textures = torch.stack([dead_leaves_image(height, width, generator=generator, dtype=dtype, **options)
                                for _ in range(num)]).to(device)
        return cls(textures, [f"leaves-{seed}-{i}" for i in range(num)], source=f"dead_leaves(seed={seed})")

    @classmethod
    def default(
        cls,
        split: str = "train",
        *,
        size: int | tuple[int, int] = (512, 512),
        num: int | None = None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> TextureBank:
        """The default texture set: procedural stand-ins for the paper's photographs.

        The paper trains on 100 natural-image textures and the AEC lineage tests on 40 held-out
        ones. Those photographs cannot be shipped or downloaded here, so the default is
        ``TextureBank.procedural(100, size, alpha=(1.0, 1.2), seed=2017)`` for ``"train"`` and
        ``TextureBank.procedural(40, size, alpha=(1.0, 1.2), seed=2018)`` for ``"test"``
        (`DEFAULT_SIZES`, `DEFAULT_SEEDS`): disjoint sets with natural-image-like 1/f spectra.
        Use `from_folder` to train and test on real photographs.

        Args:
            split: ``"train"`` (100 textures) or ``"test"`` (40 held-out textures).
            size: (height, width) of each texture (an int means a square).
            num: ``None`` (the split's 100 or 40), or the first ``num`` textures of the split's
                seeded sequence (a larger world: its first 100 are the training set).
            dtype: floating dtype of the bank.
            device: device of the bank.

        Returns:
            The bank, with names ``"pink-<seed>-<i>"``.

        Example:
            >>> test = TextureBank.default("test", size=(8, 8))
            >>> len(test), test.names[0]
            (40, 'pink-2018-0')
        """
        if split not in DEFAULT_SEEDS:
            raise ValueError(f"split must be one of {sorted(DEFAULT_SEEDS)}, got {split!r}")
        bank = cls.procedural(
            DEFAULT_SIZES[split] if num is None else num, size, _DEFAULT_ALPHA, DEFAULT_SEEDS[split],
            dtype=dtype, device=device,
        )
        bank.source = f"default {split} set: {bank.source}"
        return bank

    @classmethod
    def from_folder(
        cls,
        path: str | os.PathLike,
        size: int | tuple[int, int] = (512, 512),
        *,
        extensions: Sequence[str] = IMAGE_EXTENSIONS,
        recursive: bool = False,
        progress: bool | None = None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> TextureBank:
        """Load every image of a folder as a grey texture of the given size.

        Files whose extension is in `extensions` (case-insensitive) are loaded in the order of
        their names (relative paths with ``/`` when `recursive`), so the bank is deterministic.
        Hidden files (name starting with ``.``, such as macOS ``._*`` forks) are skipped.
        Each image is

        1. turned upright by its EXIF orientation tag, if any (`PIL.ImageOps.exif_transpose`);
        2. converted to grey by Pillow's ``convert("L")``, the ITU-R 601-2 luma
           ``L = 0.299 R + 0.587 G + 0.114 B`` on 8-bit values (an alpha channel is ignored;
           16-bit grey images are read as such and divided by 65535 instead);
        3. resized so that it just covers `size` with its aspect ratio kept, then
           centre-cropped to `size`. Both happen in one resampling, as in Pillow's
           `PIL.ImageOps.fit`: the largest centred window of the image with the aspect ratio of
           `size` (fractional coordinates, so exactly centred) is resampled to `size` by Pillow's
           LANCZOS filter in 32-bit float. LANCZOS is antialiased when downscaling (its kernel
           is stretched by the scale factor, like an area filter); images smaller than `size`
           are upscaled by the same filter; an image already of `size` is left untouched;
        4. divided by 255 and clamped to [0, 1] (LANCZOS overshoots slightly at sharp edges).

        Args:
            path: the folder.
            size: (height, width) of each texture, each >= 2 (an int means a square).
            extensions: file extensions to load (with or without the dot).
            recursive: also load images from subfolders.
            progress: show a tqdm progress bar; None (default) shows one only when stderr is a
                terminal and there are at least 20 files.
            dtype: floating dtype of the bank.
            device: device of the bank.

        Memory: one image is decoded at a time; a bank larger than `texture_ram_bytes`
        (2 GiB: about 2000 textures of 512 x 512 in float32) is written to a temporary file
        mapped into memory (`empty_textures`), so a folder of 10,000 photographs loads in the
        process's memory of a few images, at the cost of its size on disk.

        Returns:
            The bank, named by file name (relative path when `recursive`).

        Raises:
            FileNotFoundError: `path` does not exist.
            NotADirectoryError: `path` is not a folder.
            ValueError: the folder holds no file with one of `extensions`, or an image file
                cannot be read (the message names the file and gives Pillow's message).

        Example:
            >>> import tempfile
            >>> from PIL import Image
            >>> with tempfile.TemporaryDirectory() as folder:
            ...     Image.new("RGB", (60, 40), (255, 0, 0)).save(f"{folder}/b.png")
            ...     Image.new("L", (30, 30), 128).save(f"{folder}/a.JPG")
            ...     bank = TextureBank.from_folder(folder, size=(16, 16))
            >>> bank.names, bank.textures.shape
            (['a.JPG', 'b.png'], torch.Size([2, 16, 16]))
            >>> round(float(bank.textures[1].mean()) * 255)   # red: 0.299 * 255
            76
        """
        folder = Path(os.fspath(path)).expanduser()
        height, width = _check_size(size)
        suffixes = check_extensions(extensions)
        dtype = _check_dtype(dtype)
        if not folder.exists():
            raise FileNotFoundError(f"texture folder {str(folder)!r} does not exist")
        if not folder.is_dir():
            raise NotADirectoryError(f"texture folder {str(folder)!r} is not a directory")

        candidates = folder.rglob("*") if recursive else folder.iterdir()
        files = sorted(
            (
                p for p in candidates
                if p.suffix.lower() in suffixes and p.is_file()
                and not any(part.startswith(".") for part in p.relative_to(folder).parts)
            ),
            key=lambda p: p.relative_to(folder).as_posix(),
        )
        if not files:
            where = "or its subfolders " if recursive else ""
            raise ValueError(
                f"texture folder {str(folder)!r} {where}holds no image file with an extension in "
                f"{list(suffixes)} (case-insensitive)"
            )

        from tqdm import tqdm

        if progress is None:
            progress = len(files) >= _PROGRESS_MIN_FILES and sys.stderr.isatty()
        textures = empty_textures((len(files), height, width), dtype=dtype, device=device)
        for i, file in enumerate(tqdm(files, desc="textures", unit="img", disable=not progress)):
            textures[i] = torch.from_numpy(load_grey(file, height, width))
        return cls(
            textures,
            [p.relative_to(folder).as_posix() for p in files],
            source=f"folder {str(folder)!r}",
        )

    @classmethod
    def from_spec(
        cls,
        spec: str | os.PathLike,
        *,
        split: str = "train",
        size: int | tuple[int, int] = (512, 512),
        num: int | None = None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> TextureBank:
        """The bank a config names: ``"default"``/``"procedural"`` or a folder of images.

        Args:
            spec: ``"default"`` or ``"procedural"`` (both give `default` with `split`),
                ``"dead-leaves"`` (`dead_leaves` with the default set's size and seed), or the
                path of a folder of images (`from_folder`, the whole folder: `split` is not
                used; give the training and the test set as two folders, or use `split`).
            split: ``"train"`` or ``"test"``, for the default textures.
            size: (height, width) of each texture.
            num: of a generated set: ``None`` (the split's size) or how many of its seeded
                sequence (`default`); a folder is read whole.
            dtype, device: of the bank.

        Returns:
            The bank.

        Raises:
            FileNotFoundError: `spec` is neither a keyword nor an existing path.

        Example:
            >>> TextureBank.from_spec("default", split="test", size=8).names[0]
            'pink-2018-0'
        """
        if not isinstance(spec, (str, os.PathLike)):
            raise TypeError(
                f"spec must be 'default', 'procedural' or a folder path, got {type(spec).__name__}"
            )
        if isinstance(spec, str) and spec.strip().lower() in ("default", "procedural"):
            return cls.default(split, size=size, num=num, dtype=dtype, device=device)
        if isinstance(spec, str) and spec.strip().lower() in PROCEDURAL_TEXTURES:
            if split not in DEFAULT_SEEDS:
                raise ValueError(f"split must be one of {sorted(DEFAULT_SEEDS)}, got {split!r}")
            return cls.dead_leaves(DEFAULT_SIZES[split] if num is None else num, size, DEFAULT_SEEDS[split],
                                   dtype=dtype, device=device)
        folder = Path(os.fspath(spec)).expanduser()
        if not os.fspath(spec) or not folder.exists():
            raise FileNotFoundError(
                f"texture spec {os.fspath(spec)!r} is neither 'default' / 'procedural' nor an "
                f"existing folder of images"
            )
        return cls.from_folder(folder, size, dtype=dtype, device=device)

    # ------------------------------------------------------------------ container

    def __len__(self) -> int:
        return self.textures.shape[0]

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) of the textures."""
        return int(self.textures.shape[1]), int(self.textures.shape[2])

    @property
    def dtype(self) -> torch.dtype:
        return self.textures.dtype

    @property
    def device(self) -> torch.device:
        return self.textures.device

    def __repr__(self) -> str:
        return (
            f"TextureBank(N={len(self)}, size={self.size}, dtype={self.dtype}, "
            f"device={self.device}, source={self.source!r})"
        )

    def __getitem__(self, index: int | slice | Tensor | Sequence[int]) -> Tensor:
        """Textures by index: an int gives `[H, W]`, a LongTensor or list `[B]` gives `[B, H, W]`.

        Negative indices count from the end, as in Python. Index tensors may live on any device
        (they are moved to the bank's); their range is checked, which syncs with the device.

        Raises:
            IndexError: an index outside ``[-N, N)``.
            TypeError: an index of another type (e.g. a float or bool tensor).
        """
        n = len(self)
        if isinstance(index, slice):
            return self.textures[index]
        if is_int(index):
            if not -n <= index < n:  # type: ignore[operator]  # (is_int: an integer)
                raise IndexError(f"texture index must lie in [{-n}, {n}) for {n} textures, got {index}")
            return self.textures[index]
        return self.textures[self._index_tensor(index, "index")]  # type: ignore[arg-type]

    def sample_indices(self, batch: int, generator: torch.Generator) -> Tensor:
        """Texture indices drawn uniformly with replacement.

        Args:
            batch: number of indices (>= 1).
            generator: the source of randomness; the indices live on its device.

        Returns:
            Indices in ``[0, N)``, int64.

        Shape:
            output: `[batch]`.

        Example:
            >>> bank = TextureBank.procedural(num=5, size=8)
            >>> bank.sample_indices(4, torch.Generator().manual_seed(0))
            tensor([4, 4, 3, 0])
        """
        batch = _check_count(batch, "batch")
        if not isinstance(generator, torch.Generator):
            raise TypeError(f"generator must be a torch.Generator, got {type(generator).__name__}")
        return torch.randint(len(self), (batch,), generator=generator, device=generator.device)

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> TextureBank:
        """A bank with the textures on `device` and/or in `dtype` (same names and source)."""
        if dtype is not None:
            dtype = _check_dtype(dtype)
        return TextureBank(self.textures.to(device=device, dtype=dtype), self.names, source=self.source)

    def subset(self, indices: Tensor | Sequence[int]) -> TextureBank:
        """A bank of the textures at `indices`, in that order (negative indices count from the end).

        Example:
            >>> bank = TextureBank.procedural(num=5, size=8)
            >>> bank.subset([3, 0]).names
            ['pink-0-3', 'pink-0-0']
        """
        index = self._index_tensor(indices, "indices")
        if index.numel() == 0:
            raise ValueError("indices must select at least one texture, got none")
        positions = index.cpu().remainder(len(self)).tolist()
        return TextureBank(
            self.textures[index], [self.names[i] for i in positions], source=self.source
        )

    def split(self, test_fraction: float = 0.2, *, seed: int = 0) -> tuple[TextureBank, TextureBank]:
        """Split into disjoint training and held-out banks, e.g. for a folder of photographs.

        ``round(N * test_fraction)`` textures, but at least one and at most ``N - 1``, chosen by a
        random permutation from `seed`, go to the test bank; the rest to the training bank. Each
        keeps the bank's order.

        Args:
            test_fraction: share of textures held out, in (0, 1).
            seed: seed of the permutation.

        Returns:
            (train_bank, test_bank).

        Raises:
            ValueError: `test_fraction` outside (0, 1), or fewer than 2 textures.

        Example:
            >>> train, test = TextureBank.procedural(num=10, size=8).split(0.3, seed=1)
            >>> len(train), len(test), set(train.names).isdisjoint(test.names)
            (7, 3, True)
        """
        if not (is_int(test_fraction) or isinstance(test_fraction, float)):  # NaN: the ValueError below
            raise TypeError(f"test_fraction must be a float, got {type(test_fraction).__name__}")
        if not 0.0 < test_fraction < 1.0:
            raise ValueError(f"test_fraction must lie in (0, 1), got {test_fraction!r}")
        if not is_int(seed):
            raise TypeError(f"seed must be an int, got {type(seed).__name__} ({seed!r})")
        n = len(self)
        if n < 2:
            raise ValueError(f"cannot split {n} texture into non-empty train and test banks (need >= 2)")
        n_test = min(max(round(n * test_fraction), 1), n - 1)
        order = torch.randperm(n, generator=torch.Generator().manual_seed(seed))
        test_idx, _ = order[:n_test].sort()
        train_idx, _ = order[n_test:].sort()
        train, test = self.subset(train_idx), self.subset(test_idx)
        train.source = f"{self.source} [train split, seed={seed}]"
        test.source = f"{self.source} [test split {test_fraction}, seed={seed}]"
        return train, test

    def _index_tensor(self, index: Tensor | Sequence[int], name: str) -> Tensor:
        n = len(self)
        if isinstance(index, Tensor):
            if index.dtype not in (torch.int64, torch.int32, torch.int16, torch.int8, torch.uint8):
                raise TypeError(f"{name} must be an integer tensor, got dtype {index.dtype}")
            if index.ndim > 1:
                raise ValueError(f"{name} must have shape [B], got {tuple(index.shape)}")
            index = index.to(device=self.device, dtype=torch.int64)
        elif isinstance(index, Sequence) and not isinstance(index, str):
            if not all(is_int(i) for i in index):
                raise TypeError(f"{name} must be ints, got {list(index)!r}")
            index = torch.tensor(list(index), dtype=torch.int64, device=self.device)
        else:
            raise TypeError(
                f"{name} must be an int, a slice, a sequence of ints or an integer tensor, "
                f"got {type(index).__name__}"
            )
        if index.numel():
            low, high = (int(v) for v in index.aminmax())
            if low < -n or high >= n:
                raise IndexError(
                    f"texture {name} must lie in [{-n}, {n}) for {n} textures, got values in "
                    f"[{low}, {high}]"
                )
        return index


# ---------------------------------------------------------------------- helpers


def _check_textures(textures: Tensor) -> None:
    if not isinstance(textures, Tensor):
        raise TypeError(f"textures must be a torch.Tensor [N, H, W], got {type(textures).__name__}")
    shape = tuple(textures.shape)
    if textures.ndim == 2:
        raise ValueError(
            f"textures must have shape [N, H, W], got a single texture of shape {shape}; "
            f"use textures.unsqueeze(0) for a bank of one"
        )
    if textures.ndim == 4 and textures.shape[1] == 1:
        raise ValueError(
            f"textures must have shape [N, H, W] (grey), got {shape}; use textures.squeeze(1)"
        )
    if textures.ndim != 3:
        raise ValueError(f"textures must have shape [N, H, W], got {shape}")
    n, h, w = shape
    if n < 1 or h < 2 or w < 2:
        raise ValueError(f"textures must have shape [N, H, W] with N >= 1 and H, W >= 2, got {shape}")
    if not textures.is_floating_point():
        hint = " (divide 8-bit images by 255)" if textures.dtype == torch.uint8 else ""
        raise TypeError(f"textures must be a floating tensor, got dtype {textures.dtype}{hint}")
    # In chunks of textures: a bank mapped from a file (empty_textures) is never copied whole.
    step = max(1, _CHUNK_ELEMENTS // (h * w))
    low, high = math.inf, -math.inf
    for start in range(0, n, step):
        chunk = textures[start:start + step]
        if not bool(torch.isfinite(chunk).all()):
            raise ValueError("textures must be finite, got NaN or inf values")
        low, high = min(low, float(chunk.amin())), max(high, float(chunk.amax()))
    if low < 0.0 or high > 1.0:
        raise ValueError(f"textures must lie within [0, 1], got values in [{low}, {high}]")


def _check_size(size) -> tuple[int, int]:
    if is_int(size):
        size = (size, size)
    if isinstance(size, (str, bytes)) or not isinstance(size, Sequence) or len(size) != 2:
        raise ValueError(f"size must be (height, width) or an int, got {size!r}")
    if not all(is_int(s) for s in size):
        raise TypeError(f"size must hold two ints (height, width), got {size!r}")
    if min(size) < 2:
        raise ValueError(f"size must be (height, width) with both >= 2, got {tuple(size)}")
    return int(size[0]), int(size[1])


def _check_count(value, name: str) -> int:
    if not is_int(value):  # a TypeError, unlike check_int's
        raise TypeError(f"{name} must be an int >= 1, got {type(value).__name__} ({value!r})")
    if value < 1:
        raise ValueError(f"{name} must be an int >= 1, got {value}")
    return value


def _check_alpha(alpha) -> tuple[float, float]:
    if is_real(alpha):
        low = high = float(alpha)
    elif isinstance(alpha, Sequence) and not isinstance(alpha, str) and len(alpha) == 2:
        low, high = (float(a) for a in alpha)
    else:
        raise ValueError(f"alpha must be a finite float or a (low, high) pair, got {alpha!r}")
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise ValueError(f"alpha must be finite with low <= high, got {alpha!r}")
    return low, high


def _check_dtype(dtype) -> torch.dtype:
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"dtype must be a floating torch.dtype, got {dtype!r}")
    return dtype
