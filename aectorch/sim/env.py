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

The cues are data (:attr:`ActiveDepthEnv.CUES`): ``observe(cue)``, ``act(cue, increments)`` and
``hold(cue)`` (the cue's movement put at its optimum, for a learner without that cue) call a
cue's methods by its name. Observations are dicts: ``{scale name: [B, 2, side, side]}`` for the
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

from aectorch._checks import check_choice, check_distances, check_int, check_real, is_real
from aectorch.choices import Proprioception, RendererName
from aectorch.ops.backend import fused_kernels_apply
from aectorch.sim.camera import PinholeCamera, PixelWindow
from aectorch.sim.hoap3 import HOAP3Head
from aectorch.sim.motion import check_object_motion, object_place
from aectorch.sim.oculomotor import check_oculomotor_range, clamp_eyes
from aectorch.sim.perturbations import (NEUTRAL, Optics, blur_margin, defocus, defocus_each, orientation_filter,
                                        scale_contrast)
from aectorch.sim.scene import Placement, PlaneScene, SceneLayout, axis_point
from aectorch.sim.protocol import START_PURSUIT_DEG, START_VERGENCE_DEG, TrialProtocol, resolve_protocol
from aectorch.sim.textures import TextureBank, pink_noise_images

__all__ = ["ActiveDepthEnv", "CueSpec", "IterationInfo", "RENDERERS", "DEFAULT_DISTANCES_M", "SCALE_FILTER",
           "WINDOW", "make_renderer", "pyramid_blur"]

#: The key of an observation's whole rendered window, ``[B, 2, H, W]``, beside the scales' entries
#: ``{scale name: [B, 2, side, side]}``. The coder reads the same key (``aectorch.coding.WINDOW``;
#: the two packages stand side by side and do not import each other; tests/sim/test_sim.py checks
#: that they agree).
WINDOW = "window"
#: The paper's object distances: 1.0 to 3.0 m in 0.1 m steps.
DEFAULT_DISTANCES_M = tuple(round(1.0 + 0.1 * i, 1) for i in range(21))
#: Renderer names accepted by ``renderer=``.
RENDERERS = RendererName.values()


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
    #: the errors ``[B]`` of the eye movements an environment adds to pursuit and vergence (a
    #: subclass with a cue of its own: docs/architecture.md, "Adding a cue"), by movement name.
    extra_errors_deg: dict[str, Tensor] | None = None

    @property
    def errors_deg(self) -> dict[str, Tensor]:
        """Each eye movement's error ``[B]`` by the movement's name (`ActiveDepthEnv.CUES`)."""
        return {"pursuit": self.pursuit_error_deg, "vergence": self.vergence_error_deg,
                **(self.extra_errors_deg or {})}


class CueSpec(NamedTuple):
    """What a depth cue is in the environment (`ActiveDepthEnv.CUES`): method names.

    Attributes:
        movement: the eye movement the cue's action drives (its error is
            ``IterationInfo.errors_deg[movement]``).
        observe: the method returning the cue's image pair (``scales=None, *, window=False``).
        act: the method adding the cue's increments ``[B]`` (degrees).
        to_optimum: the method returning the increments ``[B]`` that put the movement at its
            optimum now (`ActiveDepthEnv.hold`).
        images: names of the pair's two images (the eye, and ``_before`` for the image at the
            fixation's start position): the viewer's titles, the LeRobot recording's cameras.
    """

    movement: str
    observe: str
    act: str
    to_optimum: str
    images: tuple[str, str]


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


#: The accommodation cue (`ActiveDepthEnv.CUES` with ``accommodation_start_D``): it sees the stereo
#: pair after vergence and changes both eyes' focus; its error is the blur disc's signed diameter.
ACCOMMODATION = CueSpec("accommodation", "stereo_observation", "apply_accommodation", "accommodation_to_optimum",
                        ("left", "right"))
#: The right eye's accommodation, a cue of its own where accommodation is not yoked.
ACCOMMODATION_RIGHT = CueSpec("accommodation_right", "stereo_observation", "apply_accommodation_right",
                              "accommodation_right_to_optimum", ("left", "right"))


#: The retinal-slip cue (`ActiveDepthEnv.CUES` with ``pursuit_velocity``, first in the order): it
#: sees the left eye's previous frame (the end of the last iteration) against its current one and
#: changes the eyes' pursuit velocity, which moves them on between iterations; its error is that
#: velocity against the optimal pan's change over the next iteration (degrees per iteration).
SLIP = CueSpec("pursuit_velocity", "slip_observation", "apply_slip", "slip_to_optimum", ("left_previous", "left"))


#: How :meth:`ActiveDepthEnv.parallax_observation` and ``stereo_observation`` render the foveal
#: scales they are asked for: mipmapped textures (``GL_LINEAR_MIPMAP_LINEAR``), 2 x 2 lookups per
#: pixel at a level of detail biased by -0.5: within 0.5 % of the exact area average
#: (docs/simulation.md, tests/sim/test_sim.py).
SCALE_FILTER = dict(filter="trilinear", lod_bias=-0.5, samples=2)


def _finer(downsample: int) -> int:
    """Scales reduced 16x or more (a few pixels, each many texels wide) render 2x finer and average:
    4 x 4 lookups per pixel, which the widest scale needs on photographs to stay within 0.5 %."""
    return 2 if downsample >= 16 else 1


def pyramid_blur(images: Tensor, levels: int) -> Tensor:
    """The rest of a Gaussian pyramid's blur for an area-filtered image: ``[..., h + 2, w + 2] -> [..., h, w]``.

    An image rendered at a scale's resolution is (within 0.5 %) the area average over each pixel:
    a box of variance 1/12 pixel^2 per axis. ``levels`` reductions of the centred pyramid
    (:func:`aectorch.coding.patches.pyramid_down`, each level a binomial of variance 5/4 of its
    input pixels) blur with variance ``5/4 (4^L - 1) / 3`` full pixels^2, i.e.
    ``5/12 (1 - 4^-L)`` reduced pixels^2. This adds the difference with the 3-tap kernel
    ``[a, 1 - 2a, a]`` per axis (variance ``2a``), over the valid region only (the caller renders
    one extra pixel on every side), so the coder's input has the pyramid's smoothness: without
    it the vergence learned on box-filtered images was twice as coarse (docs/simulation.md).
    """
    if levels == 0:
        return images[..., 1:-1, 1:-1]
    a = (5.0 / 12.0 * (1.0 - 4.0 ** -levels) - 1.0 / 12.0) / 2.0
    if _native_blur(images):
        # On CPU without a gradient: one fused kernel (``aectorch::pyramid_blur``, render_cpu.cpp),
        # the same operations as below and so the same bits, instead of eight small torch
        # operations (and six slices).
        flat = images.reshape(-1, *images.shape[-2:])
        blurred = torch.ops.aectorch.pyramid_blur(flat, 1.0 - 2.0 * a, a)
        return blurred.reshape(*images.shape[:-2], *blurred.shape[-2:])
    # (sums of shifted slices: on these few-pixel images conv2d's set-up costs more than the work)
    x = images[..., 1:-1] * (1.0 - 2.0 * a) + (images[..., :-2] + images[..., 2:]) * a
    return x[..., 1:-1, :] * (1.0 - 2.0 * a) + (x[..., :-2, :] + x[..., 2:, :]) * a


def _native_blur(images: Tensor) -> bool:
    """Whether `pyramid_blur` runs as the fused CPU kernel: where the coder's kernels apply
    (`aectorch.ops.fused_kernels_apply`: a CPU float tensor, the kernels loaded, no
    ``use_backend("torch")``), on images of at least 3 x 3 pixels, and no gradient is wanted."""
    return images.ndim >= 2 and min(images.shape[-2:]) >= 3 and images.numel() > 0 \
        and not (torch.is_grad_enabled() and images.requires_grad) and fused_kernels_apply(images)


#: A moving object's state, the eyes' focus and pursuit velocity in `ActiveDepthEnv.state_dict` (its key -> the
#: attribute), each ``[B, ...]`` and present only while it is not ``None``.
_OBJECT_STATE = {"object_speed": "object_speed", "object_pinned_speed": "_pinned_speed",
                 "object_trial_depth_speed": "_trial_depth_speed", "object_start_target_m": "_start_target_m",
                 "focus_dioptres": "focus_dioptres", "pursuit_velocity_deg": "velocity_deg",
                 "previous_pans_deg": "_previous_pans", "scene_layout": "_layout_draws"}


def _window(camera: PinholeCamera, window: str | PixelWindow) -> PixelWindow:
    """``ActiveDepthEnv``'s ``window``: ``"crops"`` (the central 128 x 128), ``"full"`` or a window, checked."""
    if window == "crops":
        window = camera.central_window(128)
    elif window == "full":
        window = camera.full_window
    elif isinstance(window, str):
        raise ValueError(f"window must be 'crops', 'full' or a PixelWindow, got {window!r}")
    return camera.check_window(window)


def _defocus(images: Tensor, radius_px) -> Tensor:
    """`defocus` by one disc (a number), or each environment's image by its own (a tensor ``[B]``)."""
    return defocus_each(images, radius_px) if isinstance(radius_px, Tensor) else defocus(images, radius_px)


def _elevated(poses: Tensor, elevation_deg: tuple[float, float]) -> Tensor:
    """OpenGL camera-to-world ``poses`` ``[B, 2, 4, 4]`` with each eye turned up by its
    ``elevation_deg`` about the camera's own x axis (x right, y up, looking along -z):
    a vertical misalignment."""
    angle = torch.deg2rad(torch.tensor(elevation_deg, dtype=poses.dtype, device=poses.device))
    c, s = torch.cos(angle), torch.sin(angle)
    turn = torch.eye(4, dtype=poses.dtype, device=poses.device).repeat(2, 1, 1)
    turn[:, 1, 1], turn[:, 1, 2], turn[:, 2, 1], turn[:, 2, 2] = c, -s, s, c
    return poses @ turn


def _sideways(plane_y_m: Tensor | None) -> dict:
    """The renderers' ``plane_y_m`` argument where the object moved sideways (none otherwise: a
    renderer of the still object is called as it always was)."""
    return {} if plane_y_m is None else {"plane_y_m": plane_y_m}


def _block_mean(images: Tensor, k: int) -> Tensor:
    if k == 1:
        return images
    pooled = torch.nn.functional.avg_pool2d(images.flatten(0, -3).unsqueeze(1), k)
    return pooled.reshape(images.shape[:-2] + pooled.shape[-2:])


def make_renderer(name: str, scene: PlaneScene, camera: PinholeCamera, *, device=None, dtype=None, **kwargs):
    """Build a renderer by name: ``"torch"`` (:class:`TorchPlaneRenderer`) or ``"pyrender"``.

    ``filter``, ``lod_bias`` and ``samples`` go to either renderer; other keyword arguments to
    pyrender's. The torch renderer's textures are moved to ``device`` and ``dtype`` once (it
    renders in the poses' dtype, and would otherwise convert them at every call).
    """
    if name == "torch":
        from aectorch.sim.render_torch import TorchPlaneRenderer

        filtering = {k: kwargs.pop(k) for k in ("filter", "lod_bias", "samples") if k in kwargs}
        return TorchPlaneRenderer(scene, camera, **filtering).to(device=device, dtype=dtype)
    if name == "pyrender":
        from aectorch.sim.render_pyrender import PyrenderRenderer

        return PyrenderRenderer(scene, camera, **kwargs)
    raise ValueError(f"renderer must be one of {RENDERERS}, got {name!r}")


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
            against its current one, :meth:`slip_observation`); a ``shift_iterations`` or
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
            and texture); ``None``: the plain world. Its object's pivot stands straight ahead of
            the left eye's start position, where a fixation from the standard start (pan 0)
            fixates. **The optimum stays on the object**: the fixation target is where the left
            eye's axis at its start pan meets the object's plane (slanted, extended past its
            edges), and the optimal vergence puts the right eye's axis through the point where the
            left axis meets that plane now, even where the left axis has slipped past the edge
            onto the background. The trial's distance (the depth's ground truth) is the pivot's.
            Not with a moving object.
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

    #: The depth cues this environment serves, in the paper's order (an iteration's steps k1, k2):
    #: motion parallax (the dominant eye before and after the body shift) drives pursuit, stereo
    #: (both eyes) drives vergence. `observe`, `act` and `hold` take a cue's name.
    CUES = {
        "parallax": CueSpec("pursuit", "parallax_observation", "apply_pursuit", "pursuit_to_optimum",
                            ("left_before", "left")),
        "stereo": CueSpec("vergence", "stereo_observation", "apply_vergence", "vergence_to_optimum",
                          ("left", "right")),
    }

    def __init__(
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
        start, total = (0, num_envs) if batch_slice is None else (int(batch_slice[0]), int(batch_slice[1]))
        if not 0 <= start <= total - num_envs:
            raise ValueError(f"batch_slice=(start, total) must have 0 <= start <= total - num_envs = "
                             f"{total - num_envs}, got {batch_slice!r}")
        self._rows, self._draws = slice(start, start + num_envs), total
        self.device, self.dtype = torch.device("cpu") if device is None else torch.device(device), dtype
        self.fixation_iterations, self.shift_m = h, float(protocol.shift_m)
        self.shift_iterations = min(protocol.shift_iterations, h)
        self.yoked_pursuit, self.q_iterations = protocol.yoked_pursuit, min(protocol.q_iterations, h)
        self.pursuit_start_deg = _range_or_value(pursuit_start_deg, "pursuit_start_deg")
        self.vergence_start_deg = _range_or_value(vergence_start_deg, "vergence_start_deg")
        self.pursuit_start_error_deg = float(check_real(pursuit_start_error_deg, "pursuit_start_error_deg", minimum=0))
        self.camera = camera or PinholeCamera()
        self.window = _window(self.camera, window)
        self.head = (head or HOAP3Head()).to(device=self.device, dtype=dtype)
        self.pan_range_deg, self.vergence_range_deg = self._oculomotor_range(protocol)

        if textures is None:
            textures = TextureBank.default("train")
        self.textures = textures if isinstance(textures, TextureBank) else TextureBank(textures)
        if background is None:
            generator = torch.Generator().manual_seed(20171028)
            background = pink_noise_images(1, 256, 256, generator=generator)[0]
        self.layout = SceneLayout() if layout is None else layout
        if not isinstance(self.layout, SceneLayout):
            raise TypeError(f"layout must be None or an aectorch.sim.scene.SceneLayout, got {type(layout).__name__}")
        self.scene = PlaneScene(self.textures.textures, background, **self._layout_scene())
        self._layout_draws: Tensor | None = None  # [B, 4]: offset, slant, background depth, background texture
        self._world, self.optics, self._optics_tensors = self.scene, NEUTRAL, {}  # perturbations: set_optics
        self._check_background(distances)
        self.distances_m = torch.tensor(distances, dtype=dtype, device=self.device)
        self._init_motion(protocol, distances)
        if self.layout.draws and (protocol.object_speed_deg != (0.0, 0.0) or protocol.object_depth_speed_m != (0.0, 0.0)):
            raise ValueError("layout (scene.object_offset_m, slant_deg, background_depth_m, background_texture) cannot "
                             "be drawn for a moving object (object_speed_deg, object_depth_speed_m): use one of them")
        if self.layout.background_texture == "bank" and len(self.textures) < 2:
            raise ValueError("scene.background_texture='bank' draws a texture other than the object's: it needs at "
                             f"least 2 textures, got {len(self.textures)}")
        self.renderer_name, self._renderer_options = renderer, dict(renderer_options or {})
        self.renderer = make_renderer(
            renderer, self.scene, self.camera, device=self.device, dtype=dtype, **self._renderer_options
        )
        self._scale_renderer = None  # built on the first request for foveal scales
        self._last_left = None  # (view version, scales, left image) of the last stereo frame
        self.seed = seed
        self.reset(seed)

    def _init_motion(self, protocol: TrialProtocol, distances: list[float]) -> None:
        """The moving object's ranges (checked) and its state: none while it stands still; the eyes'
        aperture and focus (``None``: each eye focused on the object, :meth:`set_focus`)."""
        self.aperture_m = protocol.aperture_m
        self.focus_dioptres: Tensor | None = None
        self.accommodation_start_D = protocol.accommodation_start_D
        self.yoked_accommodation = protocol.yoked_accommodation
        if self.accommodation_start_D is not None:  # this environment serves the accommodation cue(s) too
            self.CUES = {**type(self).CUES, "accommodation": ACCOMMODATION,
                         **({} if self.yoked_accommodation else {"accommodation_right": ACCOMMODATION_RIGHT})}
        self.pursuit_velocity, self.velocity_memory = protocol.pursuit_velocity, protocol.velocity_memory
        if self.pursuit_velocity:  # the slip cue first: it sees the frame the last iteration ended with
            self.CUES = {"slip": SLIP, **self.CUES}
        # The pursuit velocity [B] (deg per iteration) and the pans the last iteration ended with
        # [B, 2] (None: off, or the fixation's first iteration).
        self.velocity_deg: Tensor | None = None
        self._previous_pans: Tensor | None = None
        self.object_speed_deg, self.object_depth_speed_m = protocol.object_speed_deg, protocol.object_depth_speed_m
        check_object_motion(self.object_speed_deg, self.object_depth_speed_m, distances,
                            protocol.fixation_iterations, self.scene.background_x_m - float(self.head.eye_x_m))
        # The speeds [B, 2] (sideways deg, depth m per iteration; None: it stands still), those
        # pinned by set_object_speed, and its sideways offsets [B] (None: not moved).
        self.object_speed: Tensor | None = None
        self._pinned_speed: Tensor | None = None
        self._trial_depth_speed: Tensor | None = None
        self._start_target_m: Tensor | None = None
        self.plane_y_m: Tensor | None = None
    def _check_background(self, distances: list[float]) -> None:
        eye_x = float(self.head.eye_x_m)
        if eye_x + max(distances) >= self.scene.background_x_m:
            raise ValueError(
                f"distances_m reach {max(distances)} m, behind the background plane at "
                f"x = {self.scene.background_x_m} m; use distances below "
                f"{self.scene.background_x_m - eye_x:.2f} m"
            )

    def _oculomotor_range(self, protocol: TrialProtocol) -> tuple[tuple[float, float], tuple[float, float]]:
        """The protocol's oculomotor range, checked against this head's eye pan limits."""
        pans = self.head.limits_deg
        return check_oculomotor_range(protocol.pan_range_deg, protocol.vergence_range_deg,
                                      pan_limits_deg=(max(pans["left_eye_pan"][0], pans["right_eye_pan"][0]),
                                                      min(pans["left_eye_pan"][1], pans["right_eye_pan"][1])))

    # -- state -------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Start a new trial in every environment (from ``seed`` when given)."""
        if seed is not None:
            self._generator = torch.Generator().manual_seed(int(seed))
        b = self.num_envs
        self.roll_deg = torch.zeros(b, 2, dtype=self.dtype, device=self.device)
        self.q_deg = torch.zeros(b, 4, dtype=self.dtype, device=self.device)
        self.q_sum_deg = torch.zeros(b, 2, dtype=self.dtype, device=self.device)
        self._new_trial()

    def _uniform(self, bounds: tuple[float, float]) -> Tensor:
        lo, hi = bounds
        u = torch.rand(self._draws, generator=self._generator, dtype=torch.float64)[self._rows]
        return (lo + (hi - lo) * u).to(self.dtype).to(self.device)

    def _layout_scene(self) -> dict:
        """The `PlaneScene` arguments of the layout: none for the plain world; else the object cut
        to its side, its pivot straight ahead of the left eye's start, the background's width."""
        if self.layout.plain:
            return {}
        eye = self.head.eye_centres(torch.zeros(1, dtype=self.dtype, device=self.device))[0, 0]
        return dict(object_extent_m=None if self.layout.object_width_m >= 3.0 else self.layout.object_width_m,
                    object_center_yz_m=(float(eye[1]), float(eye[2])),
                    background_width_m=self.layout.background_width_m)

    def _draw_layout(self, index: Tensor) -> None:
        """Each environment's placement (`SceneLayout`) for a trial of object textures ``index``."""
        layout, b, rows = self.layout, self._draws, self._rows
        offset, slant = self._uniform(tuple(layout.object_offset_m)), self._uniform(tuple(layout.slant_deg))
        depth = self._uniform(tuple(layout.background_depth_m)) if layout.background_depth_m is not None \
            else torch.full_like(offset, math.nan)
        behind = torch.full_like(offset, -1.0)
        if layout.background_texture == "bank":  # any texture but the object's
            other = torch.randint(len(self.textures) - 1, (b,), generator=self._generator)[rows]
            behind = (other + (other >= index).long()).to(offset)
        self._layout_draws = torch.stack((offset, slant, depth, behind), dim=-1)

    def _placement(self) -> dict:
        """The renderers' ``plane_y_m`` and ``placement`` of this trial's layout (none: plain)."""
        if self._layout_draws is None:
            return {}
        offset, slant, depth, behind = self._layout_draws.unbind(-1)
        layout = self.layout
        return dict(plane_y_m=offset, placement=Placement(
            slant_rad=torch.deg2rad(slant) if layout.slant_deg != [0.0, 0.0] else None,
            background_x_m=self.plane_x_m + depth if layout.background_depth_m is not None else None,
            background_index=behind.long() if layout.background_texture == "bank" else None))

    def _slant_rad(self) -> Tensor | None:
        if self._layout_draws is None or self.layout.slant_deg == [0.0, 0.0]:
            return None
        return torch.deg2rad(self._layout_draws[:, 1])

    def _new_trial(self) -> None:
        b, rows = self._draws, self._rows
        index = torch.randint(len(self.textures), (b,), generator=self._generator)[rows]
        pick = torch.randint(self.distances_m.numel(), (b,), generator=self._generator)[rows]
        if self.layout.draws:
            self._draw_layout(index)
        self.set_trial(index.to(self.device), self.distances_m[pick.to(self.device)])

    def set_trial(self, texture_index: Tensor, distance_m: Tensor) -> None:
        """Start a trial with the given textures ``[B]`` and distances ``[B]`` (metres, > 0).

        Evaluation grids use this to pin the conditions; training draws them at random.
        """
        b = self.num_envs
        texture_index = torch.as_tensor(texture_index, device=self.device)
        distance_m = torch.as_tensor(distance_m, dtype=self.dtype, device=self.device)
        if texture_index.shape != (b,) or distance_m.shape != (b,):
            raise ValueError(
                f"texture_index and distance_m must have shape [B] = [{b}] (num_envs), got "
                f"{tuple(texture_index.shape)} and {tuple(distance_m.shape)}"
            )
        if not bool((distance_m > 0).all()):
            raise ValueError(
                f"distance_m must be > 0 (metres in front of the eyes), got min "
                f"{float(distance_m.min()):.4g}"
            )
        if bool(((texture_index < 0) | (texture_index >= len(self.textures))).any()):
            raise IndexError(
                f"texture_index must be in [0, {len(self.textures)}), got values "
                f"{int(texture_index.min())}..{int(texture_index.max())}"
            )
        self.texture_index = texture_index.long()
        self.distance_m = distance_m
        self.plane_x_m = distance_m + float(self.head.eye_x_m)
        self._start_fixation(0)

    def _start_fixation(self, fixation: int) -> None:
        self.fixation = fixation
        self.iteration = 0
        self.body_shift_m = self._body_shift(0)
        left = self._uniform(self.pursuit_start_deg)
        self.pan_deg = self.clamp_pan_deg(torch.stack((left, left + self._uniform(self.vergence_start_deg)), dim=-1))
        moves = self._pinned_speed is not None or self.object_speed_deg != (0.0, 0.0) \
            or self.object_depth_speed_m != (0.0, 0.0)
        if moves or self.moving:  # the object back at its start (the trial's distance, straight ahead)
            self.plane_x_m = self.distance_m + float(self.head.eye_x_m)
            self.object_speed = self.plane_y_m = None
        self.target_m = self._fixation_target(self.eye_pan_deg[:, 0], self.plane_x_m)
        self._start_pans = self.pan_deg
        if self.pursuit_start_error_deg > 0:  # the eyes off the target and the first image's view
            error = self._uniform((-self.pursuit_start_error_deg, self.pursuit_start_error_deg))
            self.pan_deg = self.clamp_pan_deg(self.pan_deg + error[:, None])
        self._first_image: dict = {}
        self._first_roll: Tensor | None = None
        self._first_optics: Optics | None = None
        if moves:
            self._start_object(fixation)
        if self.pursuit_velocity:  # the eyes start still
            self.velocity_deg = torch.zeros(self.num_envs, dtype=self.dtype, device=self.device)
            self._previous_pans = None
        if self.accommodation_start_D is not None:  # both eyes at the start focus, as vergence starts parallel
            self.focus_dioptres = torch.full((self.num_envs, 2), float(self.accommodation_start_D),
                                             dtype=self.dtype, device=self.device)
        self._moved()

    @property
    def moving(self) -> bool:
        """Whether the object moves in this fixation: speed ranges other than ``(0, 0)``, or
        speeds pinned by :meth:`set_object_speed`, when it began."""
        return self.object_speed is not None

    def set_object_speed(self, speed_deg=None, depth_speed_m=None) -> None:
        """Pin the moving object's speeds from the next fixation on (an evaluation's speeds):
        sideways ``speed_deg`` (degrees per iteration) and ``depth_speed_m`` (metres per
        iteration), each ``[B]`` or a number (``None``: 0). ``set_object_speed()`` with neither
        unpins them (the configured ranges are drawn again). The motion's limits are those of
        the constructor's ranges (`aectorch.sim.motion.check_object_motion`).
        """
        if speed_deg is None and depth_speed_m is None:
            self._pinned_speed = None
            return
        b = self.num_envs
        columns = []
        for value, name in ((speed_deg, "speed_deg"), (depth_speed_m, "depth_speed_m")):
            column = torch.as_tensor(0.0 if value is None else value, dtype=self.dtype, device=self.device)
            if column.shape not in ((), (b,)) or not bool(torch.isfinite(column).all()):
                raise ValueError(f"{name} must be a finite number or a [B] = [{b}] tensor, got {value!r}")
            columns.append(column.expand(b))
        speed = torch.stack(columns, -1)
        check_object_motion((float(speed[:, 0].min()), float(speed[:, 0].max())),
                            (float(speed[:, 1].min()), float(speed[:, 1].max())),
                            self.distances_m.tolist(), self.fixation_iterations,
                            self.scene.background_x_m - float(self.head.eye_x_m))
        self._pinned_speed = speed

    def _start_object(self, fixation: int) -> None:
        """A fixation's object motion: its speeds (pinned, or drawn: sideways per fixation, in
        depth per trial), the target it starts from, and its place in the first iteration."""
        if self._pinned_speed is not None:
            self.object_speed = self._pinned_speed.clone()
        else:
            sideways = self._uniform(self.object_speed_deg)
            depth = self._uniform(self.object_depth_speed_m) if fixation == 0 or self._trial_depth_speed is None \
                else self._trial_depth_speed
            self._trial_depth_speed = depth
            self.object_speed = torch.stack((sideways, depth), -1)
        self._start_target_m = self.target_m
        self._start_plane = (self.plane_x_m, torch.zeros_like(self.plane_x_m))
        self._place_object(0)

    def _place_object(self, iteration: int) -> None:
        """The object where it is during ``iteration`` of the fixation (`aectorch.sim.motion`);
        the fixation target moves with it."""
        self.plane_x_m, self.plane_y_m, self.target_m = self._object_at(iteration)

    def _object_at(self, iteration: int) -> tuple[Tensor, Tensor, Tensor]:
        """Where the moving object is during ``iteration`` of the fixation: its plane's world x and
        sideways offset ``[B]``, and the fixation target on it ``[B, 3]``."""
        distance, y = object_place(self.distance_m, self.object_speed, iteration + 1)
        plane_x = distance + float(self.head.eye_x_m)
        start = self._start_target_m
        return plane_x, y, torch.stack((plane_x, start[:, 1] + y, start[:, 2]), -1)

    # -- focus -----------------------------------------------------------------------------------
    def set_focus(self, dioptres=None) -> None:
        """Focus each eye at ``dioptres`` (1 / metres; ``[B, 2]``, ``[2]`` or a number, each >= 0:
        0 is infinity) from now on; ``None`` (the default state): each eye focused on the object,
        wherever it is. The image of an eye out of focus is blurred by a disc of angular diameter
        ``aperture_m * |1 / d - dioptres|`` radians (d: the object's distance), in both renderers.
        """
        if dioptres is None:
            self.focus_dioptres = None
            self._moved()
            return
        focus = torch.as_tensor(dioptres, dtype=self.dtype, device=self.device)
        if focus.shape not in ((), (2,), (self.num_envs, 2)) or not bool((torch.isfinite(focus) & (focus >= 0)).all()):
            raise ValueError(f"dioptres must be None or finite values >= 0 of shape [], [2] or [B, 2] = "
                             f"[{self.num_envs}, 2], got {dioptres!r}")
        self.focus_dioptres = focus.expand(self.num_envs, 2).clone()
        self._moved()

    @property
    def defocus_dioptres(self) -> Tensor:
        """Each eye's defocus ``[B, 2]``: its focus minus the object's vergence 1 / d (dioptres;
        positive: focused nearer than the object; 0 while the eyes follow the object), its
        refractive error (`Optics.refraction_D`, after accommodation's stop at 0 D) included."""
        return self._defocus(self.optics)

    def _defocus(self, optics: Optics) -> Tensor:
        """:attr:`defocus_dioptres` with the refractive errors of ``optics``."""
        refracted = optics.refraction_D != NEUTRAL.refraction_D
        refraction = torch.tensor(optics.refraction_D, dtype=self.dtype, device=self.device) if refracted else None
        if self.focus_dioptres is None:
            zero = torch.zeros(self.num_envs, 2, dtype=self.dtype, device=self.device)
            return zero + refraction if refracted else zero
        defocus = self.focus_dioptres - 1.0 / self.object_distance_m[:, None]
        return defocus + refraction if refracted else defocus

    @property
    def degrees_per_dioptre(self) -> float:
        """The blur disc's angular diameter per dioptre of defocus, degrees (``aperture_m`` in radians)."""
        return math.degrees(self.aperture_m)

    def accommodation_error_deg(self, eye: int = 0) -> Tensor:
        """The accommodation cue's error ``[B]``: the eye's (default the left) defocus as its blur
        disc's signed angular diameter, degrees (`defocus_dioptres` times
        :attr:`degrees_per_dioptre`; positive: focused nearer than the object)."""
        return self.defocus_dioptres[:, eye] * self.degrees_per_dioptre

    def _focus_by(self, delta_deg: Tensor, eyes: tuple[float, float]) -> None:
        delta = self._check_increment(delta_deg, "delta_deg") / self.degrees_per_dioptre
        focus = self.focus_dioptres if self.focus_dioptres is not None else \
            (1.0 / self.object_distance_m)[:, None].expand(self.num_envs, 2)
        self.focus_dioptres = (focus + delta[:, None] * focus.new_tensor(eyes)).clamp_min(0.0)
        self._moved()

    def apply_accommodation(self, delta_deg: Tensor) -> None:
        """Change both eyes' focus (the left eye's alone without ``yoked_accommodation``) by the
        increments ``[B]``, in degrees of the blur disc's diameter (``delta_deg /
        degrees_per_dioptre`` dioptres; positive: nearer), at least 0 D (infinity)."""
        self._focus_by(delta_deg, (1.0, 1.0 if self.yoked_accommodation else 0.0))

    def apply_accommodation_right(self, delta_deg: Tensor) -> None:
        """Change the right eye's focus alone (the ``accommodation_right`` cue), as :meth:`apply_accommodation`."""
        self._focus_by(delta_deg, (0.0, 1.0))

    def accommodation_to_optimum(self) -> Tensor:
        """The accommodation increments ``[B]`` (degrees of blur) that focus the left eye (both
        eyes, yoked) on the object now."""
        return -self.accommodation_error_deg()

    def accommodation_right_to_optimum(self) -> Tensor:
        """The increments ``[B]`` that focus the right eye on the object now."""
        return -self.accommodation_error_deg(1)

    def proprioception(self, names) -> Tensor:
        """What the eyes sense of themselves now, ``[B, len(names)]``, one column per name of
        `aectorch.choices.Proprioception`: ``vergence`` (:attr:`vergence_deg`, the commanded
        vergence angle, degrees), ``pan`` (the left eye's commanded pan, degrees), ``focus``
        (the left eye's focus, dioptres; only where the eyes accommodate, ``accommodation_start_D``
        or :meth:`set_focus`: an eye that follows the object would sense its distance) and
        ``shift`` (the body's sideways shift since the fixation's start, :attr:`body_shift_m`,
        metres). Efference copies of the commands, not ground truth: a squint's offset is not in them.

        Example:
            >>> env = ActiveDepthEnv(2, protocol=TrialProtocol(accommodation_start_D=0.0),
            ...                      textures=torch.rand(2, 64, 64), seed=0)
            >>> env.proprioception(["vergence", "focus"]).shape
            torch.Size([2, 2])
        """
        names = [check_choice(n, "proprioception", Proprioception) for n in names]
        if Proprioception.focus in names and self.focus_dioptres is None:
            raise ValueError("proprioception 'focus' needs an environment whose eyes accommodate "
                             "(the protocol's accommodation_start_D, env.accommodation_start_D; or set_focus): "
                             "these eyes follow the object")
        columns = {Proprioception.vergence: lambda: self.vergence_deg, Proprioception.pan: lambda: self.pan_deg[:, 0],
                   Proprioception.focus: lambda: self.focus_dioptres[:, 0], Proprioception.shift: lambda: self.body_shift_m}
        if not names:
            return self.pan_deg.new_zeros(self.num_envs, 0)
        return torch.stack([columns[n]() for n in names], -1)

    def _world_blur_arcmin(self, optics: Optics) -> Tensor | None:
        """Each eye's defocus blur disc ``[B, 2]`` (diameter, arcmin) with the refractive errors of
        ``optics``, or ``None`` where no eye is out of focus."""
        if self.aperture_m == 0 or (self.focus_dioptres is None and optics.refraction_D == NEUTRAL.refraction_D):
            return None
        return self.aperture_m * self._defocus(optics).abs() * (180.0 * 60.0 / math.pi)

    @property
    def object_distance_m(self) -> Tensor:
        """The object's distance now ``[B]`` (metres; the trial's distance unless it moves)."""
        return self.plane_x_m - float(self.head.eye_x_m) if self.moving else self.distance_m

    def _moved(self) -> None:
        """The left eye's view changed (pan, roll or body): a stereo frame can no longer be reused."""
        self._left_view = getattr(self, "_left_view", 0) + 1

    def body_shift_fraction(self, iteration: int) -> float:
        """The fraction of ``shift_m`` the body has moved during ``iteration`` of a fixation."""
        return min(1.0, (iteration + 1) / self.shift_iterations)

    def _body_shift(self, iteration: int) -> Tensor:
        direction = 1.0 if self.fixation == 0 else -1.0
        zero = torch.zeros(self.num_envs, dtype=self.dtype, device=self.device)
        return zero + direction * self.shift_m * self.body_shift_fraction(iteration)

    def _fixation_target(self, left_pan_deg: Tensor, plane_x_m: Tensor) -> Tensor:
        """The fixation target ``[N, 3]``: where the left axis meets the plane at the start position."""
        start = self.head.eye_centres(torch.zeros_like(plane_x_m))[:, 0]  # [N, 3]
        shift = self._eye_shift()
        if shift is not None:  # the left camera's own place (camera_shift)
            start = start + shift[0]
        slant = self._slant_rad()
        if slant is not None and slant.shape == plane_x_m.shape:  # the slanted object's plane (its pivot)
            return axis_point(start, left_pan_deg, plane_x_m, slant, self.scene.object_center_yz_m[0])
        along = torch.tan(torch.deg2rad(left_pan_deg)) * (plane_x_m - start[:, 0])
        return torch.stack((plane_x_m, start[:, 1] + along, start[:, 2]), dim=-1)

    def clamp_pan_deg(self, pan_deg: Tensor) -> Tensor:
        """Pans ``[B, 2]`` (left, right; degrees) brought within the head's joint limits and the
        oculomotor range (``pan_range_deg``, ``vergence_range_deg``; `aectorch.sim.oculomotor`):
        where every movement of the eyes ends."""
        return clamp_eyes(self.head.clamp_pan_deg(pan_deg), self.pan_range_deg, self.vergence_range_deg)

    def set_pan_deg(self, pan_deg) -> None:
        """Put the eyes at the given pans ``[B, 2]`` (left, right; degrees), within their range
        (:meth:`clamp_pan_deg`).

        For evaluation grids (for example a set of initial vergence errors) and tests; the
        fixation target does not change.
        """
        pan = torch.as_tensor(pan_deg, dtype=self.dtype, device=self.device)
        if pan.shape != (self.num_envs, 2):
            raise ValueError(f"pan_deg must have shape [B, 2] = [{self.num_envs}, 2], got {tuple(pan.shape)}")
        self.pan_deg = self.clamp_pan_deg(pan)
        self._moved()

    def set_roll(self, roll_deg) -> None:
        """Set each eye's roll about its optical axis (the perturbation), ``[2]`` or ``[B, 2]``, degrees."""
        roll = torch.as_tensor(roll_deg, dtype=self.dtype, device=self.device)
        if roll.shape not in ((2,), (self.num_envs, 2)):
            raise ValueError(
                f"roll_deg must have shape [2] or [B, 2] = [{self.num_envs}, 2], got {tuple(roll.shape)}"
            )
        self.roll_deg = roll.expand(self.num_envs, 2).clone()
        self.optics = replace(self.optics, roll_deg=tuple(self.roll_deg[0].tolist()))
        self._moved()

    # -- perturbations ---------------------------------------------------------------------------
    def set_optics(self, optics: Optics) -> None:
        """Perturb the eyes and the world (`aectorch.sim.perturbations.Optics`): from now on the
        eyes are rolled, offset, moved, blurred, dimmed and magnified as ``optics`` says, and the
        world's textures filtered to its orientation bands. The fixation's first image keeps the
        optics it was taken with (unless the world changed: it is rendered again in the new one).
        ``set_optics(NEUTRAL)`` is the unperturbed robot; every environment gets the same optics.
        """
        if not isinstance(optics, Optics):
            raise TypeError(f"optics must be an aectorch.sim.perturbations.Optics, got {type(optics).__name__}")
        if optics.refraction_D != NEUTRAL.refraction_D and self.aperture_m == 0:
            raise ValueError(f"optics.refraction_D={optics.refraction_D}: a refractive error blurs only through an "
                             "aperture, and this environment's eyes are pinholes (aperture_m=0); give aperture_m > 0")
        world_changed = optics.orientation_bands != self.optics.orientation_bands
        self.optics = optics
        self._optics_tensors = {}
        self.roll_deg = torch.tensor(optics.roll_deg, dtype=self.dtype, device=self.device).expand(self.num_envs, 2).clone()
        if world_changed:
            self._set_world(optics.orientation_bands)
        self._moved()

    def _set_world(self, bands) -> None:
        """The world's textures filtered to ``bands`` (none: as built); the renderers are rebuilt."""
        world = self._world
        if bands:
            world = replace(world, textures=orientation_filter(world.textures, bands),
                            background=orientation_filter(world.background, bands))
        self.close()
        self.scene = world
        self.renderer = make_renderer(self.renderer_name, world, self.camera, device=self.device, dtype=self.dtype,
                                      **self._renderer_options)
        self._scale_renderer = None
        self._first_image = {}  # what the eye saw of the old world is rendered again in the new one
        self._last_left = None

    def _optics_tensor(self, name: str) -> Tensor:
        """``optics.<name>`` as a tensor of the environment's dtype and device (kept until the optics change)."""
        tensor = self._optics_tensors.get(name)
        if tensor is None:
            tensor = torch.tensor(getattr(self.optics, name), dtype=self.dtype, device=self.device)
            self._optics_tensors[name] = tensor
        return tensor

    def _eye_shift(self) -> Tensor | None:
        """The cameras' translations ``[2, 3]`` (camera_shift), or ``None`` when neither moved."""
        return None if self.optics.shift_m == NEUTRAL.shift_m else self._optics_tensor("shift_m")

    @property
    def eye_pan_deg(self) -> Tensor:
        """Where the eyes point ``[B, 2]`` (left, right; degrees): the commanded pans
        (:attr:`pan_deg`) plus a squint's offset (`Optics.pan_offset_deg`)."""
        if self.optics.pan_offset_deg == NEUTRAL.pan_offset_deg:
            return self.pan_deg
        return self.pan_deg + self._optics_tensor("pan_offset_deg")

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

    # -- ground truth ----------------------------------------------------------------------
    def optimal_left_pan_deg(self, target_m: Tensor | None = None, body_shift_m: Tensor | None = None) -> Tensor:
        """The left pan that keeps the fixation target on the left axis at the shifted position
        (of the left eye's axis: with a squint's offset the command differs by it); ``target_m``
        ``[B, 3]`` and ``body_shift_m`` ``[B]`` default to now's."""
        target = self.target_m if target_m is None else target_m
        body = self.body_shift_m if body_shift_m is None else body_shift_m
        shift = self._eye_shift()
        if shift is None:
            return self.head.pursuit_pan_deg(target, body)
        return self.head.pursuit_pan_deg(target - shift[0], body)

    def optimal_right_pan_deg(self, left_pan_deg: Tensor | None = None) -> Tensor:
        """The right pan whose axis meets the plane where the left axis does (current left pan,
        of the eye's axis: :attr:`eye_pan_deg`)."""
        left = self.eye_pan_deg[:, 0] if left_pan_deg is None else left_pan_deg
        shift = self._eye_shift()
        slant = self._slant_rad()
        if slant is not None:  # where the left axis meets the slanted object's plane, never the background
            eye = self.head.eye_centres(self.body_shift_m)[:, 0]
            point = axis_point(eye if shift is None else eye + shift[0], left, self.plane_x_m, slant,
                               self.scene.object_center_yz_m[0])
            return self.head.pursuit_pan_deg(point if shift is None else point - shift[1], self.body_shift_m,
                                             eye="right")
        if shift is None:
            return self.head.vergence_pan_deg(left, self.plane_x_m, self.body_shift_m)
        # Each camera where camera_shift put it: the left axis from its place, the right eye's pan
        # toward that point from its own.
        point = self.head.plane_point_m(left, self.plane_x_m - shift[0, 0], self.body_shift_m) + shift[0]
        return self.head.pursuit_pan_deg(point - shift[1], self.body_shift_m, eye="right")

    def ideal_q_deg(self, distance_m: Tensor | None = None, *, start_pan_deg: float = 0.0) -> Tensor:
        """The final eye movements ``q`` ``[N, 4]`` of a perfectly fixating trial, degrees.

        What :attr:`IterationInfo.q_deg` holds at the end of a trial whose pursuit and vergence
        errors are zero at both fixation ends (q1 left pan and q2 vergence after the leftward
        shift, q3 and q4 after the rightward one): the geometry the depth MLP has to invert.

        Args:
            distance_m: object distances ``[N]`` (metres, > 0); default the current trials'.
            start_pan_deg: the left pan each fixation starts from, which sets its target (the
                evaluation's standard start state: 0).
        """
        d = self.distance_m if distance_m is None else torch.as_tensor(
            distance_m, dtype=self.dtype, device=self.device)
        if d.dim() != 1 or not bool((d > 0).all()):
            raise ValueError(f"distance_m must be a [N] tensor of distances > 0 (metres), got {d!r}")
        plane_x = d + float(self.head.eye_x_m)
        target = self._fixation_target(torch.full_like(d, float(start_pan_deg)), plane_x)
        columns = []
        for direction in (1.0, -1.0):
            shift = torch.full_like(d, direction * self.shift_m)
            left = self.head.pursuit_pan_deg(target, shift)
            columns += [left, self.head.vergence_pan_deg(left, plane_x, shift) - left]
        return torch.stack(columns, dim=-1)

    # -- observations ----------------------------------------------------------------------
    def _render(self, shift_m: Tensor, pans: Tensor, eyes: slice, roll_deg: Tensor | None = None,
                scales=None, window: bool = False, optics: Optics | None = None,
                plane: tuple[Tensor, Tensor | None] | None = None) -> dict[str, Tensor]:
        """The eyes' images at ``shift_m`` and ``pans``, the object plane at ``plane`` (its x and
        sideways offset; default where it is now)."""
        plane_x, plane_y = (self.plane_x_m, self.plane_y_m) if plane is None else plane
        roll = self.roll_deg if roll_deg is None else roll_deg
        optics = self.optics if optics is None else optics
        if optics.pan_offset_deg != NEUTRAL.pan_offset_deg:
            pans = pans + torch.tensor(optics.pan_offset_deg, dtype=pans.dtype, device=pans.device)
        poses = self.head.camera_poses(shift_m, pans, roll, convention="opengl")
        if optics.elevation_offset_deg != NEUTRAL.elevation_offset_deg:
            poses = _elevated(poses, optics.elevation_offset_deg)
        if optics.shift_m != NEUTRAL.shift_m:  # the robot's frame is the world's moved by the body shift
            poses = poses.clone()
            poses[..., :3, 3] += torch.tensor(optics.shift_m, dtype=poses.dtype, device=poses.device)
        poses = poses[:, eyes]
        indices = tuple(range(*eyes.indices(2)))
        world = self._world_blur_arcmin(optics)
        if world is not None or not optics.images_neutral(indices):
            return self._render_optics(poses, indices, optics, scales, window, plane_x, plane_y, world)
        out = {}
        # The indices were checked by set_trial: no host sync per frame.
        if scales is None or window:
            out[WINDOW] = self.renderer(poses, plane_x, self.texture_index, self.window, check=False,
                                        **_sideways(plane_y), **self._placement()).to(self.dtype)
        if scales is None:
            return out
        # Each scale's crop with one more of its pixels on every side, for the blur.
        finer = [_finer(s.downsample) for s in scales]
        windows = [(self.camera.central_window(s.crop + 2 * s.downsample), s.downsample // k)
                   for s, k in zip(scales, finer)]
        images = self._scale_renderer_built().render_windows(poses, plane_x, self.texture_index, windows,
                                                             check=False, **_sideways(plane_y), **self._placement())
        for s, image, k in zip(scales, images, finer):
            out[s.name] = pyramid_blur(_block_mean(image, k), s.levels).to(self.dtype)
        return out

    def _scale_renderer_built(self):
        if self._scale_renderer is None:
            self._scale_renderer = make_renderer(self.renderer_name, self.scene, self.camera, device=self.device,
                                                 dtype=self.dtype, **{**self._renderer_options, **SCALE_FILTER})
        return self._scale_renderer

    def _margin_window(self, camera: PinholeCamera, size: int, margin: int, what: str) -> PixelWindow:
        """The central ``size`` crop with ``margin`` more pixels on every side, for a blur."""
        if size + 2 * margin > min(camera.height, camera.width):
            raise ValueError(f"the blur of anisometropia ({what}) needs {margin} px beyond the {size} px crop on "
                             f"every side, more than the {camera.height} x {camera.width} image holds; use a smaller "
                             "blur disc")
        return camera.central_window(size + 2 * margin)

    def _render_optics(self, poses: Tensor, eyes: tuple[int, ...], optics: Optics, scales, window: bool,
                       plane_x: Tensor, plane_y: Tensor | None, world_arcmin: Tensor | None = None):
        """`_render` of eyes with perturbed images, one eye at a time: each through its own camera
        (magnified: aniseikonia), rendered with the margin its blur disc needs (anisometropia, and
        the world's defocus ``world_arcmin`` ``[B, 2]``, each environment's disc diameter added to
        the eye's), blurred, then its contrast scaled about each image's mean (monocular deprivation)."""
        per_eye = []
        for j, eye in enumerate(eyes):
            camera = self.camera.magnified(optics.magnification[eye])
            arcmin_per_px = 60.0 * camera.degrees_per_pixel
            radius = optics.blur_arcmin[eye] / 2.0 / arcmin_per_px  # full-resolution pixels of this eye
            if world_arcmin is not None:  # the world's defocus too: a disc per environment
                radius = (optics.blur_arcmin[eye] + world_arcmin[:, eye]) / 2.0 / arcmin_per_px
            largest = float(radius.max()) if isinstance(radius, Tensor) else radius
            pose, out = poses[:, j:j + 1], {}
            if scales is None or window:
                margin = blur_margin(largest)
                top, left, h, w = self.window
                grown = PixelWindow(top - margin, left - margin, h + 2 * margin, w + 2 * margin)
                if margin and (h + 2 * margin > camera.height or w + 2 * margin > camera.width
                               or top < margin or left < margin):
                    raise ValueError(f"the blur of anisometropia ({optics.blur_arcmin[eye]:g} arcmin) needs {margin} "
                                     "px beyond the rendered window, which the image does not hold")
                image = self.renderer.render_windows(pose, plane_x, self.texture_index, [(grown, 1)],
                                                     check=False, camera=camera, **_sideways(plane_y), **self._placement())[0]
                out[WINDOW] = _defocus(image, radius).to(self.dtype)
            if scales is not None:
                finer = [_finer(s.downsample) for s in scales]
                margins = [blur_margin(largest / s.downsample) for s in scales]
                windows = [(self._margin_window(camera, s.crop + 2 * s.downsample, s.downsample * m,
                                                f"{optics.blur_arcmin[eye]:g} arcmin at the {s.name} scale"),
                            s.downsample // k) for s, k, m in zip(scales, finer, margins)]
                images = self._scale_renderer_built().render_windows(pose, plane_x, self.texture_index,
                                                                     windows, check=False, camera=camera,
                                                                     **_sideways(plane_y), **self._placement())
                for s, image, k in zip(scales, images, finer):
                    image = _defocus(_block_mean(image, k), radius / s.downsample)
                    out[s.name] = pyramid_blur(image, s.levels).to(self.dtype)
            if optics.contrast[eye] != 1:
                out = {name: scale_contrast(image, optics.contrast[eye]) for name, image in out.items()}
            per_eye.append(out)
        return {name: torch.cat([out[name] for out in per_eye], dim=1) for name in per_eye[0]}

    @staticmethod
    def _key(scales, window: bool):
        return None if scales is None else tuple(scales), bool(window)

    def parallax_observation(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The motion-parallax pair: the left eye before the shift, then after it.

        The first image is the left eye at the starting position with the fixation's start pan,
        rendered once per fixation; the second is the left eye after the body shift with the
        current pan (the previous stereo frame's left image when nothing has moved since).

        Args:
            scales: ``None`` (the whole window), or foveal scales (:class:`aectorch.coding.Scale`):
                each scale's central ``crop`` rendered directly at its resolution
                (``crop // downsample``, mipmapped: :data:`SCALE_FILTER`) and given the rest of the
                pyramid's blur (:func:`pyramid_blur`), what :class:`aectorch.coding.BinocularEncoder`
                reads in place of the pyramid's output.
            window: with ``scales``, also render the whole window.

        Returns:
            ``{scale.name: [B, 2, side, side]}`` for each scale and ``{WINDOW: [B, 2, h, w]}`` (the
            crops of ``window``) without scales or with ``window=True``.
        """
        key = self._key(scales, window)
        first = self._first_left(key, scales, window)
        second = self._current_left(key, scales, window)
        return {name: torch.cat((first[name], second[name]), dim=1) for name in first}

    def _first_left(self, key, scales, window: bool) -> dict[str, Tensor]:
        """The left eye's image at the fixation's start (its start pan, roll, optics and object
        place), rendered once per fixation and kept."""
        first = self._first_image.get(key)
        if first is None:
            zero = torch.zeros_like(self.body_shift_m)
            if self._first_roll is None:  # the roll and optics when the fixation's first image was taken
                self._first_roll = self.roll_deg.clone()
            if self._first_optics is None:
                self._first_optics = self.optics
            # (the world's textures are always today's: a change of them rendered it again)
            first = self._render(zero, self._start_pans, slice(0, 1), self._first_roll, scales, window,
                                 optics=replace(self._first_optics, orientation_bands=self.optics.orientation_bands),
                                 plane=self._start_plane if self.moving else None)
            self._first_image[key] = first
        return first

    def _current_left(self, key, scales, window: bool) -> dict[str, Tensor]:
        """The left eye's image now: the last one rendered when the eye has not moved since."""
        cached = self._last_left
        if cached is not None and cached[0] == self._left_view and cached[1] == key:
            return cached[2]
        second = self._render(self.body_shift_m, self.pan_deg, slice(0, 1), scales=scales, window=window)
        self._last_left = (self._left_view, key, second)
        return second

    def slip_observation(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The retinal-slip pair (with ``pursuit_velocity``): the left eye's previous frame, then its
        current one.

        The previous frame is the left eye as the last iteration ended (its pans after every
        movement, the body and the object where they were; in a fixation's first iteration, the
        fixation's first image); between the two the object and the body moved on and the eyes
        moved by their pursuit velocity, so the image slips by the object's motion the eye did not
        follow. Rendered with the optics of now. ``scales``, ``window`` and the returned dict as
        for :meth:`parallax_observation`.
        """
        if not self.pursuit_velocity:
            raise ValueError("slip_observation needs pursuit_velocity=True (the environment's slip cue)")
        key = self._key(scales, window)
        if self._previous_pans is None:
            first = self._first_left(key, scales, window)
        else:
            # the object where it was during the last iteration
            plane = self._object_at(self.iteration - 1)[:2] if self.moving else None
            first = self._render(self._body_shift(self.iteration - 1), self._previous_pans, slice(0, 1),
                                 scales=scales, window=window, plane=plane)
        second = self._current_left(key, scales, window)
        return {name: torch.cat((first[name], second[name]), dim=1) for name in first}

    def stereo_observation(self, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The stereo pair: the left then the right eye at the shifted position.

        Args:
            scales, window: as for :meth:`parallax_observation`.
        """
        pair = self._render(self.body_shift_m, self.pan_deg, slice(0, 2), scales=scales, window=window)
        self._last_left = (self._left_view, self._key(scales, window), {name: p[:, :1] for name, p in pair.items()})
        return pair

    # -- the cues ----------------------------------------------------------------------------
    def cue(self, name: str) -> CueSpec:
        """The :class:`CueSpec` of the cue ``name`` (``ValueError`` naming the cues otherwise)."""
        spec = self.CUES.get(str(name))
        if spec is None:
            raise ValueError(f"cue must be one of {tuple(self.CUES)} (this environment's cues), got {name!r}")
        return spec

    def observe(self, cue: str, scales=None, *, window: bool = False) -> dict[str, Tensor]:
        """The image pair of ``cue`` (its observation method, e.g. :meth:`stereo_observation`)."""
        return getattr(self, self.cue(cue).observe)(scales, window=window)

    def act(self, cue: str, delta_deg: Tensor) -> None:
        """Add the increments ``[B]`` (degrees) of the eye movement ``cue`` drives."""
        getattr(self, self.cue(cue).act)(delta_deg)

    def hold(self, cue: str) -> None:
        """Put the eye movement ``cue`` drives at its optimum (the increment that reaches it, within
        the eyes' limits): a learner without that cue (e.g. the vergence-only model) has it held."""
        spec = self.cue(cue)
        getattr(self, spec.act)(getattr(self, spec.to_optimum)())

    def pursuit_to_optimum(self) -> Tensor:
        """The pursuit increments ``[B]`` that put the left eye at its optimal pan now."""
        return self.optimal_left_pan_deg() - self.eye_pan_deg[:, 0]

    def slip_to_optimum(self) -> Tensor:
        """The increments ``[B]`` that set the pursuit velocity to the optimal left pan's change over
        the next iteration (the object's and the body's motion as the left eye sees it)."""
        return self.optimal_velocity_deg() - self.velocity_deg

    def optimal_velocity_deg(self) -> Tensor:
        """The optimal left pan's change ``[B]`` from this iteration to the next, degrees."""
        # the target where the object will be
        target = self._object_at(self.iteration + 1)[2] if self.moving else self.target_m
        return self.optimal_left_pan_deg(target, self._body_shift(self.iteration + 1)) - self.optimal_left_pan_deg()

    def vergence_to_optimum(self) -> Tensor:
        """The vergence increments ``[B]`` that put the right eye at its optimal pan now."""
        return self.optimal_right_pan_deg() - self.eye_pan_deg[:, 1]

    # -- actions -----------------------------------------------------------------------------
    def _check_increment(self, delta_deg, name: str) -> Tensor:
        delta = torch.as_tensor(delta_deg, device=self.device)
        if not delta.is_floating_point():
            delta = delta.to(self.dtype)
        if delta.shape != (self.num_envs,):
            raise ValueError(
                f"{name} must have shape [B] = [{self.num_envs}] (num_envs), got {tuple(delta.shape)}"
            )
        return delta.to(self.dtype)

    def apply_pursuit(self, delta_deg: Tensor) -> None:
        """Add the pursuit increments ``[B]`` (degrees) to the left eye's pan (within the oculomotor
        range, :meth:`clamp_pan_deg`).

        With ``yoked_pursuit`` the right eye turns by the same increment.
        """
        delta = self._check_increment(delta_deg, "delta_deg")
        if self.velocity_memory:  # the step also goes on as velocity
            self.velocity_deg = self.velocity_deg + delta
        self.pan_deg = self.clamp_pan_deg(self.pan_deg + self._pursuit_step(delta))
        self._moved()

    def _pursuit_step(self, delta: Tensor) -> Tensor:
        """The pans' change ``[B, 2]`` of a pursuit increment ``[B]``: both eyes with
        ``yoked_pursuit``, else the left alone."""
        return torch.stack((delta, delta if self.yoked_pursuit else torch.zeros_like(delta)), dim=-1)

    def apply_slip(self, delta_deg: Tensor) -> None:
        """Add the increments ``[B]`` (degrees per iteration) to the eyes' pursuit velocity (with
        ``pursuit_velocity``): the eyes move by it when the iteration ends (both with
        ``yoked_pursuit``, else the left), within the oculomotor range."""
        if not self.pursuit_velocity:
            raise ValueError("apply_slip needs pursuit_velocity=True (the environment's slip cue)")
        self.velocity_deg = self.velocity_deg + self._check_increment(delta_deg, "delta_deg")

    def apply_vergence(self, delta_deg: Tensor) -> None:
        """Add the vergence increments ``[B]`` (degrees) to the right eye's pan (within the
        oculomotor range, :meth:`clamp_pan_deg`: the vergence stays within ``vergence_range_deg``)."""
        delta = self._check_increment(delta_deg, "delta_deg")
        step = torch.stack((torch.zeros_like(delta), delta), dim=-1)
        self.pan_deg = self.clamp_pan_deg(self.pan_deg + step)

    def _extra_errors_deg(self) -> dict[str, Tensor] | None:
        """The errors of the eye movements beyond pursuit and vergence that this environment
        serves (accommodation; the pursuit velocity against its optimum), by movement."""
        extra = {m: self.accommodation_error_deg(e) for e, m in enumerate(("accommodation", "accommodation_right"))
                 if m in self.CUES}
        if self.pursuit_velocity:
            extra[SLIP.movement] = -self.slip_to_optimum()
        return extra or None

    def end_iteration(self) -> IterationInfo:
        """End the iteration: the ground truth after its movements, and the next iteration, fixation
        or trial begins."""
        optimal_left = self.optimal_left_pan_deg()
        optimal_right = self.optimal_right_pan_deg()
        extra = self._extra_errors_deg()
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
        info_left, info_right = eyes[:, 0], eyes[:, 1]
        if trial_end:
            q, distance = self.q_deg.clone(), self.object_distance_m
            self._new_trial()
        elif fixation_end:
            self._start_fixation(1)
        else:
            self.iteration += 1
            if self.shift_iterations > self.iteration:  # the body moves on
                self.body_shift_m = self._body_shift(self.iteration)
                self._moved()
            if self.moving:  # and so does the object
                self._place_object(self.iteration)
                self._moved()
            if self.pursuit_velocity:  # and the eyes, at their pursuit velocity
                self._previous_pans = self.pan_deg
                self.pan_deg = self.clamp_pan_deg(self.pan_deg + self._pursuit_step(self.velocity_deg))
                self._moved()
        return IterationInfo(
            left_pan_deg=info_left,
            right_pan_deg=info_right,
            optimal_left_pan_deg=optimal_left,
            optimal_right_pan_deg=optimal_right,
            pursuit_error_deg=info_left - optimal_left,
            vergence_error_deg=info_right - optimal_right,
            iteration=iteration,
            fixation=fixation,
            fixation_end=fixation_end,
            trial_end=trial_end,
            q_deg=q,
            distance_m=distance,
            extra_errors_deg=extra,
        )

    # -- checkpoints ---------------------------------------------------------------------------
    _STATE_TENSORS = ("texture_index", "distance_m", "plane_x_m", "body_shift_m", "pan_deg",
                      "roll_deg", "q_deg", "target_m", "_start_pans", "q_sum_deg")

    def state_dict(self) -> dict:
        """Everything that determines the environments' future: resume with :meth:`load_state_dict`.

        The configuration (textures, renderer, geometry) is not included: build the environment
        with the same arguments, then load the state. The cached first image of the current
        fixation is not stored; it is rendered again, identically (with the roll of the moment
        it was first taken), when next needed.
        """
        state = {name: getattr(self, name).clone() for name in self._STATE_TENSORS}
        state.update(
            fixation=self.fixation,
            iteration=self.iteration,
            generator=self._generator.get_state(),
            num_envs=self.num_envs,
            num_textures=len(self.textures),
            first_roll=None if self._first_roll is None else self._first_roll.clone(),
            optics=self.optics.to_dict(),
            first_optics=None if self._first_optics is None else self._first_optics.to_dict(),
        )
        for name, attribute in _OBJECT_STATE.items():  # a moving object's (absent while it stands still)
            if getattr(self, attribute) is not None:
                state[name] = getattr(self, attribute).clone()
        return state

    @classmethod
    def join_states(cls, states: list[dict]) -> dict:
        """The :meth:`state_dict` of the whole batch from those of its parts, in order (the
        processes of a run, which draw for the whole batch and so share the generator's state).
        Per-environment tensors are joined along the batch; everything else must agree."""
        if len(states) == 1:
            return states[0]
        first, whole = states[0], dict(states[0])
        for name, value in first.items():
            if name == "num_envs":
                whole[name] = sum(int(s[name]) for s in states)
            elif name in cls._STATE_TENSORS or name == "first_roll" or name in _OBJECT_STATE:
                whole[name] = None if value is None else torch.cat([s[name] for s in states])
            elif name == "generator":
                if any(not torch.equal(s[name], value) for s in states):
                    raise ValueError("the environments' parts have different generator states: they are not "
                                     "one run's processes")
            elif any(s[name] != value for s in states):
                raise ValueError(f"the environments' parts differ in {name!r} ({[s[name] for s in states]})")
        return whole

    @classmethod
    def state_rows(cls, state: dict, start: int, stop: int) -> dict:
        """The :meth:`state_dict` of the environments ``start .. stop - 1`` of a whole batch's state
        (:meth:`join_states`): a process's share when another number of processes resumes it."""
        total = int(state["num_envs"])
        if not 0 <= start < stop <= total:
            raise ValueError(f"rows {start}..{stop - 1} are not within the {total} environments of the state")
        rows = dict(state, num_envs=stop - start)
        for name in (*cls._STATE_TENSORS, "first_roll", *_OBJECT_STATE):
            if rows.get(name) is not None:
                rows[name] = state[name][start:stop].clone()
        return rows

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` taken from an environment built with the same arguments."""
        for key, expected in (("num_envs", self.num_envs), ("num_textures", len(self.textures))):
            if state.get(key) != expected:
                raise ValueError(
                    f"state was saved with {key}={state.get(key)!r}, this environment has {expected}; "
                    "build it with the same arguments as the one that was saved"
                )
        for name in self._STATE_TENSORS:
            if name == "q_sum_deg" and name not in state:  # saved before q_iterations: q was the last iteration's
                self.q_sum_deg = torch.zeros_like(self.q_sum_deg)
                continue
            setattr(self, name, state[name].to(device=self.device, dtype=getattr(self, name).dtype).clone())
        self.fixation = int(state["fixation"])
        self.iteration = int(state["iteration"])
        self._generator.set_state(state["generator"])
        # The optics (None in states saved before perturbations were data, as
        # `aectorch.runtime.migrations` fills them in: none but the roll, which roll_deg holds);
        # the roll tensor is the state's own.
        roll = self.roll_deg
        self.set_optics(Optics.from_dict(state["optics"]) if state.get("optics") is not None
                        else replace(NEUTRAL, roll_deg=tuple(roll[0].tolist())))
        self.roll_deg = roll
        first_optics = state.get("first_optics")
        self._first_optics = None if first_optics is None else Optics.from_dict(first_optics)
        self._first_image = {}
        self._moved()
        first_roll = state.get("first_roll")
        self._first_roll = None if first_roll is None else first_roll.to(self.roll_deg)
        for name, attribute in _OBJECT_STATE.items():
            value = state.get(name)
            setattr(self, attribute, None if value is None else value.to(device=self.device, dtype=self.dtype).clone())
        self.plane_y_m = None
        if self.object_speed is not None:  # the object where it was
            self._start_plane = (self.distance_m + float(self.head.eye_x_m), torch.zeros_like(self.distance_m))
            self._place_object(self.iteration)

    def close(self) -> None:
        """Free the renderers' resources (pyrender's OpenGL contexts); the environment cannot
        render afterwards. Also ``with ActiveDepthEnv(...) as env:``."""
        for renderer in (self.renderer, self._scale_renderer):
            if renderer is not None:
                renderer.close()

    def __enter__(self) -> "ActiveDepthEnv":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"ActiveDepthEnv(num_envs={self.num_envs}, renderer={self.renderer_name!r}, "
            f"textures={len(self.textures)}, h={self.fixation_iterations}, shift_m={self.shift_m}, "
            f"shift_iterations={self.shift_iterations}, yoked_pursuit={self.yoked_pursuit}, "
            f"q_iterations={self.q_iterations}, pan_range_deg={self.pan_range_deg}, "
            f"vergence_range_deg={self.vergence_range_deg}, "
            f"window={tuple(self.window)}, device={self.device}, dtype={self.dtype})"
        )
