"""Perturbations of what the eyes see: each eye's mounting and optics, and the world's textures.

The seed paper's section 4 rolls one eye, then the other; the AEC lineage (Lonini et al. 2013,
Eckmann et al. 2020, Klimmasch et al. 2021) rears its models with one eye blurred, deprived,
squinting, magnified or moved, or in a world of one orientation. Here each is a small class
behind one protocol (:class:`Perturbation`), registered by name in :data:`PERTURBATIONS`
(:func:`make_perturbation`), that changes an :class:`Optics`: the state of both eyes and of the
world that `aectorch.sim.ActiveDepthEnv.set_optics` renders, in either renderer.

==========================  ======  ============================================================
kind                        acts on parameters
==========================  ======  ============================================================
``roll``                    an eye  ``deg``: rotation about the optical axis (the paper's)
``strabismus``              an eye  ``deg``: a fixed pan offset, positive inward (esotropia)
``vertical_misalignment``   an eye  ``deg``: a fixed elevation offset, positive up (hypertropia)
``anisometropia``           an eye  ``arcmin``: diameter of the defocus blur disc
``refractive_error``        an eye  ``dioptres``: the eye's focus offset (the world's defocus)
``monocular_deprivation``   an eye  ``contrast``: the image's contrast scaled to c (0 = grey)
``aniseikonia``             an eye  ``percent``: the image magnified by m %
``camera_shift``            an eye  ``x_m``, ``y_m``, ``z_m``: the camera translated (Lonini 2013)
``orientation_rearing``     world   ``orientation``, ``bandwidth_deg``: textures filtered to a band
==========================  ======  ============================================================

Perturbations compose: each applies to the :class:`Optics` the ones before it made (rolls, pan
offsets, elevation offsets, blur diameters, refractive errors and shifts add; contrasts and
magnifications multiply; orientation bands all filter). The geometric kinds act on the camera poses
(roll, pan offset, elevation offset, translation) or the camera's focal length (magnification), the image kinds on the rendered images
(blur, contrast), the refractive error on the eye's focus (the world's defocus, whose blur disc
follows the object's distance and the eye's accommodation) and the world kind on the textures, so
the torch and the pyrender renderer see the same thing.
The functions that do the image work are public: :func:`disc_kernel`, :func:`defocus`,
:func:`scale_contrast`, :func:`orientation_filter`.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, fields, replace
from typing import Any, ClassVar, Protocol, runtime_checkable

import torch
from torch import Tensor

from aectorch._checks import check_real, is_real
from aectorch.choices import PerturbationKind

__all__ = ["EYES", "NEUTRAL", "ORIENTATIONS", "Optics", "PERTURBATIONS", "Perturbation", "blur_margin",
           "defocus", "defocus_each", "disc_kernel", "disc_kernels", "make_perturbation", "orientation_filter", "scale_contrast"]

#: The eyes a perturbation can act on, in the order of the environment's eye index.
EYES = ("left", "right")
#: Named orientations of ``orientation_rearing``: the orientation of the stripes that pass, in
#: degrees counter-clockwise from horizontal as the robot sees them.
ORIENTATIONS = {"horizontal": 0.0, "oblique": 45.0, "vertical": 90.0}

Pair = tuple[float, float]
Vector = tuple[float, float, float]


@dataclass(frozen=True)
class Optics:
    """Both eyes' mounting and optics and the world's texture filter: what perturbations change.

    Every per-eye field is a ``(left, right)`` pair. The default is the unperturbed robot
    (:data:`NEUTRAL`).

    Attributes:
        roll_deg: rotation of each eye about its optical axis, degrees.
        pan_offset_deg: added to each eye's commanded pan, degrees (positive toward the robot's
            left, as pans are): where the eye points is the command plus this offset.
        elevation_offset_deg: each eye's elevation offset, degrees (positive up): the camera turned
            about its own horizontal axis after its pan and roll. The eyes have no tilt joint, so no
            command undoes it; the ground truth (the horizontal pans that fixate) is unchanged.
        shift_m: each camera's translation ``(x, y, z)`` in metres in the robot's frame (x forward,
            y left, z up).
        blur_arcmin: diameter of each eye's defocus blur disc, minutes of arc (0 = sharp).
        refraction_D: each eye's refractive error, dioptres: its focus offset from where its
            accommodation puts it (positive: focused nearer, myopic; negative: beyond, hyperopic),
            which `aectorch.sim.ActiveDepthEnv` renders as the world's defocus (0 = none).
        contrast: each eye's image contrast about its mean (1 = as rendered, 0 = uniform grey).
        magnification: each eye's image magnification about its centre (1 = none).
        orientation_bands: ``(orientation_deg, bandwidth_deg)`` bands the world's textures are
            filtered to (each keeps the stripes within ``bandwidth_deg / 2`` of its orientation);
            empty: the textures as they are.
    """

    roll_deg: Pair = (0.0, 0.0)
    pan_offset_deg: Pair = (0.0, 0.0)
    elevation_offset_deg: Pair = (0.0, 0.0)
    shift_m: tuple[Vector, Vector] = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    blur_arcmin: Pair = (0.0, 0.0)
    refraction_D: Pair = (0.0, 0.0)
    contrast: Pair = (1.0, 1.0)
    magnification: Pair = (1.0, 1.0)
    orientation_bands: tuple[Pair, ...] = ()

    def __post_init__(self) -> None:
        pairs = {name: tuple(float(v) for v in getattr(self, name))
                 for name in ("roll_deg", "pan_offset_deg", "elevation_offset_deg", "blur_arcmin", "refraction_D", "contrast",
                              "magnification")}
        for name, value in pairs.items():
            if len(value) != 2 or not all(math.isfinite(v) for v in value):
                raise ValueError(f"Optics.{name} must be a (left, right) pair of finite numbers, got {value!r}")
            object.__setattr__(self, name, value)
        shift = tuple(tuple(float(v) for v in eye) for eye in self.shift_m)
        if len(shift) != 2 or any(len(eye) != 3 or not all(math.isfinite(v) for v in eye) for eye in shift):
            raise ValueError(f"Optics.shift_m must be two (x, y, z) triples of finite numbers, got {self.shift_m!r}")
        object.__setattr__(self, "shift_m", shift)
        bands = tuple((float(o), float(w)) for o, w in self.orientation_bands)
        object.__setattr__(self, "orientation_bands", bands)
        if any(v < 0 for v in self.blur_arcmin):
            raise ValueError(f"Optics.blur_arcmin must be >= 0, got {self.blur_arcmin!r}")
        if any(v < 0 for v in self.contrast):
            raise ValueError(f"Optics.contrast must be >= 0, got {self.contrast!r}")
        if any(v <= 0 for v in self.magnification):
            raise ValueError(f"Optics.magnification must be > 0, got {self.magnification!r}")
        if any(not (0 < w <= 180) or not math.isfinite(o) for o, w in bands):
            raise ValueError(f"Optics.orientation_bands must hold (orientation, bandwidth in (0, 180]) pairs, "
                             f"got {bands!r}")

    # -- what is perturbed --------------------------------------------------------------------
    @property
    def mounting_neutral(self) -> bool:
        """No pan or elevation offset and no camera translation (the roll is the environment's ``roll_deg``)."""
        return (self.pan_offset_deg == NEUTRAL.pan_offset_deg and self.shift_m == NEUTRAL.shift_m
                and self.elevation_offset_deg == NEUTRAL.elevation_offset_deg)

    def images_neutral(self, eyes=(0, 1)) -> bool:
        """The eyes ``eyes`` (indices) render as they would unperturbed: no blur, contrast or magnification."""
        return all(self.blur_arcmin[e] == 0 and self.contrast[e] == 1 and self.magnification[e] == 1 for e in eyes)

    @property
    def is_neutral(self) -> bool:
        return self == NEUTRAL

    # -- state ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain lists and floats (a checkpoint holds it; :meth:`from_dict` reads it back)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, state: dict) -> "Optics":
        return cls(**{k: tuple(tuple(v) if isinstance(v, list) else v for v in value) if k in ("shift_m",
                      "orientation_bands") else tuple(value) for k, value in state.items()})


def _plain(value):
    return [_plain(v) for v in value] if isinstance(value, tuple) else value


#: The unperturbed robot.
NEUTRAL = Optics()


def _set_eye(pair: tuple, eye: int, value) -> tuple:
    return tuple(value if i == eye else v for i, v in enumerate(pair))


@runtime_checkable
class Perturbation(Protocol):
    """What a perturbation kind is: its parameters (a frozen dataclass's fields, checked when it is
    made, the message naming the parameter) and how it changes the :class:`Optics`.

    Attributes:
        kind: its name in :data:`PERTURBATIONS`.
        acts_on: ``"eye"`` (it needs an eye: 0 left, 1 right) or ``"world"`` (none).
    """

    kind: ClassVar[str]
    acts_on: ClassVar[str]

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        """``optics`` with this perturbation added (of eye ``eye``; ``None`` for the world)."""

    def describe(self) -> str:
        """A short label, e.g. ``roll 10 deg``."""


def _real(value, name: str, **bounds) -> float:
    return float(check_real(value, name, **bounds))


@dataclass(frozen=True)
class Roll:
    """The paper's perturbation (section 4): the eye rotated by ``deg`` about its optical axis."""

    deg: float
    kind: ClassVar[str] = "roll"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "deg", _real(self.deg, "deg", unit="degrees"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        return replace(optics, roll_deg=_set_eye(optics.roll_deg, eye, optics.roll_deg[eye] + self.deg))

    def describe(self) -> str:
        return f"roll {self.deg:g} deg"


@dataclass(frozen=True)
class Strabismus:
    """A squint: the eye's pan offset by ``deg`` from what it is commanded, positive inward
    (toward the nose: esotropia), negative outward (exotropia). The eye still moves with its
    commands; the vergence it needs to fixate differs by the offset."""

    deg: float
    kind: ClassVar[str] = "strabismus"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "deg", _real(self.deg, "deg", unit="degrees"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        inward = -self.deg if eye == 0 else self.deg  # the left eye turns inward to the right: negative pan
        return replace(optics, pan_offset_deg=_set_eye(optics.pan_offset_deg, eye, optics.pan_offset_deg[eye] + inward))

    def describe(self) -> str:
        return f"strabismus {self.deg:g} deg {'inward' if self.deg >= 0 else 'outward'}"


@dataclass(frozen=True)
class VerticalMisalignment:
    """A vertical squint: the eye turned ``deg`` up (hypertropia; negative down, hypotropia) from
    where it is commanded, about the camera's own horizontal axis. The HOAP-3's eyes pan and
    roll but have no tilt joint, so no eye movement undoes it: the two eyes' images keep a
    vertical disparity of ``deg`` that only the stereo code can learn to live with (a change of
    the plant for self-calibration). The fixating pans are unchanged."""

    deg: float
    kind: ClassVar[str] = "vertical_misalignment"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "deg", _real(self.deg, "deg", unit="degrees"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        offsets = optics.elevation_offset_deg
        return replace(optics, elevation_offset_deg=_set_eye(offsets, eye, offsets[eye] + self.deg))

    def describe(self) -> str:
        return f"vertical misalignment {self.deg:g} deg {'up' if self.deg >= 0 else 'down'}"


@dataclass(frozen=True)
class Anisometropia:
    """Defocus of one eye: its image blurred by a uniform disc of diameter ``arcmin`` (a blur
    disc's angular size; 0 = sharp). A later event's end corrects it."""

    arcmin: float
    kind: ClassVar[str] = "anisometropia"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "arcmin", _real(self.arcmin, "arcmin", minimum=0, unit="minutes of arc"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        return replace(optics, blur_arcmin=_set_eye(optics.blur_arcmin, eye, optics.blur_arcmin[eye] + self.arcmin))

    def describe(self) -> str:
        return f"anisometropia {self.arcmin:g} arcmin"


@dataclass(frozen=True)
class RefractiveError:
    """Refractive anisometropia: the eye's focus offset by ``dioptres`` from where its
    accommodation puts it (positive: focused nearer than the object, myopic; negative: beyond it,
    hyperopic). The environment renders it as the world's defocus, a disc of ``aperture_m *
    |dioptres|`` radians while the eyes' accommodation follows the object (at the default 16 mm,
    2 D: 110 arcmin), so it needs an aperture (``aperture_m > 0``); with the accommodation cue the
    disc follows the learned focus and the object's distance. A later event's end corrects it.

    Accommodation is yoked and stops at 0 D (infinity); the error is added after the stop (it is
    the eye's optics, not its accommodation): an eye 2 D myopic cannot be focused beyond 0.5 m
    by any accommodation, while a hyperopic one can, at the sharp eye's expense."""

    dioptres: float
    kind: ClassVar[str] = "refractive_error"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "dioptres", _real(self.dioptres, "dioptres", unit="dioptres"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        refraction = optics.refraction_D[eye] + self.dioptres
        return replace(optics, refraction_D=_set_eye(optics.refraction_D, eye, refraction))

    def describe(self) -> str:
        return f"refractive error {self.dioptres:+g} D"


@dataclass(frozen=True)
class MonocularDeprivation:
    """One eye's contrast scaled to ``contrast`` about the image's mean (0, the default: uniform
    grey, a closed or occluded eye; the mean luminance stays)."""

    contrast: float = 0.0
    kind: ClassVar[str] = "monocular_deprivation"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "contrast", _real(self.contrast, "contrast", minimum=0))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        return replace(optics, contrast=_set_eye(optics.contrast, eye, optics.contrast[eye] * self.contrast))

    def describe(self) -> str:
        return f"monocular deprivation, contrast {self.contrast:g}"


@dataclass(frozen=True)
class Aniseikonia:
    """One eye's image magnified by ``percent`` % about its centre (its camera's focal length
    times ``1 + percent / 100``; negative shrinks it)."""

    percent: float
    kind: ClassVar[str] = "aniseikonia"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        object.__setattr__(self, "percent", _real(self.percent, "percent", above=-100))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        return replace(optics, magnification=_set_eye(optics.magnification, eye,
                                                      optics.magnification[eye] * (1 + self.percent / 100)))

    def describe(self) -> str:
        return f"aniseikonia {self.percent:+g} %"


@dataclass(frozen=True)
class CameraShift:
    """One eye's camera translated by ``(x_m, y_m, z_m)`` metres in the robot's frame (x forward,
    y left, z up), as Lonini et al. 2013 displaced a camera. The ground truth follows the camera:
    the optimal pans are those of its new place."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    kind: ClassVar[str] = "camera_shift"
    acts_on: ClassVar[str] = "eye"

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "z_m"):
            object.__setattr__(self, name, _real(getattr(self, name), name, unit="metres"))

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        old = optics.shift_m[eye]
        new = (old[0] + self.x_m, old[1] + self.y_m, old[2] + self.z_m)
        return replace(optics, shift_m=_set_eye(optics.shift_m, eye, new))

    def describe(self) -> str:
        return f"camera shift ({self.x_m:g}, {self.y_m:g}, {self.z_m:g}) m"


@dataclass(frozen=True)
class OrientationRearing:
    """The world's textures (objects and background) filtered to one band of orientations, as
    in Blakemore and Cooper's striped cylinder: ``orientation`` ``"vertical"``,
    ``"horizontal"``, ``"oblique"`` (45 deg, rising to the right) or a number of degrees
    counter-clockwise from horizontal; the stripes within ``bandwidth_deg / 2`` of it pass."""

    orientation: Any = "vertical"
    bandwidth_deg: float = 30.0
    kind: ClassVar[str] = "orientation_rearing"
    acts_on: ClassVar[str] = "world"

    def __post_init__(self) -> None:
        if isinstance(self.orientation, str):
            if self.orientation not in ORIENTATIONS:
                raise ValueError(f"orientation must be one of {', '.join(map(repr, ORIENTATIONS))} or a number of "
                                 f"degrees, got {self.orientation!r}")
        elif not is_real(self.orientation):
            raise ValueError(f"orientation must be one of {', '.join(map(repr, ORIENTATIONS))} or a number of degrees, "
                             f"got {self.orientation!r}")
        bandwidth = _real(self.bandwidth_deg, "bandwidth_deg", above=0, unit="degrees")
        if bandwidth > 180:
            raise ValueError(f"bandwidth_deg must be at most 180 degrees, got {bandwidth!r}")
        object.__setattr__(self, "bandwidth_deg", bandwidth)

    @property
    def orientation_deg(self) -> float:
        return ORIENTATIONS[self.orientation] if isinstance(self.orientation, str) else float(self.orientation)

    def apply(self, optics: Optics, eye: int | None) -> Optics:
        return replace(optics, orientation_bands=optics.orientation_bands + ((self.orientation_deg, self.bandwidth_deg),))

    def describe(self) -> str:
        return f"orientation rearing {self.orientation} +-{self.bandwidth_deg / 2:g} deg"


#: The perturbation kinds by name (`aectorch.choices.PerturbationKind`): name -> class.
PERTURBATIONS: dict[PerturbationKind, type] = {
    PerturbationKind.roll: Roll,
    PerturbationKind.strabismus: Strabismus,
    PerturbationKind.anisometropia: Anisometropia,
    PerturbationKind.refractive_error: RefractiveError,
    PerturbationKind.monocular_deprivation: MonocularDeprivation,
    PerturbationKind.aniseikonia: Aniseikonia,
    PerturbationKind.orientation_rearing: OrientationRearing,
    PerturbationKind.camera_shift: CameraShift,
    PerturbationKind.vertical_misalignment: VerticalMisalignment,
}


def make_perturbation(kind: str, params: dict | None = None) -> Perturbation:
    """The perturbation ``kind`` (a name of :data:`PERTURBATIONS`) with its parameters.

    Raises ``ValueError`` naming what is wrong: an unknown kind (with the kinds), an unknown or
    missing parameter (with the kind's parameters), an impossible value (with the parameter).

    Example:
        >>> make_perturbation("roll", {"deg": 10}).apply(NEUTRAL, 1).roll_deg
        (0.0, 10.0)
        >>> make_perturbation("rol", {"deg": 10})
        Traceback (most recent call last):
        ...
        ValueError: kind must be one of 'roll', 'strabismus', 'anisometropia', 'refractive_error', \
'monocular_deprivation', 'aniseikonia', 'orientation_rearing', 'camera_shift', 'vertical_misalignment', \
got 'rol'
    """
    try:
        member = PerturbationKind(str(kind))
    except ValueError:
        names = ", ".join(repr(k) for k in PerturbationKind.values())
        raise ValueError(f"kind must be one of {names}, got {kind!r}") from None
    cls = PERTURBATIONS[member]
    params = dict(params or {})
    known = [f.name for f in fields(cls)]
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(f"params.{unknown[0]} is not a parameter of {member} (its parameters: {', '.join(known)})")
    try:
        return cls(**params)
    except TypeError:
        missing = [f.name for f in fields(cls) if f.name not in params and f.default is MISSING]
        raise ValueError(f"params.{missing[0]} is missing: {member} needs {', '.join(missing)}") from None
    except ValueError as err:
        raise ValueError(f"params.{err}") from None


# -- the image work ------------------------------------------------------------------------------
def blur_margin(radius_px: float) -> int:
    """Pixels a disc of ``radius_px`` (pixels), averaged over each pixel's area, reaches beyond
    the centre pixel: the margin :func:`defocus` consumes on every side (``ceil(radius_px)``)."""
    return max(0, math.ceil(radius_px - 1e-9))


def disc_kernel(radius_px: float, *, dtype: torch.dtype = torch.float32, device=None,
                subsamples: int = 16) -> Tensor:
    """The defocus kernel ``[2M + 1, 2M + 1]`` (M = :func:`blur_margin`): a rendered image, each
    pixel the area average of the scene, blurred by a uniform disc of ``radius_px`` pixels and
    averaged again over each pixel's area. Its pixels are taken as constant over their area, so
    each entry is the mean over the disc of the two pixel boxes' overlap (the tent ``max(0, 1 -
    |x|)`` per axis), from ``subsamples`` points per pixel along each axis; it sums to 1 and grows
    from the identity continuously with the radius (a disc within the centre pixel blurs too, as
    a lens's would; one smaller than a point spacing is the identity).

    Example:
        >>> k = disc_kernel(1.5)
        >>> k.shape, round(float(k.sum()), 6), bool(k[2, 2] > k[1, 2] > k[0, 2] > 0)
        (torch.Size([5, 5]), 1.0, True)
        >>> round(float(disc_kernel(0.25)[1, 1]), 3)
        0.805
    """
    return disc_kernels(torch.tensor([float(radius_px)], dtype=torch.float64), subsamples=subsamples)[0].to(
        dtype=dtype, device=device)


def defocus(images: Tensor, radius_px: float) -> Tensor:
    """``images`` ``[..., H, W]`` blurred by a disc of ``radius_px`` pixels (:func:`disc_kernel`),
    valid region only: ``[..., H - 2M, W - 2M]`` (the caller renders M = :func:`blur_margin`
    more pixels on every side)."""
    kernel = disc_kernel(radius_px, dtype=images.dtype, device=images.device)
    if kernel.numel() == 1:
        return images
    flat = images.reshape(-1, 1, *images.shape[-2:])
    out = torch.nn.functional.conv2d(flat, kernel[None, None])
    return out.reshape(*images.shape[:-2], *out.shape[-2:])


def disc_kernels(radius_px: Tensor, *, subsamples: int = 16) -> Tensor:
    """:func:`disc_kernel` of each radius of ``radius_px`` ``[N]`` (pixels), all padded to the largest
    one's size: ``[N, 2M + 1, 2M + 1]`` with M the largest :func:`blur_margin` (one host sync).

    Example:
        >>> k = disc_kernels(torch.tensor([0.0, 1.5]))
        >>> k.shape, torch.equal(k[1], disc_kernel(1.5)), float(k[0, 2, 2])
        (torch.Size([2, 5, 5]), True, 1.0)
    """
    margin = blur_margin(float(radius_px.max())) if radius_px.numel() else 0
    dtype = radius_px.dtype if radius_px.is_floating_point() else torch.float32
    if margin == 0:
        return torch.ones(radius_px.shape[0], 1, 1, dtype=dtype, device=radius_px.device)
    # Points on a grid of `subsamples` per pixel, the centre among them; each point's tent weights.
    points = torch.arange(-margin * subsamples, margin * subsamples + 1, dtype=torch.float64) / subsamples
    centres = torch.arange(-margin, margin + 1, dtype=torch.float64)
    tent = (1.0 - (centres[:, None] - points[None, :]).abs()).clamp_min(0.0).to(radius_px.device)  # [2M+1, P]
    square = (points[:, None] ** 2 + points[None, :] ** 2).to(radius_px.device)
    inside = (square <= radius_px.double()[:, None, None] ** 2).double()  # [N, P, P]; the centre always
    kernels = tent @ inside @ tent.T
    return (kernels / kernels.sum(dim=(1, 2), keepdim=True)).to(dtype)


def defocus_each(images: Tensor, radius_px: Tensor) -> Tensor:
    """Each image of ``images`` ``[N, ..., H, W]`` blurred by its own disc, ``radius_px`` ``[N]``
    (:func:`disc_kernels`), valid region only: ``[N, ..., H - 2M, W - 2M]`` with M the largest
    :func:`blur_margin`; :func:`defocus` of each image alone, in one grouped convolution."""
    kernels = disc_kernels(radius_px.to(images.device)).to(images.dtype)
    if kernels.shape[-1] == 1:
        return images
    per_image = images[0].numel() // (images.shape[-2] * images.shape[-1])  # images per row of the batch
    weight = kernels.repeat_interleave(per_image, dim=0)[:, None]  # [N * per_image, 1, K, K]
    flat = images.reshape(1, -1, *images.shape[-2:])
    out = torch.nn.functional.conv2d(flat, weight, groups=flat.shape[1])
    return out.reshape(*images.shape[:-2], *out.shape[-2:])


def scale_contrast(images: Tensor, contrast: float) -> Tensor:
    """Each image of ``images`` ``[..., H, W]`` with its contrast about its own mean scaled by
    ``contrast`` (0: uniform grey at the image's mean)."""
    mean = images.mean(dim=(-2, -1), keepdim=True)
    return mean + (images - mean) * contrast


def orientation_filter(images: Tensor, bands) -> Tensor:
    """Images ``[..., H, W]`` in [0, 1] filtered to bands of orientation.

    Each ``(orientation_deg, bandwidth_deg)`` band keeps the Fourier components whose stripes
    (perpendicular to the wave vector; degrees counter-clockwise from horizontal, rows running
    downward) lie within ``bandwidth_deg / 2`` of ``orientation_deg``; several bands multiply
    (only what every band passes stays). The mean stays; the filtered contrast is scaled back to
    the image's standard deviation and the result clipped to [0, 1].

    Example:
        >>> y, x = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
        >>> checks = 0.5 + 0.25 * (torch.sin(x) + torch.sin(y))  # vertical and horizontal stripes
        >>> out = orientation_filter(checks, [(90.0, 30.0)])
        >>> bool((out - out.mean(0)).abs().max() < 1e-4)  # only the vertical stripes: constant down columns
        True
    """
    bands = list(bands)
    if not bands:
        return images
    h, w = images.shape[-2:]
    data = images.double()
    fy = torch.fft.fftfreq(h, dtype=torch.float64)[:, None].expand(h, w)
    fx = torch.fft.fftfreq(w, dtype=torch.float64)[None, :].expand(h, w)
    # A wave vector (fx, fy) (rows running down) is (fx, -fy) seen with y up; its stripes are
    # perpendicular to it: at 90 - atan2(fy, fx) degrees (mod 180).
    stripes = 90.0 - torch.rad2deg(torch.atan2(fy, fx))
    mask = torch.ones(h, w, dtype=torch.float64)
    for orientation, bandwidth in bands:
        offset = torch.remainder(stripes - float(orientation) + 90.0, 180.0) - 90.0
        mask = mask * (offset.abs() <= bandwidth / 2 + 1e-9).double()
    mask[0, 0] = 1.0  # the mean
    spectrum = torch.fft.fft2(data)
    filtered = torch.fft.ifft2(spectrum * mask).real
    mean = data.mean(dim=(-2, -1), keepdim=True)
    std, new_std = data.std(dim=(-2, -1), keepdim=True), filtered.std(dim=(-2, -1), keepdim=True)
    filtered = mean + (filtered - mean) * (std / new_std.clamp_min(1e-12))
    return filtered.clamp(0.0, 1.0).to(images.dtype)
