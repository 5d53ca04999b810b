"""Read-outs of a learned binocular code: binocularity, disparity tuning and orientation of each atom.

The AEC lineage reads its learned dictionaries out the way physiologists read out V1 (Klimmasch
et al. 2021, eLife, among others): how much each atom listens to each eye, which disparity it
prefers, which orientation. Here each is a batched function of a
dictionary's atoms ``[..., P, N]`` (the columns of `SparseDictionary.atoms`), with no loop over
atoms; device and dtype follow the input.

Layout. An atom of length ``P = 2 p^2`` is two ``p x p`` halves, row-major, the first image's half
first (:func:`aectorch.coding.patches.extract_patches`): for the stereo cue the left eye, then the
right; for the motion-parallax cue the dominant eye before, then after, the body shift, where
"left" and "right" below read "before" and "after". Every patch half the coder sees is zero-mean,
so the mean of an atom's half never enters a response: every read-out uses the halves with their
means removed (:func:`atom_halves`).

- :func:`binocularity_index`: ``(|R| - |L|) / (|R| + |L|)`` of the halves' norms, -1 left only, +1
  right only, 0 balanced; :func:`binocularity_histogram` bins it.
- :func:`disparity_tuning`: each atom's mean squared response to white-noise stereograms at each
  horizontal disparity (derived there); :func:`preferred_disparity` its peak and depth of
  modulation; :func:`disparity_histogram` counts the peaks.
- :func:`orientation_preference`: the orientation of the plane wave that best fits the atom (the
  peak of its periodogram on a polar grid) and how concentrated its power is in orientation;
  :func:`orientation_histogram` bins it.
- :func:`principal_components`: PCA of a dictionary's atoms (scores and explained variance), the
  axes of Fig. 2 (:func:`aectorch.figures.plot_dictionaries`).
- :func:`gabor_binocularity`: the lineage's own binocularity measure (a 2-D Gabor fitted to the
  dominant half, :func:`aectorch.coding.gabor.fit_gabor`, shown to both halves; Klimmasch et al.
  2021), beside ours.
- :func:`code_summary`: all of it for one dictionary as plain, JSON-ready numbers (what a run's
  ``summary.json`` records per dictionary under ``"code"``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from aectorch._checks import check_int, is_int
from aectorch.coding.gabor import GABOR_PARAMETERS, GaborFit, fit_gabor

__all__ = [
    "DisparityPreference",
    "GABOR_PARAMETERS",
    "GaborBinocularity",
    "GaborFit",
    "OrientationPreference",
    "atom_halves",
    "check_atoms",
    "binocularity_index",
    "binocularity_histogram",
    "disparity_tuning",
    "preferred_disparity",
    "disparity_histogram",
    "orientation_preference",
    "orientation_histogram",
    "principal_components",
    "fit_gabor",
    "gabor_binocularity",
    "code_summary",
]

#: Default number of binocularity bins over [-1, 1]: seven, as Hubel & Wiesel's ocular-dominance
#: groups (1 and 7 monocular, 4 balanced).
BINOCULARITY_BINS = 7
#: Default number of orientation bins over [0, 180) deg, centred on 0, 22.5, ..., 157.5 deg.
ORIENTATION_BINS = 8
#: Default number of orientations of :func:`orientation_preference`'s bank of plane waves (2.5 deg apart).
ORIENTATIONS = 72
#: Default spatial frequencies (cycles per pixel) of that bank: 0.05, 0.1, ..., 0.5.
FREQUENCIES = tuple(round(0.05 * i, 2) for i in range(1, 11))


def _patch_size(dim: int) -> int:
    p = math.isqrt(dim // 2)
    if dim <= 0 or 2 * p * p != dim:
        raise ValueError(f"atoms must have P = 2 * patch_size**2 rows (two square halves), got P = {dim}")
    return p


def atom_halves(atoms: Tensor) -> Tensor:
    """The two halves of each atom as images, each with its mean removed.

    Args:
        atoms: a dictionary, atoms as columns, ``[..., P, N]`` with ``P = 2 p^2`` (the first image's
            half first, each row-major: `SparseDictionary.atoms`), floating point.

    Returns:
        The halves ``[..., N, 2, p, p]``: index 0 the first (left) image's, 1 the second's, each
        zero-mean (the part of an atom a zero-mean patch half can excite).

    Shape:
        - atoms: :math:`(..., 2 p^2, N)`
        - output: :math:`(..., N, 2, p, p)`

    Example:
        >>> atoms = torch.zeros(8, 1)
        >>> atoms[:4, 0] = torch.tensor([1.0, 2.0, 3.0, 4.0])   # left half only, p = 2
        >>> atom_halves(atoms)[0]
        tensor([[[-1.5000, -0.5000],
                 [ 0.5000,  1.5000]],
        <BLANKLINE>
                [[ 0.0000,  0.0000],
                 [ 0.0000,  0.0000]]])
    """
    if not isinstance(atoms, Tensor):
        raise TypeError(f"atoms must be a torch.Tensor [..., P, N], got {type(atoms).__name__}")
    if atoms.ndim < 2:
        raise ValueError(f"atoms must have shape [..., P, N] (atoms as columns), got {tuple(atoms.shape)}")
    if not atoms.is_floating_point():
        raise TypeError(f"atoms must be floating point, got dtype {atoms.dtype}")
    p = _patch_size(atoms.shape[-2])
    halves = atoms.detach().transpose(-1, -2).reshape(*atoms.shape[:-2], atoms.shape[-1], 2, p * p)
    halves = halves - halves.mean(-1, keepdim=True)
    return halves.reshape(*halves.shape[:-1], p, p)


def binocularity_index(atoms: Tensor) -> Tensor:
    """The binocularity index of each atom, ``(|R| - |L|) / (|R| + |L|)``.

    ``|L|`` and ``|R|`` are the L2 norms of the atom's two halves with their means removed
    (:func:`atom_halves`): -1 for an atom with only a left (first-image) half, +1 for one with
    only a right half, 0 for two halves of equal norm (the index of Klimmasch et al. 2021, eLife).
    An atom with two zero halves gets 0.

    Args:
        atoms: ``[..., P, N]``, atoms as columns (see :func:`atom_halves`).

    Returns:
        The index ``[..., N]`` in [-1, 1], in the dtype and on the device of ``atoms``.

    Example:
        >>> left = torch.tensor([1.0, -1.0, 1.0, -1.0])
        >>> zero = torch.zeros(4)
        >>> atoms = torch.stack([torch.cat([left, zero]), torch.cat([zero, left]),
        ...                      torch.cat([left, left]), torch.cat([left, 3 * left])], dim=1)
        >>> binocularity_index(atoms)
        tensor([-1.0000,  1.0000,  0.0000,  0.5000])
    """
    norms = torch.linalg.vector_norm(atom_halves(atoms).flatten(-2), dim=-1)
    left, right = norms.unbind(-1)
    total = left + right
    return torch.where(total > 0, (right - left) / torch.where(total > 0, total, torch.ones_like(total)),
                       torch.zeros_like(total))


def _counts(bins: Tensor, size: int) -> Tensor:
    """Counts of the bin indices ``bins [..., N]`` in ``size`` bins, ``[..., size]`` (int64)."""
    counts = torch.zeros(*bins.shape[:-1], size, dtype=torch.int64, device=bins.device)
    return counts.scatter_add_(-1, bins, torch.ones_like(bins))


def binocularity_histogram(index: Tensor, bins: int = BINOCULARITY_BINS) -> tuple[Tensor, Tensor]:
    """Counts of binocularity indices in ``bins`` equal bins over [-1, 1].

    Bin i holds ``edges[i] <= index < edges[i + 1]``, the last bin also ``index = 1``.

    Args:
        index: binocularity indices ``[..., N]`` (:func:`binocularity_index`).
        bins: the number of bins (default 7: the ocular-dominance groups' count).

    Returns:
        ``(counts [..., bins] int64, edges [bins + 1])``, on the device of ``index``.

    Example:
        >>> counts, edges = binocularity_histogram(torch.tensor([-1.0, -0.1, 0.0, 0.05, 1.0]), bins=4)
        >>> counts, edges
        (tensor([1, 1, 2, 1]), tensor([-1.0000, -0.5000,  0.0000,  0.5000,  1.0000]))
    """
    check_int(bins, "bins")
    _check_values(index, "index")
    edges = torch.linspace(-1.0, 1.0, bins + 1, dtype=index.dtype, device=index.device)
    which = torch.bucketize(index.clamp(-1.0, 1.0).contiguous(), edges[1:-1].contiguous(), right=True)
    return _counts(which, bins), edges


def _check_values(values: Tensor, name: str) -> None:
    if not isinstance(values, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor [..., N], got {type(values).__name__}")
    if values.ndim < 1:
        raise ValueError(f"{name} must have shape [..., N], got a scalar")


def disparity_tuning(atoms: Tensor, max_disparity: int | None = None) -> tuple[Tensor, Tensor]:
    """Each atom's disparity tuning curve: its mean squared response to white-noise stereograms.

    The stimulus at disparity ``d`` (pixels of the atom's scale) is a random-dot stereogram: a
    white-noise image ``s`` (unit variance) seen by the left half as ``s[y, x]`` and by the right
    half as ``s[y, x - d]``, the same texture ``d`` pixels further right (``d > 0``: the right
    eye's image is shifted right). The response of an atom with halves ``L``, ``R`` (means
    removed, :func:`atom_halves`) is ``r = <L, s> + <R, s(. - d)>``, and over the noise

        E[r^2] = |L|^2 + |R|^2 + 2 C(d),    C(d) = sum_{y, x} L[y, x] R[y, x + d]

    (``R`` read as 0 outside the patch): the tuning curve is the horizontal cross-correlation of
    the two halves. It is returned normalised by ``|L|^2 + |R|^2``, ``1 + 2 C(d) / (|L|^2 + |R|^2)``,
    which lies in [0, 2]: 2 where the right half is the left half shifted by ``d`` (the atom's
    disparity), 0 where it is its negative, 1 throughout for an atom with one half zero (no
    disparity signal). The patches' contrast normalisation is left out (it rescales every
    stimulus alike in expectation). For the stereo cue's images (columns left to right as seen),
    ``d > 0`` is an uncrossed disparity (the surface beyond the fixation point), ``d < 0`` a
    crossed one.

    Args:
        atoms: ``[..., P, N]``, atoms as columns (see :func:`atom_halves`).
        max_disparity: the largest |d| (pixels), ``0 <= max_disparity < p``; default ``p - 1``,
            every shift that leaves an overlap.

    Returns:
        ``(tuning [..., N, 2 D + 1], disparities [2 D + 1])``: the normalised energy at each
        disparity ``-D .. D`` (an atom with two zero halves: 1 throughout) and those disparities
        (int64), on the device of ``atoms``.

    Example:
        >>> left = torch.zeros(4, 4); left[:, 1] = 1.0                  # a vertical bar, p = 4
        >>> right = torch.roll(left, shifts=1, dims=1)                  # the same bar 1 px right
        >>> atoms = torch.cat([left.flatten(), right.flatten()])[:, None]
        >>> tuning, disparities = disparity_tuning(atoms, max_disparity=2)
        >>> disparities[tuning[0].argmax()].item()
        1
    """
    halves = atom_halves(atoms)
    p = halves.shape[-1]
    d = p - 1 if max_disparity is None else max_disparity
    check_int(d, "max_disparity", 0)
    if d >= p:
        raise ValueError(f"max_disparity must be below the patch size {p} (an overlap left), got {d}")
    left, right = halves.unbind(-3)
    # right's columns x + d for d = -D .. D: pad D zeros each side, windows of p columns.
    windows = torch.nn.functional.pad(right, (d, d)).unfold(-1, p, 1)  # [..., N, p, 2D+1, p]
    cross = torch.einsum("...yx,...ydx->...d", left, windows)
    energy = left.square().sum((-2, -1)) + right.square().sum((-2, -1))
    scale = torch.where(energy > 0, energy, torch.ones_like(energy)).unsqueeze(-1)
    tuning = torch.where(energy.unsqueeze(-1) > 0, 1.0 + 2.0 * cross / scale, torch.ones_like(cross))
    return tuning, torch.arange(-d, d + 1, device=atoms.device)


class DisparityPreference(NamedTuple):
    """What :func:`preferred_disparity` returns.

    Attributes:
        disparity: each atom's preferred disparity in pixels, ``[..., N]`` (int64): where its
            tuning curve peaks (the smallest |d| on a tie, then the negative).
        modulation: the tuning curve's depth of modulation, ``(max - min) / (max + min)`` in [0, 1],
            ``[..., N]``: 0 for a flat curve (a monocular atom), 1 where it touches 0.
    """

    disparity: Tensor
    modulation: Tensor


def preferred_disparity(tuning: Tensor, disparities: Tensor) -> DisparityPreference:
    """Each atom's preferred disparity and depth of modulation, from its tuning curve.

    Args:
        tuning: tuning curves ``[..., N, K]`` (:func:`disparity_tuning`), non-negative.
        disparities: the disparity of each of the ``K`` columns ``[K]``.

    Returns:
        A :class:`DisparityPreference` of ``[..., N]`` tensors.

    Example:
        >>> tuning = torch.tensor([[1.0, 1.5, 2.0], [1.0, 1.0, 1.0]])
        >>> preferred_disparity(tuning, torch.tensor([-1, 0, 1]))
        DisparityPreference(disparity=tensor([1, 0]), modulation=tensor([0.3333, 0.0000]))
    """
    if not isinstance(tuning, Tensor) or tuning.ndim < 1 or not isinstance(disparities, Tensor) \
            or disparities.shape != tuning.shape[-1:]:
        raise ValueError(f"tuning must be [..., N, K] and disparities [K], got {tuple(getattr(tuning, 'shape', ()))} "
                         f"and {tuple(getattr(disparities, 'shape', ()))}")
    # On a tie the smallest |d| wins (a flat curve prefers 0), then the negative one: order the
    # columns by |d| first, argmax keeps the first maximum.
    order = torch.argsort(disparities.abs() * 2 + (disparities > 0).long(), stable=True)
    peak = tuning[..., order].argmax(-1)
    high = tuning.amax(-1)
    low = tuning.amin(-1)
    total = high + low
    modulation = torch.where(total > 0, (high - low) / torch.where(total > 0, total, torch.ones_like(total)),
                             torch.zeros_like(total))
    return DisparityPreference(disparities.to(tuning.device)[order][peak], modulation)


def disparity_histogram(disparity: Tensor, max_disparity: int) -> tuple[Tensor, Tensor]:
    """Counts of preferred disparities, one bin per pixel of ``-max_disparity .. max_disparity``.

    Args:
        disparity: preferred disparities ``[..., N]`` (integers, :func:`preferred_disparity`).
        max_disparity: the largest |d|; disparities beyond it are counted in the end bins.

    Returns:
        ``(counts [..., 2 D + 1] int64, disparities [2 D + 1])``.

    Example:
        >>> disparity_histogram(torch.tensor([0, 0, 1, -2]), 2)
        (tensor([1, 0, 2, 1, 0]), tensor([-2, -1,  0,  1,  2]))
    """
    check_int(max_disparity, "max_disparity", 0)
    _check_values(disparity, "disparity")
    which = disparity.round().long().clamp(-max_disparity, max_disparity) + max_disparity
    disparities = torch.arange(-max_disparity, max_disparity + 1, device=disparity.device)
    return _counts(which, 2 * max_disparity + 1), disparities


class OrientationPreference(NamedTuple):
    """What :func:`orientation_preference` returns.

    Attributes:
        orientation_deg: each atom's preferred orientation in degrees, [0, 180), ``[..., N]``: the
            orientation of the stripes of its best-fitting grating, counter-clockwise from the
            image's rows as displayed (0 horizontal stripes, 90 vertical ones, 45 rising to the
            right).
        frequency: that grating's spatial frequency, cycles per pixel, ``[..., N]``.
        selectivity: how concentrated the atom's power is in orientation, in [0, 1]: the length of
            the power-weighted mean of ``exp(2 i theta)`` over the bank's plane waves, near 1 for a
            grating, near 0 for isotropic noise, ``[..., N]``.
    """

    orientation_deg: Tensor
    frequency: Tensor
    selectivity: Tensor


_BANKS: dict[tuple, tuple[Tensor, Tensor, Tensor]] = {}


def _plane_waves(p: int, orientations: int, frequencies: tuple[float, ...], dtype: torch.dtype,
                 device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    """The bank's waves on a ``p x p`` patch: ``(cos | sin [p^2, 2W], stripes_rad [W], frequency [W])``
    for ``W = orientations * len(frequencies)`` (cached)."""
    key = (p, orientations, frequencies, dtype, device)
    bank = _BANKS.get(key)
    if bank is None:
        stripes = torch.arange(orientations, dtype=torch.float64) * (math.pi / orientations)
        frequency = torch.tensor(frequencies, dtype=torch.float64)
        stripes, frequency = (t.reshape(-1) for t in torch.meshgrid(stripes, frequency, indexing="ij"))
        wave = stripes - math.pi / 2  # the wave vector is normal to the stripes; as displayed, y is up
        y, x = torch.meshgrid(torch.arange(p, dtype=torch.float64), torch.arange(p, dtype=torch.float64),
                              indexing="ij")
        phase = 2 * math.pi * frequency * (x.reshape(-1, 1) * torch.cos(wave) - y.reshape(-1, 1) * torch.sin(wave))
        waves, stripes, frequency = (t.to(dtype=dtype, device=device) for t in (
            torch.cat([torch.cos(phase), torch.sin(phase)], dim=1), stripes, frequency))
        bank = _BANKS[key] = (waves, stripes, frequency)
    return bank


def orientation_preference(atoms: Tensor, orientations: int = ORIENTATIONS,
                           frequencies: tuple[float, ...] = FREQUENCIES) -> OrientationPreference:
    """Each atom's preferred orientation: that of the grating which fits it best.

    The power of each half (mean removed, :func:`atom_halves`) at a bank of plane waves,
    ``orientations`` stripe orientations evenly over [0, 180) deg times ``frequencies`` (cycles per
    pixel), is ``|sum_r h[r] exp(-2 pi i k . r)|^2``, the patch's periodogram sampled on a polar
    grid; the two halves' powers are added (the halves of a binocular atom share an orientation; a
    monocular atom's zero half adds nothing) and the peak is taken. The periodogram's peak is the
    frequency of the single complex plane wave that fits the patch best in least squares, as a Gabor
    fit's carrier would be, without an iterative fit. The whole bank is one matrix product.

    Args:
        atoms: ``[..., P, N]``, atoms as columns (see :func:`atom_halves`).
        orientations: the bank's number of orientations (default 72: 2.5 deg apart).
        frequencies: the bank's spatial frequencies in cycles per pixel, each in (0, 0.5] (default
            0.05, 0.1, ..., 0.5: from half a cycle across a 10-pixel patch to the Nyquist limit).

    Returns:
        An :class:`OrientationPreference` of ``[..., N]`` tensors in the dtype and on the device
        of ``atoms`` (an atom with two zero halves: orientation 0, frequency 0, selectivity 0).

    Example:
        >>> y, x = torch.meshgrid(torch.arange(10.0), torch.arange(10.0), indexing="ij")
        >>> vertical = torch.cos(2 * math.pi * 0.25 * x)        # stripes along the columns
        >>> atoms = torch.cat([vertical.flatten(), vertical.flatten()])[:, None]
        >>> preference = orientation_preference(atoms)
        >>> preference.orientation_deg, preference.frequency
        (tensor([90.]), tensor([0.2500]))
    """
    check_int(orientations, "orientations")
    frequencies = tuple(float(f) for f in frequencies)
    if not frequencies or not all(0 < f <= 0.5 for f in frequencies):
        raise ValueError(f"frequencies must be cycles per pixel in (0, 0.5], at least one, got {frequencies}")
    halves = atom_halves(atoms)
    p = halves.shape[-1]
    waves, stripes, frequency = _plane_waves(p, orientations, frequencies, halves.dtype, halves.device)
    projections = halves.flatten(-2) @ waves  # [..., N, 2, 2W]: cos and sin parts
    power = projections.square().unflatten(-1, (2, -1)).sum((-3, -2))  # [..., N, W]
    peak = power.argmax(-1)
    total = power.sum(-1)
    doubled = torch.stack([torch.cos(2 * stripes), torch.sin(2 * stripes)])  # [2, W]
    resultant = torch.linalg.vector_norm(power @ doubled.T, dim=-1)
    empty = total <= 0
    selectivity = torch.where(empty, torch.zeros_like(total), resultant / torch.where(empty, torch.ones_like(total),
                                                                                       total))
    orientation = torch.rad2deg(stripes[peak])
    return OrientationPreference(torch.where(empty, torch.zeros_like(orientation), orientation),
                                 torch.where(empty, torch.zeros_like(total), frequency[peak]), selectivity)


def orientation_histogram(orientation_deg: Tensor, bins: int = ORIENTATION_BINS) -> tuple[Tensor, Tensor]:
    """Counts of orientations in ``bins`` bins over [0, 180) deg, centred on multiples of ``180 / bins``.

    Orientation is periodic: bin 0, centred on 0 deg (horizontal), also holds the orientations
    just below 180; with the default 8 bins, 90 deg (vertical) is the centre of bin 4.

    Args:
        orientation_deg: orientations ``[..., N]`` in degrees (any real; taken modulo 180).
        bins: the number of bins.

    Returns:
        ``(counts [..., bins] int64, centres_deg [bins])``.

    Example:
        >>> orientation_histogram(torch.tensor([0.0, 179.0, 90.0, 44.0]), bins=4)
        (tensor([2, 1, 1, 0]), tensor([  0.,  45.,  90., 135.]))
    """
    check_int(bins, "bins")
    _check_values(orientation_deg, "orientation_deg")
    width = 180.0 / bins
    which = torch.floor(torch.remainder(orientation_deg + width / 2, 180.0) / width).long().clamp(0, bins - 1)
    centres = torch.arange(bins, dtype=orientation_deg.dtype if orientation_deg.is_floating_point()
                           else torch.float32, device=orientation_deg.device) * width
    return _counts(which, bins), centres


def check_atoms(value, name: str = "atoms") -> Tensor:
    """``value`` as a finite floating-point ``[P, N]`` tensor of atoms (columns), or a
    ``ValueError`` that names ``name`` and what it got."""
    if not isinstance(value, Tensor):
        try:
            value = torch.as_tensor(value)
        except Exception as exc:  # noqa: BLE001 - re-raised as the documented ValueError
            raise ValueError(f"{name} must be a [P, N] tensor, got {type(value).__name__}") from exc
    if value.ndim != 2:
        raise ValueError(f"{name} must be a 2-D [P, N] tensor (atoms as columns), got shape {tuple(value.shape)}")
    if not value.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor, got dtype {value.dtype}")
    if not bool(torch.isfinite(value).all()):
        raise ValueError(f"{name} contains non-finite values (NaN or inf)")
    return value


def principal_components(atoms: Tensor, k: int = 2) -> tuple[Tensor, Tensor]:
    r"""PCA of a dictionary's atoms: their scores on the first ``k`` principal axes.

    The ``N`` atoms (columns of ``atoms``) are the samples: the mean atom is subtracted and the
    centred ``[N, P]`` matrix is decomposed by SVD. Scores and ratios equal scikit-learn's
    ``PCA(n_components=k).fit_transform(atoms.T)`` and ``explained_variance_ratio_`` up to the
    sign of each axis; here the sign is fixed so that each axis's largest-magnitude loading
    (first one on ties) is positive.

    Args:
        atoms: dictionary ``[P, N]``, floating point, finite; ``N >= 2`` atoms of dimension ``P``.
        k: number of principal axes, ``1 <= k <= min(N, P)``.

    Returns:
        ``(scores [N, k], explained_variance_ratio [k])`` in the dtype and on the device of
        ``atoms``. The ratio is the share of the total variance of the atoms per axis (zeros when
        all atoms are equal).

    Example:
        >>> atoms = torch.tensor([[0., 1., 2., 3.], [0., 2., 4., 6.], [1., 1., 1., 1.]])
        >>> scores, ratio = principal_components(atoms, k=1)
        >>> scores[:, 0]
        tensor([-3.3541, -1.1180,  1.1180,  3.3541])
        >>> ratio
        tensor([1.])
    """
    atoms = check_atoms(atoms)
    p, n = atoms.shape
    if not (is_int(k) and 1 <= k <= min(n, p)):
        raise ValueError(f"k must be an int in [1, min(N, P)] = [1, {min(n, p)}] for atoms of shape {(p, n)}, got {k!r}")
    if n < 2:
        raise ValueError(f"atoms must hold at least 2 atoms (columns), got shape {(p, n)}")
    x = atoms.detach().T
    x = x - x.mean(dim=0, keepdim=True)
    u, s, vh = torch.linalg.svd(x, full_matrices=False)
    u, s, vh = u[:, :k], s[:k], vh[:k]
    columns = vh.abs().argmax(dim=1)
    signs = torch.sign(vh.gather(1, columns[:, None]).squeeze(1))
    signs = torch.where(signs == 0, torch.ones_like(signs), signs)
    scores = u * (s * signs)
    variance = (x * x).sum()
    ratio = s.square() / variance if bool(variance > 0) else torch.zeros_like(s)
    return scores, ratio


class GaborBinocularity(NamedTuple):
    """What :func:`gabor_binocularity` returns, per atom ``[..., N]``.

    Attributes:
        binocularity: the index ``(R - L) / (R + L)`` in [-1, 1] (0 for an atom with two zero halves).
        valid: whether the dominant half's Gabor fit has a relative residual <= ``max_residual``.
        residual: that fit's relative residual.
    """

    binocularity: Tensor
    valid: Tensor
    residual: Tensor


def gabor_binocularity(atoms: Tensor, max_residual: float = 0.2, steps: int = 60) -> GaborBinocularity:
    """The binocularity index as Klimmasch et al. 2021 (eLife 10:e56212) measure it.

    A 2-D Gabor is fitted to the dominant half of each atom (the half of the larger norm, means
    removed: :func:`atom_halves`; :func:`fit_gabor`) and shown to both halves: ``L = |<left, G>|``
    and ``R = |<right, G>|``, and the index is ``(R - L) / (R + L)``, -1 left only, +1 right only.
    An atom whose fit leaves a relative residual above ``max_residual`` has no Gabor-like
    receptive field and is not valid (the lineage drops it). Ours, :func:`binocularity_index`,
    compares the halves' norms instead and needs no fit.

    Args:
        atoms: ``[..., P, N]``, atoms as columns (see :func:`atom_halves`).
        max_residual: the largest relative residual of a valid fit (the lineage's 0.2).
        steps: :func:`fit_gabor`'s steps.

    Returns:
        A :class:`GaborBinocularity` of ``[..., N]`` tensors.

    Example:
        >>> y, x = torch.meshgrid(torch.arange(10.0) - 4.5, torch.arange(10.0) - 4.5, indexing="ij")
        >>> g = (torch.exp(-(x ** 2 + y ** 2) / 8) * torch.cos(2 * math.pi * 0.2 * x)).flatten().double()
        >>> atoms = torch.stack([torch.cat([g, 0 * g]), torch.cat([g, g]), torch.cat([g, 3 * g])], 1)
        >>> result = gabor_binocularity(atoms)
        >>> result.binocularity, result.valid
        (tensor([-1.0000,  0.0000,  0.5000], dtype=torch.float64), tensor([True, True, True]))
    """
    halves = atom_halves(atoms)
    batch, p = halves.shape[:-3], halves.shape[-1]
    halves = halves.reshape(-1, 2, p * p)
    left, right = halves.unbind(-2)
    dominant = torch.where((right.square().sum(-1) > left.square().sum(-1))[:, None], right, left)
    fit = fit_gabor(dominant.reshape(-1, p, p), steps=steps)
    shown = fit.fitted.reshape(-1, 1, p * p)
    responses = (halves * shown).sum(-1).abs()
    low, high = responses.unbind(-1)
    total = low + high
    index = torch.where(total > 0, (high - low) / torch.where(total > 0, total, torch.ones_like(total)),
                        torch.zeros_like(total))
    return GaborBinocularity(index.reshape(batch), (fit.residual <= max_residual).reshape(batch),
                             fit.residual.reshape(batch))


def code_summary(atoms: Tensor, *, binocularity_bins: int = BINOCULARITY_BINS,
                 max_disparity: int | None = None, orientation_bins: int = ORIENTATION_BINS,
                 orientations: int = ORIENTATIONS, frequencies: tuple[float, ...] = FREQUENCIES) -> dict:
    """All read-outs of one dictionary as plain numbers (JSON-ready): what ``summary.json`` records.

    Args:
        atoms: one dictionary ``[P, N]``, atoms as columns.
        binocularity_bins, orientation_bins: the histograms' bins.
        max_disparity: the largest |d| of the disparity tuning (default ``p - 1``).
        orientations, frequencies: the bank of :func:`orientation_preference`.

    Returns:
        A dict of plain ints, floats and lists: ``atoms`` (N), ``patch_size`` (p) and three
        entries, each a histogram's bins, its ``counts`` and one mean:
        ``binocularity`` (``edges``, ``counts``, ``mean_abs_index``), ``disparity``
        (``disparities_px``, ``counts``, ``mean_modulation``) and ``orientation``
        (``centres_deg``, ``counts``, ``mean_selectivity``). The disparity histogram counts every
        atom's peak (a monocular atom's flat curve peaks at 0, see :func:`preferred_disparity`);
        ``mean_modulation`` says how deep the curves are.

    Example:
        >>> s = code_summary(torch.randn(200, 288, generator=torch.Generator().manual_seed(0)))
        >>> s["atoms"], s["patch_size"], [sum(s[part].get("counts")) for part in ("binocularity", "disparity")]
        (288, 10, [288, 288])
    """
    if not isinstance(atoms, Tensor) or atoms.ndim != 2:
        raise ValueError(f"atoms must be one dictionary [P, N], got {tuple(getattr(atoms, 'shape', ()))}")
    index = binocularity_index(atoms)
    b_counts, edges = binocularity_histogram(index, binocularity_bins)
    tuning, disparities = disparity_tuning(atoms, max_disparity)
    preference = preferred_disparity(tuning, disparities)
    d_counts, _ = disparity_histogram(preference.disparity, int(disparities[-1]))
    orientation = orientation_preference(atoms, orientations, frequencies)
    o_counts, centres = orientation_histogram(orientation.orientation_deg, orientation_bins)
    return {
        "atoms": int(atoms.shape[-1]),
        "patch_size": _patch_size(atoms.shape[-2]),
        "binocularity": {"edges": edges.tolist(), "counts": b_counts.tolist(),
                         "mean_abs_index": float(index.abs().mean())},
        "disparity": {"disparities_px": disparities.tolist(), "counts": d_counts.tolist(),
                      "mean_modulation": float(preference.modulation.mean())},
        "orientation": {"centres_deg": centres.tolist(), "counts": o_counts.tolist(),
                        "mean_selectivity": float(orientation.selectivity.mean())},
    }
