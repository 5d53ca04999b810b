"""``ActiveDepthEnv``: B robots, each in front of its own textured plane, running the paper's protocol.

The protocol of section 2.1 of the paper, batched. A **trial** is one texture at one distance,
seen in two **fixations** of ``h`` iterations each: the body shifts ``shift_m`` to the left
(fixation 0, the "leftmost position"), then ``shift_m`` to the right (fixation 1, the "rightmost
position"). One **iteration** of one fixation is:

1. :meth:`ActiveDepthEnv.parallax_observation`: the dominant (left) eye's image at the starting
   position (taken once per fixation, before any movement) and its image at the current body
   shift with the current pan (motion parallax, cue *m*); the shift is all of ``shift_m`` from the
   first iteration on, or grows over the first ``shift_iterations`` of them;
2. :meth:`ActiveDepthEnv.apply_pursuit`: the pursuit increment is added to the left eye's pan
   (and to the right eye's too with ``yoked_pursuit``);
3. :meth:`ActiveDepthEnv.stereo_observation`: both eyes' images at the shifted position
   (stereo, cue *s*);
4. :meth:`ActiveDepthEnv.apply_vergence`: the vergence increment is added to the right eye's
   pan;
5. :meth:`ActiveDepthEnv.end_iteration`: the iteration ends, and the returned
   :class:`IterationInfo` carries the ground truth.

The cues are data (:attr:`ActiveDepthEnv.CUES`): each names the eye movement it drives, a
:class:`aectorch.sim.movements.Movement` class, of which the environment holds one object;
``observe(cue)``, ``act(cue, increments)`` and ``hold(cue)`` (the cue's movement put at its
optimum, for a learner without that cue) call that movement. Observations are dicts: ``{scale name: [B, 2, side, side]}`` for the
foveal scales asked for, and ``{WINDOW: [B, 2, h, w]}``, the whole rendered window, when no scales
are asked for or with ``window=True``.

At each fixation's start the left eye looks straight ahead (pan ``pursuit_start_deg``, default
0) and the right eye is parallel to it (vergence ``vergence_start_deg``, default 0), so the eye
movement, not the start state, carries the distance. The fixation target is the point where the
left eye's axis meets the plane at the start; the optimal pursuit pan keeps it on that axis after
the shift, and the optimal vergence puts the right eye's axis through the point where the left
axis meets the plane now. All environments run in lockstep (their fixations start together),
each with its own texture, distance and eye state.

Every movement ends within the **oculomotor range** (`aectorch.sim.oculomotor`): each eye's pan
within ``pan_range_deg`` and the vergence within ``vergence_range_deg`` (by default +-45 degrees,
the HOAP-3's joint limits, and 2 degrees past parallel to 40 degrees converged). It acts on the
pans, before either renderer draws them.

Angles are in degrees; pan is positive toward the robot's left (counter-clockwise seen from
above); the vergence angle is ``right pan - left pan`` (positive = converged).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from aectorch._checks import check_distances, check_int, check_real, is_real
from aectorch.sim import batch_state
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.ground_truth import fixation_target, ideal_q_deg
from aectorch.sim.hoap3 import HOAP3Head
from aectorch.sim.motion import MovingObject, check_object_motion
from aectorch.sim.movements import Accommodation, AccommodationRight, Movement, Pursuit, Slip, Vergence
from aectorch.sim.observations import (RENDERERS, SCALE_FILTER, WINDOW, EyeImages, check_window, make_renderer,
                                       pyramid_blur)
from aectorch.sim.oculomotor import check_oculomotor_range, clamp_eyes
from aectorch.sim.optics_state import EyeOptics
from aectorch.sim.perturbations import NEUTRAL, Optics
from aectorch.sim.proprioception import proprioception
from aectorch.sim.protocol import START_PURSUIT_DEG, START_VERGENCE_DEG, TrialProtocol, resolve_protocol
from aectorch.sim.scene import LayoutDraws, PlaneScene, SceneLayout
from aectorch.sim.textures import TextureBank, pink_noise_images

__all__ = ["ActiveDepthEnv", "IterationInfo", "RENDERERS", "DEFAULT_DISTANCES_M", "SCALE_FILTER", "WINDOW",
           "make_renderer", "pyramid_blur"]

#: The paper's object distances: 1.0 to 3.0 m in 0.1 m steps.
DEFAULT_DISTANCES_M = tuple(round(1.0 + 0.1 * i, 1) for i in range(21))
#: The cues an environment adds to :attr:`ActiveDepthEnv.CUES` when its protocol asks for them: the
#: retinal slip (``pursuit_velocity``, first in the order: it sees the left eye's previous frame
#: against its current one) and accommodation (``accommodation_start_D``; the right eye's a cue of
#: its own where accommodation is not yoked).
OPTIONAL_CUES: dict[str, type[Movement]] = {"slip": Slip, "accommodation": Accommodation,
                                            "accommodation_right": AccommodationRight}


class IterationInfo(NamedTuple):
    """What :meth:`ActiveDepthEnv.end_iteration` reports at the end of every iteration.

    All angles in degrees, each tensor ``[B]`` unless noted. Errors are actual minus optimal.
    """

    #: left-eye pan and right-eye pan after this iteration's increments.
    left_pan_deg: Tensor
    right_pan_deg: Tensor
    #: optimal left pan (keeps the fixation target) and optimal right pan (looks where the
    #: left axis meets the plane), for the state after the increments.
    optimal_left_pan_deg: Tensor
    optimal_right_pan_deg: Tensor
    pursuit_error_deg: Tensor
    vergence_error_deg: Tensor
    #: the iteration within the fixation that just ended (0 .. h-1), the fixation (0 = leftward,
    #: 1 = rightward) and whether this iteration ended a fixation or the whole trial.
    iteration: int
    fixation: int
    fixation_end: bool
    trial_end: bool
    #: ``[B, 4]`` final eye movements (q1 left pan and q2 vergence at the leftmost position,
    #: q3 and q4 at the rightmost one) of the trial that just ended, else ``None``.
    q_deg: Tensor | None
    #: the true distance of the trial that just ended (``None`` when no trial ended).
    distance_m: Tensor | None
    #: the errors ``[B]`` of the eye movements beyond pursuit and vergence (accommodation, the
    #: pursuit velocity, a movement a subclass adds: docs/architecture.md, "Adding a cue"), by name.
    extra_errors_deg: dict[str, Tensor] | None = None

    @property
    def errors_deg(self) -> dict[str, Tensor]:
        """Each eye movement's error ``[B]`` by the movement's name (`ActiveDepthEnv.CUES`)."""
        return {"pursuit": self.pursuit_error_deg, "vergence": self.vergence_error_deg,
                **(self.extra_errors_deg or {})}


def _range_or_value(value, name: str) -> tuple[float, float]:
    if is_real(value):
        lo = hi = float(value)
    else:
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a finite number or a (low, high) pair, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"{name} must be finite with low <= high, got {value!r}")
    return lo, hi


def _batch_rows(batch_slice: tuple[int, int] | None, num_envs: int) -> tuple[slice, int]:
    """The rows of ``batch_slice`` (``(start, total)``; ``None``: all ``num_envs``) and the batch's size, checked."""
    start, total = (0, num_envs) if batch_slice is None else (int(batch_slice[0]), int(batch_slice[1]))
    if not 0 <= start <= total - num_envs:
        raise ValueError(f"batch_slice=(start, total) must have 0 <= start <= total - num_envs = "
                         f"{total - num_envs}, got {batch_slice!r}")
    return slice(start, start + num_envs), total


def _oculomotor_range(head: HOAP3Head, protocol: TrialProtocol) -> tuple[tuple[float, float], tuple[float, float]]:
    """The protocol's oculomotor range, checked against the head's eye pan limits."""
    pans = head.limits_deg
    return check_oculomotor_range(protocol.pan_range_deg, protocol.vergence_range_deg,
                                  pan_limits_deg=(max(pans["left_eye_pan"][0], pans["right_eye_pan"][0]),
                                                  min(pans["left_eye_pan"][1], pans["right_eye_pan"][1])))


def _with_optional_cues(cues: dict[str, type[Movement]], protocol: TrialProtocol) -> dict[str, type[Movement]]:
    """``cues`` with the :data:`OPTIONAL_CUES` the protocol asks for: the slip cue first (it sees the
    frame the last iteration ended with), the accommodation cue(s) last."""
    accommodates = protocol.accommodation_start_D is not None
    return {**({"slip": Slip} if protocol.pursuit_velocity else {}), **cues,
            **({"accommodation": Accommodation} if accommodates else {}),
            **({"accommodation_right": AccommodationRight} if accommodates and not protocol.yoked_accommodation else {})}


def _check_trial(texture_index: Tensor, distance_m: Tensor, b: int, num_textures: int) -> None:
    """`ActiveDepthEnv.set_trial`'s arguments checked: shapes ``[B]``, distances > 0, textures in range."""
    if texture_index.shape != (b,) or distance_m.shape != (b,):
        raise ValueError(f"texture_index and distance_m must have shape [B] = [{b}] (num_envs), got "
                         f"{tuple(texture_index.shape)} and {tuple(distance_m.shape)}")
    if not bool((distance_m > 0).all()):
        raise ValueError(f"distance_m must be > 0 (metres in front of the eyes), got min {float(distance_m.min()):.4g}")
    if bool(((texture_index < 0) | (texture_index >= num_textures)).any()):
        raise IndexError(f"texture_index must be in [0, {num_textures}), got values "
                         f"{int(texture_index.min())}..{int(texture_index.max())}")


def _check_background(eye_x_m: float, distances: list[float], background_x_m: float) -> None:
    if eye_x_m + max(distances) >= background_x_m:
        raise ValueError(f"distances_m reach {max(distances)} m, behind the background plane at x = "
                         f"{background_x_m} m; use distances below {background_x_m - eye_x_m:.2f} m")


def _batch_keys(cls: type[ActiveDepthEnv]) -> tuple[str, ...]:
    """The keys of a state's per-environment tensors: those of every part and movement ``cls`` may hold."""
    return batch_state.batch_keys(MovingObject, EyeOptics, *cls.CUES.values(), *OPTIONAL_CUES.values(), LayoutDraws)


class ActiveDepthEnv:
    """B simulated HOAP-3 heads looking at textured planes, batched, with ground truth.

    Args:
        num_envs: number of environments B (>= 1).
        protocol: the trial protocol (`TrialProtocol`, default its defaults, the paper's): the
            renderer, h, the body shift and its profile, yoked pursuit, q's window, the moving
            object, the eyes' aperture and the accommodation cue, the pursuit velocity and the
            oculomotor range (its pan range is checked against ``head``'s joint limits here). An
            ``accommodation_start_D`` adds the ``accommodation`` cue(s) to :attr:`CUES`, a
            ``pursuit_velocity`` the ``slip`` cue (first: it sees the left eye's previous frame
            against its current one, `aectorch.sim.movements.slip`); a ``shift_iterations`` or
            ``q_iterations`` longer than the fixation is cut to ``fixation_iterations``.
        textures: object textures: a :class:`TextureBank`, a tensor ``[N, H, W]`` in [0, 1], or
            ``None`` for ``TextureBank.default("train")`` (100 procedural textures).
        distances_m: the object distances a trial draws from uniformly (metres from the eyes'
            centres along the robot's forward axis; each > 0); default 1.0 .. 3.0 m in 0.1 m steps.
        pursuit_start_deg: left-eye pan at each fixation's start: a number or a ``(low, high)``
            range drawn uniformly per environment and fixation.
        vergence_start_deg: right pan minus left pan at each fixation's start (0 = parallel),
            a number or a range.
        pursuit_start_error_deg: each fixation's eyes start turned off their target by an angle
            drawn uniformly from ``+-pursuit_start_error_deg`` (both eyes alike, the vergence
            kept), while the target and the parallax pair's first image are where the start pans
            above point: pursuit starts off its optimum on either side, as a fixation does after
            a saccade's error (>= 0; 0, the default and the paper's: every fixation starts on its
            target).
        window: ``"crops"`` renders only the central 128 x 128 pixels the coder uses (its
            central 80 x 80 is the fine scale's crop), ``"full"`` the whole frame, or a
            :class:`PixelWindow`.
        camera: intrinsics (default 320 x 240, 50 degrees vertical field of view).
        head: the kinematics (default: :class:`HOAP3Head` from ``robots/hoap3``).
        background: the background's texture ``[Hb, Wb]`` (default: a fixed 1/f texture).
        seed: seed of the environment's own generator (textures, distances, start states).
        device, dtype: where and in which float type poses and images live.
        renderer_options: passed on to the pyrender renderer, e.g. ``{"platform": "egl"}``.
        layout: the world's depth structure (`aectorch.sim.scene.SceneLayout`, drawn per trial:
            a narrower object moved sideways and slanted, before a background at its own distance
            and texture); ``None``: the plain world. Not with a moving object. **The optimum
            stays on the object** (`aectorch.sim.ground_truth`); the trial's distance is the pivot's.
        batch_slice: ``(start, total)``: these B environments are rows ``start .. start + B - 1``
            of a batch of ``total`` split across processes (`aectorch.runtime.distributed`). Every random
            draw is made for the whole batch and this slice kept, so the split batch behaves as
            one environment of ``total`` would. ``None``: the batch is these B.

    Example:
        >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(fixation_iterations=2), textures=torch.rand(3, 64, 64),
        ...                      seed=0)
        >>> first, second = env.parallax_observation()["window"].unbind(1)
        >>> first.shape
        torch.Size([2, 128, 128])
        >>> env.apply_pursuit(torch.tensor([-0.2, 0.1]))
        >>> left, right = env.stereo_observation()["window"].unbind(1)
        >>> env.apply_vergence(torch.zeros(2))
        >>> info = env.end_iteration()
        >>> info.iteration, info.fixation_end, info.errors_deg["pursuit"].shape
        (0, False, torch.Size([2]))
    """

    #: The depth cues this environment serves, in the paper's order (an iteration's steps k1, k2),
    #: each the eye movement it drives (`aectorch.sim.movements`): motion parallax (the dominant eye
    #: before and after the body shift) drives pursuit, stereo (both eyes) drives vergence.
    #: `observe`, `act` and `hold` take a cue's name; :data:`OPTIONAL_CUES` are added as configured.
    CUES: dict[str, type[Movement]] = {"parallax": Pursuit, "stereo": Vergence}

    def __init__(  # the world's and every movement's start settings: the public signature, kept
        self,
        num_envs: int = 1,
        *,
        protocol: TrialProtocol | None = None,
        textures=None,
        distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
        pursuit_start_deg=START_PURSUIT_DEG,
        vergence_start_deg=START_VERGENCE_DEG,
        pursuit_start_error_deg: float = 0.0,
        window: str | PixelWindow = "crops",
        camera: PinholeCamera | None = None,
        head: HOAP3Head | None = None,
        background: Tensor | None = None,
        seed: int = 0,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        renderer_options: dict | None = None,
        batch_slice: tuple[int, int] | None = None,
        layout: SceneLayout | None = None,
    ) -> None:
        check_int(num_envs, "num_envs")
        self.protocol = protocol = resolve_protocol(protocol)
        renderer, h = str(protocol.renderer), protocol.fixation_iterations
        distances = check_distances(distances_m, "distances_m")
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        self.num_envs = num_envs
        self._rows, self._draws = _batch_rows(batch_slice, num_envs)
        self.device, self.dtype = torch.device("cpu") if device is None else torch.device(device), dtype
        self.fixation_iterations, self.shift_m = h, float(protocol.shift_m)
        self.shift_iterations = min(protocol.shift_iterations, h)
        self.yoked_pursuit, self.q_iterations = protocol.yoked_pursuit, min(protocol.q_iterations, h)
        self.pursuit_start_deg = _range_or_value(pursuit_start_deg, "pursuit_start_deg")
        self.vergence_start_deg = _range_or_value(vergence_start_deg, "vergence_start_deg")
        self.pursuit_start_error_deg = float(check_real(pursuit_start_error_deg, "pursuit_start_error_deg", minimum=0))
        self.camera = camera or PinholeCamera()
        self.window = check_window(self.camera, window)
        self.head = (head or HOAP3Head()).to(device=self.device, dtype=dtype)
        self.pan_range_deg, self.vergence_range_deg = _oculomotor_range(self.head, protocol)
        self.textures = TextureBank.default("train") if textures is None else \
            textures if isinstance(textures, TextureBank) else TextureBank(textures)
        if background is None:
            background = pink_noise_images(1, 256, 256, generator=torch.Generator().manual_seed(20171028))[0]
        self.layout = SceneLayout() if layout is None else layout
        if not isinstance(self.layout, SceneLayout):
            raise TypeError(f"layout must be None or an aectorch.sim.scene.SceneLayout, got {type(layout).__name__}")
        self.layout_draws = LayoutDraws(self, self.layout)
        self.scene = self.built_scene = PlaneScene(self.textures.textures, background, **self.layout_draws.scene_arguments())
        self.aperture_m = protocol.aperture_m
        self.eye_optics = EyeOptics(self)  # perturbations: set_optics; focus: set_focus
        _check_background(float(self.head.eye_x_m), distances, self.scene.background_x_m)
        self.distances_m = torch.tensor(distances, dtype=dtype, device=self.device)
        self._init_movements(protocol, distances)
        self.renderer_name, self.renderer_options = renderer, dict(renderer_options or {})
        self.renderer = make_renderer(renderer, self.scene, self.camera, device=self.device, dtype=dtype,
                                      **self.renderer_options)
        self.images = EyeImages(self)
        self.seed = seed
        self.reset(seed)

    def _init_movements(self, protocol: TrialProtocol, distances: list[float]) -> None:
        """The cues the protocol asks for, their movements (by name) and the moving object, checked."""
        self.accommodation_start_D = protocol.accommodation_start_D
        self.yoked_accommodation = protocol.yoked_accommodation
        self.pursuit_velocity, self.velocity_memory = protocol.pursuit_velocity, protocol.velocity_memory
        if protocol.pursuit_velocity or protocol.accommodation_start_D is not None:
            self.CUES = _with_optional_cues(type(self).CUES, protocol)
        self._cues = {cue: movement(self) for cue, movement in self.CUES.items()}
        self.movements: dict[str, Movement] = {m.name: m for m in self._cues.values()}
        self.object_speed_deg, self.object_depth_speed_m = protocol.object_speed_deg, protocol.object_depth_speed_m
        check_object_motion(self.object_speed_deg, self.object_depth_speed_m, distances,
                            protocol.fixation_iterations, self.scene.background_x_m - float(self.head.eye_x_m))
        self.layout_draws.check(protocol)
        self.motion = MovingObject(self, self.object_speed_deg, self.object_depth_speed_m)

    # -- the trial clock ---------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Start a new trial in every environment (from ``seed`` when given)."""
        if seed is not None:
            self._generator = torch.Generator().manual_seed(int(seed))
        b = self.num_envs
        self.roll_deg = torch.zeros(b, 2, dtype=self.dtype, device=self.device)
        self.q_deg = torch.zeros(b, 4, dtype=self.dtype, device=self.device)
        self.q_sum_deg = torch.zeros(b, 2, dtype=self.dtype, device=self.device)
        self._new_trial()

    def uniform(self, bounds: Sequence[float]) -> Tensor:
        """A uniform draw ``[B]`` within ``bounds`` from the generator (for the whole batch, these rows kept)."""
        lo, hi = bounds
        u = torch.rand(self._draws, generator=self._generator, dtype=torch.float64)[self._rows]
        return (lo + (hi - lo) * u).to(self.dtype).to(self.device)

    def randint(self, high: int) -> Tensor:
        """Integers ``[B]`` in ``[0, high)`` from the environment's generator (as :meth:`uniform`), on CPU."""
        return torch.randint(high, (self._draws,), generator=self._generator)[self._rows]

    def _new_trial(self) -> None:
        index, pick = self.randint(len(self.textures)), self.randint(self.distances_m.numel())
        if self.layout.draws:
            self.layout_draws.draw(index)
        self.set_trial(index.to(self.device), self.distances_m[pick.to(self.device)])

    def set_trial(self, texture_index: Tensor, distance_m: Tensor) -> None:
        """Start a trial with the given textures ``[B]`` and distances ``[B]`` (metres, > 0).

        Evaluation grids use this to pin the conditions; training draws them at random.
        """
        texture_index = torch.as_tensor(texture_index, device=self.device)
        distance_m = torch.as_tensor(distance_m, dtype=self.dtype, device=self.device)
        _check_trial(texture_index, distance_m, self.num_envs, len(self.textures))
        self.texture_index, self.distance_m = texture_index.long(), distance_m
        self.plane_x_m = distance_m + float(self.head.eye_x_m)
        self._start_fixation(0)

    def _start_fixation(self, fixation: int) -> None:
        self.fixation, self.iteration = fixation, 0
        self.body_shift_m = self.body_shift(0)
        left = self.uniform(self.pursuit_start_deg)
        self.pan_deg = self.clamp_pan_deg(torch.stack((left, left + self.uniform(self.vergence_start_deg)), dim=-1))
        moves = self.motion.moves
        if moves or self.moving:  # the object back at its start (the trial's distance, straight ahead)
            self.motion.stop()
        self.target_m = fixation_target(self, self.eye_pan_deg[:, 0], self.plane_x_m)
        self._start_pans = self.pan_deg
        if self.pursuit_start_error_deg > 0:  # the eyes off the target and the first image's view
            error = self.uniform((-self.pursuit_start_error_deg, self.pursuit_start_error_deg))
            self.pan_deg = self.clamp_pan_deg(self.pan_deg + error[:, None])
        self.images.start_fixation()
        if moves:
            self.motion.start(fixation)
        for movement in self._cues.values():
            movement.start_fixation(fixation)
        self.images.moved()

    def body_shift(self, iteration: int) -> Tensor:
        """The body's shift ``[B]`` during ``iteration`` of the fixation (metres; all of ``shift_m``
        from the ``shift_iterations``-th on), to the left in fixation 0 and to the right in 1."""
        direction = 1.0 if self.fixation == 0 else -1.0
        zero = torch.zeros(self.num_envs, dtype=self.dtype, device=self.device)
        return zero + direction * self.shift_m * min(1.0, (iteration + 1) / self.shift_iterations)

    def end_iteration(self) -> IterationInfo:
        """End the iteration: the ground truth after its movements, and the next iteration, fixation
        or trial begins."""
        optimal_left, optimal_right = self.optimal_left_pan_deg(), self.optimal_right_pan_deg()
        extra = {name: m.error_deg() for name, m in self.movements.items() if name not in ("pursuit", "vergence")}
        iteration, fixation = self.iteration, self.fixation
        fixation_end = iteration == self.fixation_iterations - 1
        trial_end = fixation_end and fixation == 1
        q = distance = None
        if iteration >= self.fixation_iterations - self.q_iterations:  # q's window
            self.q_sum_deg = self.q_sum_deg + torch.stack((self.left_pan_deg, self.right_pan_deg - self.left_pan_deg), -1)
        if fixation_end:
            self.q_deg[:, 2 * fixation: 2 * fixation + 2] = self.q_sum_deg / self.q_iterations
            self.q_sum_deg = torch.zeros_like(self.q_sum_deg)
        eyes = self.eye_pan_deg  # where the eyes point (the commands, unless a squint offsets them)
        if trial_end:
            q, distance = self.q_deg.clone(), self.object_distance_m
            self._new_trial()
        elif fixation_end:
            self._start_fixation(1)
        else:
            self.iteration += 1
            if self.shift_iterations > self.iteration:  # the body moves on
                self.body_shift_m = self.body_shift(self.iteration)
                self.images.moved()
            if self.moving:  # and so does the object
                self.motion.place(self.iteration)
                self.images.moved()
            for movement in self._cues.values():  # and the eyes, at their pursuit velocity
                movement.between_iterations()
        return IterationInfo(
            left_pan_deg=eyes[:, 0], right_pan_deg=eyes[:, 1], optimal_left_pan_deg=optimal_left,
            optimal_right_pan_deg=optimal_right, pursuit_error_deg=eyes[:, 0] - optimal_left,
            vergence_error_deg=eyes[:, 1] - optimal_right, iteration=iteration, fixation=fixation,
            fixation_end=fixation_end, trial_end=trial_end, q_deg=q, distance_m=distance,
            extra_errors_deg=extra or None)

    # -- the cues ----------------------------------------------------------------------------------
    def cue(self, name: str) -> Movement:
        """The movement the cue ``name`` drives (``ValueError`` naming the cues otherwise)."""
        movement = self._cues.get(str(name))
        if movement is None:
            raise ValueError(f"cue must be one of {tuple(self.CUES)} (this environment's cues), got {name!r}")
        return movement

    def observe(self, cue: str, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The image pair of ``cue`` (its movement's observation, e.g. :meth:`stereo_observation`)."""
        return self.cue(cue).observe(scales, window=window)

    def act(self, cue: str, delta_deg: Tensor) -> None:
        """Add the increments ``[B]`` (degrees) of the eye movement ``cue`` drives."""
        self.cue(cue).act(delta_deg)

    def hold(self, cue: str) -> None:
        """Put the eye movement ``cue`` drives at its optimum (the increment that reaches it, within
        the eyes' limits): a learner without that cue (e.g. the vergence-only model) has it held."""
        movement = self.cue(cue)
        movement.act(movement.to_optimum())

    def parallax_observation(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The motion-parallax pair (`Pursuit.observe`): the left eye before the shift, then after it;
        ``scales``: ``None`` (the whole window) or foveal scales, ``window``: also the whole window."""
        return self.movements["pursuit"].observe(scales, window=window)

    def stereo_observation(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The stereo pair (`Vergence`): the left then the right eye at the shifted position;
        ``scales`` and ``window`` as for :meth:`parallax_observation`."""
        return self.movements["vergence"].observe(scales, window=window)

    def apply_pursuit(self, delta_deg: Tensor) -> None:
        """Add the pursuit increments ``[B]`` (degrees) to the left eye's pan (`Pursuit.act`)."""
        self.movements["pursuit"].act(delta_deg)

    def apply_vergence(self, delta_deg: Tensor) -> None:
        """Add the vergence increments ``[B]`` (degrees) to the right eye's pan (`Vergence.act`)."""
        self.movements["vergence"].act(delta_deg)

    def optimal_left_pan_deg(self, target_m: Tensor | None = None, body_shift_m: Tensor | None = None) -> Tensor:
        """The left pan that keeps the fixation target on the left axis at the shifted position
        (of the left eye's axis: with a squint's offset the command differs by it); ``target_m``
        ``[B, 3]`` and ``body_shift_m`` ``[B]`` default to now's."""
        return self.movements["pursuit"].optimal_pan_deg(target_m, body_shift_m)

    def optimal_right_pan_deg(self, left_pan_deg: Tensor | None = None) -> Tensor:
        """The right pan whose axis meets the plane where the left axis does (current left pan,
        of the eye's axis: :attr:`eye_pan_deg`)."""
        return self.movements["vergence"].optimal_pan_deg(left_pan_deg)

    # -- the head ----------------------------------------------------------------------------------
    def clamp_pan_deg(self, pan_deg: Tensor) -> Tensor:
        """Pans ``[B, 2]`` (left, right; degrees) brought within the head's joint limits and the
        oculomotor range (``pan_range_deg``, ``vergence_range_deg``; `aectorch.sim.oculomotor`):
        where every movement of the eyes ends."""
        return clamp_eyes(self.head.clamp_pan_deg(pan_deg), self.pan_range_deg, self.vergence_range_deg)

    def set_pan_deg(self, pan_deg) -> None:
        """Put the eyes at the given pans ``[B, 2]`` (left, right; degrees), within their range
        (:meth:`clamp_pan_deg`); for evaluation grids and tests: the fixation target does not change."""
        pan = torch.as_tensor(pan_deg, dtype=self.dtype, device=self.device)
        if pan.shape != (self.num_envs, 2):
            raise ValueError(f"pan_deg must have shape [B, 2] = [{self.num_envs}, 2], got {tuple(pan.shape)}")
        self.pan_deg = self.clamp_pan_deg(pan)
        self.images.moved()

    def set_roll(self, roll_deg) -> None:
        """Set each eye's roll about its optical axis (the perturbation), ``[2]`` or ``[B, 2]``, degrees."""
        roll = torch.as_tensor(roll_deg, dtype=self.dtype, device=self.device)
        if roll.shape not in ((2,), (self.num_envs, 2)):
            raise ValueError(f"roll_deg must have shape [2] or [B, 2] = [{self.num_envs}, 2], got {tuple(roll.shape)}")
        self.roll_deg = roll.expand(self.num_envs, 2).clone()
        self.eye_optics.optics = replace(self.optics, roll_deg=tuple(self.roll_deg[0].tolist()))
        self.images.moved()

    @property
    def eye_pan_deg(self) -> Tensor:
        """Where the eyes point ``[B, 2]`` (left, right; degrees): the commanded pans
        (:attr:`pan_deg`) plus a squint's offset (`Optics.pan_offset_deg`)."""
        if self.optics.pan_offset_deg == NEUTRAL.pan_offset_deg:
            return self.pan_deg
        return self.pan_deg + self.eye_optics.tensor("pan_offset_deg")

    @property
    def left_pan_deg(self) -> Tensor:
        """Current left-eye (dominant) pan ``[B]``, degrees."""
        return self.pan_deg[:, 0]

    @property
    def right_pan_deg(self) -> Tensor:
        """Current right-eye pan ``[B]``, degrees."""
        return self.pan_deg[:, 1]

    @property
    def vergence_deg(self) -> Tensor:
        """Current vergence angle ``[B]``: right pan minus left pan (positive = converged)."""
        return self.pan_deg[:, 1] - self.pan_deg[:, 0]

    def proprioception(self, names) -> Tensor:
        """What the eyes sense of themselves now, ``[B, len(names)]``: efference copies of the
        commands, one column per name of `aectorch.choices.Proprioception` (`aectorch.sim.proprioception`).

        Example:
            >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(accommodation_start_D=0.0),
            ...                      textures=torch.rand(2, 64, 64), seed=0)
            >>> env.proprioception(["vergence", "focus"]).shape
            torch.Size([2, 2])
        """
        return proprioception(self, names)

    # -- the object and the eyes' optics -----------------------------------------------------------
    @property
    def moving(self) -> bool:
        """Whether the object moves in this fixation (drawn or pinned speeds when it began)."""
        return self.motion.speed is not None

    @property
    def object_distance_m(self) -> Tensor:
        """The object's distance now ``[B]`` (metres; the trial's distance unless it moves)."""
        return self.plane_x_m - float(self.head.eye_x_m) if self.moving else self.distance_m

    def set_object_speed(self, speed_deg=None, depth_speed_m=None) -> None:
        """Pin the moving object's speeds from the next fixation on (`MovingObject.pin`)."""
        self.motion.pin(speed_deg, depth_speed_m)

    @property
    def optics(self) -> Optics:
        """The eyes' and the world's perturbations now (:meth:`set_optics`)."""
        return self.eye_optics.optics

    @property
    def focus_dioptres(self) -> Tensor | None:
        """Each eye's focus ``[B, 2]`` (dioptres), or ``None``: each eye focused on the object."""
        return self.eye_optics.focus_dioptres

    @property
    def defocus_dioptres(self) -> Tensor:
        """Each eye's defocus ``[B, 2]``, dioptres (`EyeOptics.defocus`)."""
        return self.eye_optics.defocus()

    def set_focus(self, dioptres=None) -> None:
        """Focus each eye at ``dioptres`` from now on (`EyeOptics.set_focus`; ``None``: on the object)."""
        self.eye_optics.set_focus(dioptres)
        self.images.moved()

    def set_optics(self, optics: Optics) -> None:
        """Perturb the eyes and the world as ``optics`` says (`EyeOptics.set_optics`); the world's
        textures filtered to its orientation bands (`EyeImages.rebuild_world`)."""
        world_changed = isinstance(optics, Optics) and optics.orientation_bands != self.optics.orientation_bands
        self.eye_optics.set_optics(optics)
        self.roll_deg = torch.tensor(optics.roll_deg, dtype=self.dtype, device=self.device).expand(self.num_envs, 2).clone()
        if world_changed:
            self.images.rebuild_world(optics.orientation_bands)
        self.images.moved()

    # -- ground truth ------------------------------------------------------------------------------
    def ideal_q_deg(self, distance_m: Tensor | None = None, *, start_pan_deg: float = 0.0) -> Tensor:
        """The final eye movements ``q`` ``[N, 4]`` (degrees) of a perfectly fixating trial at
        ``distance_m`` ``[N]`` (default the current trials'), its fixations starting from the left
        pan ``start_pan_deg`` (`aectorch.sim.ground_truth`)."""
        return ideal_q_deg(self, distance_m, start_pan_deg)

    # -- checkpoints (`aectorch.sim.batch_state`) --------------------------------------------------
    def state_dict(self) -> dict:
        """Everything that determines the environments' future (not the configuration: build the
        environment with the same arguments, then :meth:`load_state_dict`; `aectorch.sim.batch_state`)."""
        return batch_state.state_dict(self)

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` taken from an environment built with the same arguments."""
        batch_state.load_state_dict(self, state)

    def state_parts(self) -> list:
        """The parts of the batch state with their own tensors, in the state's order."""
        return [self.motion, self.eye_optics, *self._cues.values(), self.layout_draws]

    @classmethod
    def join_states(cls, states: list[dict]) -> dict:
        """The :meth:`state_dict` of the whole batch from those of its parts (`batch_state.join_states`)."""
        return batch_state.join_states(states, _batch_keys(cls))

    @classmethod
    def state_rows(cls, state: dict, start: int, stop: int) -> dict:
        """The :meth:`state_dict` of environments ``start .. stop - 1`` (`batch_state.state_rows`)."""
        return batch_state.state_rows(state, start, stop, _batch_keys(cls))

    def close(self) -> None:
        """Free the renderers' resources (pyrender's OpenGL contexts); the environment cannot
        render afterwards. Also ``with ActiveDepthEnv(...) as env:``."""
        self.renderer.close()
        self.images.close()

    def __enter__(self) -> "ActiveDepthEnv":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"ActiveDepthEnv(num_envs={self.num_envs}, renderer={self.renderer_name!r}, textures={len(self.textures)}, "
                f"h={self.fixation_iterations}, shift_m={self.shift_m}, shift_iterations={self.shift_iterations}, "
                f"yoked_pursuit={self.yoked_pursuit}, q_iterations={self.q_iterations}, pan_range_deg="
                f"{self.pan_range_deg}, vergence_range_deg={self.vergence_range_deg}, window={tuple(self.window)}, "
                f"device={self.device}, dtype={self.dtype})")
