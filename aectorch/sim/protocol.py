"""The trial protocol's defaults, held once, and the interface every renderer satisfies.

:class:`TrialProtocol` is what a trial is: the renderer, the fixation length h, the body shift
and its profile, and whether pursuit is yoked. It is the one object that travels from the
experiment's `EnvConfig` (``EnvConfig.protocol``) to `ActiveDepthEnv` (``protocol=``) and the
evaluation (`aectorch.evaluation.run_trials`, `evaluate`), and the one place its rules are
checked.

:class:`Renderer` states what `ActiveDepthEnv` needs of a renderer; `TorchPlaneRenderer` and
`PyrenderRenderer` both satisfy it (``isinstance(r, Renderer)`` checks the methods' presence).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, Sequence, runtime_checkable

from torch import Tensor

from aectorch._checks import check_bool, check_choice, check_int, check_range, check_real
from aectorch.choices import RendererName
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.oculomotor import PAN_RANGE_DEG, VERGENCE_RANGE_DEG, check_oculomotor_range

__all__ = ["DEFAULT_APERTURE_M", "DEFAULT_PROTOCOL", "Renderer", "START_PURSUIT_DEG", "START_VERGENCE_DEG", "TrialProtocol",
           "resolve_protocol"]

#: The eyes at each fixation's start: the left eye straight ahead (pan 0) and the right eye
#: parallel to it (vergence 0), as in the paper; the evaluation always starts there.
START_PURSUIT_DEG = 0.0
START_VERGENCE_DEG = 0.0


@dataclass(frozen=True)
class TrialProtocol:
    """One trial's protocol (the paper's section 3, with the body movement's profile).

    Attributes:
        renderer: ``"torch"`` or ``"pyrender"``.
        fixation_iterations: h, iterations per fixation (paper: 30).
        shift_m: the body's lateral shift in each fixation, metres (paper: 0.1).
        shift_iterations: the shift grows linearly over the first this many iterations of a
            fixation and is then held (1: all of it before the first iteration).
        yoked_pursuit: pursuit increments move both eyes (Hering's law); ``False``: the dominant
            eye alone.
        q_iterations: the trial's eye movements q (the depth MLP's input) are each fixation's
            pan and vergence averaged over its last this many iterations (1, the paper: the
            last iteration's; at most ``fixation_iterations``).
        object_speed_deg: a moving object: ``(low, high)``, the range of its sideways speed in
            degrees per iteration, drawn uniformly per environment and fixation (positive: toward
            the robot's left; ``(-1, 1)`` draws both directions). The object's centre turns by it
            about the eyes' midpoint, from its start straight ahead at each fixation's start.
            ``(0, 0)`` (default): the object stands still, the paper's.
        object_depth_speed_m: the range of the object's speed in depth, metres per iteration,
            drawn per trial (negative: approaching; both fixations of a trial move alike from the
            trial's distance, so both end at the same distance, the depth's ground truth).
            ``(0, 0)`` (default): no motion in depth.
        aperture_m: the eyes' aperture (pupil diameter, metres): an eye focused at F dioptres
            (`ActiveDepthEnv.set_focus`) sees an object at d metres blurred by a disc of angular
            diameter ``aperture_m * |1 / d - F|`` radians; 0 is a pinhole. The default, 16 mm
            (`DEFAULT_APERTURE_M`), is four times a human pupil: the coder's pixels (0.22 deg) are
            some 25 times a foveal cone, and at 16 mm 0.25 D of defocus (what human accommodation
            resolves) blurs by 4 mrad, 0.23 deg, one coder pixel. The eyes stay focused on the
            object unless something sets their focus, so the default images are the pinhole's.
        accommodation_start_D: ``None`` (default): no accommodation cue, the eyes follow the
            object's focus. A number (dioptres, >= 0; 0 = infinity, the relaxed eye): the
            environment serves the ``accommodation`` cue (`ActiveDepthEnv.CUES`), and each
            fixation starts with both eyes focused there, as vergence starts parallel.
        yoked_accommodation: the accommodation cue's action focuses both eyes alike (default, as
            human accommodation does); ``False``: it focuses the left eye, and the
            ``accommodation_right`` cue the right one.
        pan_range_deg: ``(low, high)``, each eye's pan range in degrees, within the HOAP-3's
            joint limits (default +-45, the URDF's; `aectorch.sim.oculomotor`).
        vergence_range_deg: ``(low, high)``, the vergence's range in degrees (right pan minus
            left pan, positive converging); it holds 0. Default (-2, 40): 2 degrees past
            parallel to a near point of 8 cm.
        pursuit_velocity: the eyes keep a pursuit velocity that moves them on between iterations,
            learned by the ``slip`` cue from the retinal slip (the left eye's previous frame
            against its current one; `aectorch.sim.movements.slip`). ``False`` (default): the
            eyes move only by the cues' increments, the paper's.
        velocity_memory: with ``pursuit_velocity``, each pursuit step (the parallax cue's) also
            adds to the pursuit velocity, so that a lag pursuit keeps catching up on raises the
            velocity until it matches (integral action). Default ``False``.

    Example:
        >>> protocol = TrialProtocol(fixation_iterations=10)
        >>> protocol.shift_iterations, str(protocol.renderer)
        (20, 'torch')
        >>> resolve_protocol(protocol, shift_m=0.2).shift_m
        0.2
    """

    renderer: RendererName = RendererName.torch
    fixation_iterations: int = 30
    shift_m: float = 0.1
    shift_iterations: int = 20
    yoked_pursuit: bool = True
    q_iterations: int = 1
    object_speed_deg: tuple[float, float] = (0.0, 0.0)
    object_depth_speed_m: tuple[float, float] = (0.0, 0.0)
    aperture_m: float = 0.016
    accommodation_start_D: float | None = None
    yoked_accommodation: bool = True
    pan_range_deg: tuple[float, float] = PAN_RANGE_DEG
    vergence_range_deg: tuple[float, float] = VERGENCE_RANGE_DEG
    pursuit_velocity: bool = False
    velocity_memory: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "renderer", check_choice(self.renderer, "renderer", RendererName))
        check_int(self.fixation_iterations, "fixation_iterations")
        check_real(self.shift_m, "shift_m", minimum=0, unit="metres")
        check_int(self.shift_iterations, "shift_iterations")
        check_bool(self.yoked_pursuit, "yoked_pursuit")
        check_int(self.q_iterations, "q_iterations")
        check_real(self.aperture_m, "aperture_m", minimum=0, unit="metres")
        check_bool(self.yoked_accommodation, "yoked_accommodation")
        check_bool(self.pursuit_velocity, "pursuit_velocity")
        check_bool(self.velocity_memory, "velocity_memory")
        if self.velocity_memory and not self.pursuit_velocity:
            raise ValueError("velocity_memory needs pursuit_velocity=True (a velocity to remember the steps in)")
        if self.accommodation_start_D is not None:
            check_real(self.accommodation_start_D, "accommodation_start_D", minimum=0, unit="dioptres")
            if self.aperture_m == 0:
                raise ValueError("accommodation_start_D needs aperture_m > 0: a pinhole eye sees no defocus to "
                                 "learn accommodation from")
        object.__setattr__(self, "object_speed_deg", check_range(self.object_speed_deg, "object_speed_deg",
                                                                 unit="degrees per iteration"))
        object.__setattr__(self, "object_depth_speed_m", check_range(self.object_depth_speed_m, "object_depth_speed_m",
                                                                     unit="metres per iteration"))
        # (the joint limits are the environment's head's: `ActiveDepthEnv` checks them)
        pan, vergence = check_oculomotor_range(self.pan_range_deg, self.vergence_range_deg,
                                               pan_limits_deg=(-math.inf, math.inf))
        object.__setattr__(self, "pan_range_deg", pan)
        object.__setattr__(self, "vergence_range_deg", vergence)

    @property
    def moving(self) -> bool:
        """Whether the object moves (either speed range is not ``(0, 0)``)."""
        return self.object_speed_deg != (0.0, 0.0) or self.object_depth_speed_m != (0.0, 0.0)


#: The default protocol.
DEFAULT_PROTOCOL = TrialProtocol()
#: The eyes' default aperture for the world's defocus (`TrialProtocol.aperture_m`), metres.
DEFAULT_APERTURE_M = DEFAULT_PROTOCOL.aperture_m


@runtime_checkable
class Renderer(Protocol):
    """What `ActiveDepthEnv` calls on a renderer (the torch and the pyrender renderer both do).

    ``render`` / ``__call__`` draw one window ``[B, ..., h, w]``; ``render_windows`` several, each
    at its own downsampling, in one pass; ``close`` frees what the renderer holds (OpenGL
    contexts; nothing for the torch renderer). The arguments are those of
    `aectorch.sim.render_torch.render_planes`.
    """

    def __call__(self, poses: Tensor, plane_x_m: Tensor, texture_index: Tensor,
                 window: PixelWindow | None = None, *, check: bool = True,
                 plane_y_m: Tensor | None = None) -> Tensor: ...

    def render_windows(self, poses: Tensor, plane_x_m: Tensor, texture_index: Tensor,
                       windows: Sequence[tuple[PixelWindow, int]], *, check: bool = True,
                       camera: PinholeCamera | None = None, plane_y_m: Tensor | None = None) -> list[Tensor]: ...

    def close(self) -> None: ...


def resolve_protocol(protocol: TrialProtocol | None = None, **fields) -> TrialProtocol:
    """``protocol`` (default :data:`DEFAULT_PROTOCOL`) with the given fields that are not ``None``
    replaced: the command lines' single options over the run's protocol."""
    base = DEFAULT_PROTOCOL if protocol is None else protocol
    if not isinstance(base, TrialProtocol):
        raise ValueError(f"protocol must be a TrialProtocol, got {type(base).__name__}")
    given = {k: v for k, v in fields.items() if v is not None}
    return replace(base, **given) if given else base
