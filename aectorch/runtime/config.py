"""Structured configs of the experiment (`train.py`, Hydra).

One dataclass per component; each docstring explains every field and each ``__post_init__``
rejects impossible values with a message that names the field (``env.num_envs must be ...``).
Hydra composes the command line onto :class:`ExperimentConfig` (type checks), and
:func:`to_experiment_config` then builds the dataclasses, which runs the value checks.
Beside it: the named settings (`aectorch.runtime.presets`), the checks of what the dataclasses
cannot see (`aectorch.runtime.resources`) and Hydra's store (`aectorch.runtime.store`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Optional

import torch

from aectorch._checks import check_bool, check_choice, check_device, check_distances, check_int, check_real, is_int
from aectorch.choices import DType, Eye, RendererName
from aectorch.evaluation import EVAL_BATCH_SIZE
from aectorch.framework import LearnerConfig
from aectorch.runtime.metrics import PAPER_WINDOW, RECENT_WINDOW
from aectorch.runtime.perturbations import Event, PerturbationEventConfig, resolve_events
from aectorch.runtime.watchdog import WatchdogConfig
from aectorch.sim import (
    DEFAULT_DISTANCES_M, DEFAULT_PROTOCOL, PROCEDURAL_TEXTURES, START_PURSUIT_DEG, START_VERGENCE_DEG, TrialProtocol,
    check_oculomotor_range,
)
from aectorch.sim.scene import SceneLayout

__all__ = [
    "EnvConfig",
    "EvalConfig",
    "ExperimentConfig",
    "PerturbationConfig",
    "PerturbationEventConfig",
    "PlasticityConfig",
    "RecordConfig",
    "TrainConfig",
    "WatchdogConfig",
    "to_container",
    "to_experiment_config",
]

_DTYPES = {DType.float32: torch.float32, DType.float64: torch.float64}
#: `EnvConfig`'s keys that are the trial protocol's fields (`EnvConfig.protocol`).
_PROTOCOL_FIELDS = tuple(f.name for f in fields(TrialProtocol))


def _check_folder(value: object, name: str) -> None:
    if value is not None and (not isinstance(value, str) or not value):
        raise ValueError(f"{name} must be null or a folder of images, got {value!r}")


@dataclass
class EnvConfig:
    """The simulated world: B HOAP-3 heads in front of textured planes (`ActiveDepthEnv`).

    Attributes:
        num_envs: environments B simulated in lockstep (>= 1); every learner step is the mean
            of the B per-environment updates.
        renderer: ``"torch"`` (differentiable bilinear ray casting, fast on CPU and GPU) or
            ``"pyrender"`` (OpenGL through OSMesa).
        textures: a folder of images used as the object textures (`TextureBank.from_folder`,
            512 x 512 grey); ``None`` uses ``TextureBank.default("train")``, 100 procedural
            1/f textures standing in for the paper's photographs; ``dead-leaves`` 100
            dead-leaves textures (`TextureBank.dead_leaves`, the default set's seed): occluding
            discs of power-law sizes, with sharp edges and flat regions.
        num_textures: ``null`` (default): the generated training set's 100 textures; N (>= 1): the
            first N of the same seeded sequence (procedural or ``dead-leaves``; the first 100 are
            the default set), a larger world for long training. Only for generated textures: a
            folder's images are what it holds.
        distances_m: object distances a trial draws from uniformly, metres (paper: 1.0 to 3.0 m
            in 0.1 m steps).
        fixation_iterations: h, iterations per fixation (paper: 30).
        shift_m: the body's lateral shift in each fixation, metres (paper: 0.1).
        shift_iterations: the body movement's profile: the shift grows linearly over the first
            this many iterations of each fixation (at most ``fixation_iterations``) and is then
            held (1 = the whole shift before the first iteration; `ActiveDepthEnv`).
        yoked_pursuit: pursuit increments move both eyes (Hering's law), so vergence only adds
            the convergence; ``false``: the dominant eye alone.
        q_iterations: the depth MLP reads each fixation's pan and vergence averaged over its
            last this many iterations (1, the paper: the last iteration's).
        pursuit_start_deg: left-eye pan at each fixation's start, degrees (paper: 0).
        vergence_start_deg: vergence at each fixation's start, degrees (paper: 0 = parallel).
        pursuit_start_spread_deg: while training, each fixation's start pan is drawn uniformly
            from ``pursuit_start_deg +- pursuit_start_spread_deg`` per environment (>= 0; 0, the
            paper, starts every fixation at ``pursuit_start_deg``). The evaluation always starts
            from the standard state (0, 0).
        vergence_start_spread_deg: the same for the vergence at each fixation's start (>= 0).
        pursuit_start_error_deg: while training, each fixation's eyes start turned off their
            target by an angle drawn uniformly from ``+-pursuit_start_error_deg`` (both eyes, the
            vergence kept); the target and the parallax pair's first image are where the start
            pans point, so pursuit starts off its optimum on either side (>= 0; 0, the paper:
            every fixation starts on its target). The evaluation always starts on target.
        object_speed_deg: a moving object: ``[low, high]``, the range of its sideways speed,
            degrees per iteration, drawn uniformly per environment and fixation (positive: toward
            the robot's left; ``[-1, 1]`` draws both directions); it starts each fixation straight
            ahead at the trial's distance and pursuit has to follow it (`TrialProtocol`,
            docs/simulation.md). ``[0, 0]`` (default): the object stands still, the paper's.
        object_depth_speed_m: the range of the object's speed in depth, metres per iteration,
            drawn per trial (negative: approaching; vergence follows it, and the depth's ground
            truth is where it ends). ``[0, 0]`` (default): none.
        aperture_m: the eyes' aperture (pupil diameter, metres) of the world's defocus: an eye
            focused off the object sees it blurred by a disc of ``aperture_m * |1/d - focus|``
            radians (`TrialProtocol`, docs/simulation.md; default 0.016, where 0.25 D blurs by one
            coder pixel; 0: a pinhole). The eyes stay focused on the object unless something sets
            their focus, so by default the images are the pinhole's.
        accommodation_start_D: ``null`` (default): no accommodation cue. A number (dioptres, >= 0):
            the environment serves the ``accommodation`` cue (``learner.cues.accommodation``,
            ``+experiment=accommodation``), each fixation starting with both eyes focused there.
        yoked_accommodation: the accommodation cue focuses both eyes alike (default); ``false``:
            the left eye, and a second cue, ``learner.cues.accommodation_right``, the right one.
        pan_range_deg: ``[low, high]``, the range of each eye's pan, degrees, within the HOAP-3's
            joint limits (the URDF's +-45, the default): the oculomotor range
            (`aectorch.sim.oculomotor`), where every eye movement ends, in both renderers.
        vergence_range_deg: ``[low, high]``, the range of the vergence (right pan minus left
            pan, positive converging), degrees; it must hold 0 (parallel, where fixations start).
            Default ``[-2, 40]``: human eyes diverge only a few degrees past parallel and converge
            to a near point of about 8 cm; without a floor, a learner whose reward is flat on a
            view of little texture can drift its eyes apart. ``[-90, 90]`` leaves only
            the pan limits (what runs did before the range existed).
        pursuit_velocity: the eyes keep a pursuit velocity that moves them on between iterations,
            and the environment serves the ``slip`` cue (``learner.cues.slip``,
            ``+experiment=slip``), which learns it from the retinal slip: the left eye's previous
            frame against its current one (docs/simulation.md). ``false`` (default): the paper's.
        velocity_memory: with ``pursuit_velocity``, each pursuit step also adds to the pursuit
            velocity (integral action: a lag pursuit keeps catching up on raises the velocity).
        scene: the world's depth structure, drawn per trial (`aectorch.sim.scene.SceneLayout`, its
            own table below): a narrower object, moved sideways and slanted, before a background at
            its own distance and texture. The default is the plain world. Training only: the
            evaluation's trials are the plain world's.
        device: torch device of the environment and the learner (``"cpu"``, ``"cuda"``, ...).
        dtype: ``"float32"`` or ``"float64"``, of the environment and the learner.
    """

    num_envs: int = 32
    renderer: RendererName = DEFAULT_PROTOCOL.renderer
    textures: Optional[str] = None
    num_textures: Optional[int] = None
    distances_m: list[float] = field(default_factory=lambda: list(DEFAULT_DISTANCES_M))
    fixation_iterations: int = DEFAULT_PROTOCOL.fixation_iterations
    shift_m: float = DEFAULT_PROTOCOL.shift_m
    shift_iterations: int = DEFAULT_PROTOCOL.shift_iterations
    yoked_pursuit: bool = DEFAULT_PROTOCOL.yoked_pursuit
    q_iterations: int = DEFAULT_PROTOCOL.q_iterations
    pursuit_start_deg: float = START_PURSUIT_DEG
    vergence_start_deg: float = START_VERGENCE_DEG
    pursuit_start_spread_deg: float = 0.0
    vergence_start_spread_deg: float = 0.0
    pursuit_start_error_deg: float = 0.0
    object_speed_deg: list[float] = field(default_factory=lambda: list(DEFAULT_PROTOCOL.object_speed_deg))
    object_depth_speed_m: list[float] = field(default_factory=lambda: list(DEFAULT_PROTOCOL.object_depth_speed_m))
    aperture_m: float = DEFAULT_PROTOCOL.aperture_m
    accommodation_start_D: Optional[float] = DEFAULT_PROTOCOL.accommodation_start_D
    yoked_accommodation: bool = DEFAULT_PROTOCOL.yoked_accommodation
    pan_range_deg: list[float] = field(default_factory=lambda: list(DEFAULT_PROTOCOL.pan_range_deg))
    vergence_range_deg: list[float] = field(default_factory=lambda: list(DEFAULT_PROTOCOL.vergence_range_deg))
    pursuit_velocity: bool = DEFAULT_PROTOCOL.pursuit_velocity
    velocity_memory: bool = DEFAULT_PROTOCOL.velocity_memory
    scene: SceneLayout = field(default_factory=SceneLayout)
    device: str = "cpu"
    dtype: DType = DType.float32

    def __post_init__(self) -> None:
        owner = "env"
        check_int(self.num_envs, f"{owner}.num_envs", 1)
        _check_folder(self.textures, f"{owner}.textures")
        if self.num_textures is not None:
            check_int(self.num_textures, f"{owner}.num_textures", 1)
            if self.textures is not None and self.textures not in PROCEDURAL_TEXTURES:
                raise ValueError(f"{owner}.num_textures={self.num_textures} sizes a generated texture set, but "
                                 f"{owner}.textures={self.textures!r} is a folder: leave {owner}.num_textures=null")
        self.distances_m = check_distances(self.distances_m, f"{owner}.distances_m")
        for name in ("pursuit_start_deg", "vergence_start_deg"):
            check_real(getattr(self, name), f"{owner}.{name}", unit="degrees")
        for name in ("pursuit_start_spread_deg", "vergence_start_spread_deg", "pursuit_start_error_deg"):
            check_real(getattr(self, name), f"{owner}.{name}", minimum=0, unit="degrees")
        try:  # the trial protocol's fields are checked by `TrialProtocol`, named by their keys here
            protocol = self.protocol
        except ValueError as err:
            raise ValueError(f"{owner}.{err}") from None
        self.renderer = protocol.renderer
        for name in ("object_speed_deg", "object_depth_speed_m", "pan_range_deg", "vergence_range_deg"):
            setattr(self, name, list(getattr(protocol, name)))
        # the config's environments have the HOAP-3's head: its pan range is refused here, before a run
        check_oculomotor_range(self.pan_range_deg, self.vergence_range_deg, prefix=f"{owner}.")
        check_device(self.device, f"{owner}.device")
        self.dtype = check_choice(self.dtype, f"{owner}.dtype", DType)

    @property
    def protocol(self) -> TrialProtocol:
        """The trial protocol these fields make (`TrialProtocol`): the one object the run's
        environments (`aectorch.runtime.build_env`) and its evaluation take."""
        return TrialProtocol(**{name: getattr(self, name) for name in _PROTOCOL_FIELDS})

    @property
    def torch_dtype(self) -> torch.dtype:
        return _DTYPES[self.dtype]


@dataclass
class TrainConfig:
    """The training loop, its logs and checkpoints.

    Attributes:
        iterations: learner iterations (>= 1); each advances every environment by one
            iteration (steps k1 and k2), so the run makes ``iterations * env.num_envs``
            environment iterations.
        compile: compile the two encoders' forward passes (the hot path) with ``torch.compile``
            where that pays: on CUDA; on CPU the hot paths are fused kernels and nothing is
            compiled (`aectorch.runtime.builders.compile_hot_path`).
        resume: a run folder to continue in place from its ``checkpoint.pt`` (until
            ``iterations``); its stored config is used, except ``train.iterations``,
            ``train.progress`` and ``train.resume`` from the command line (and ``env.num_envs``,
            which may change with the number of processes while the whole batch stays the
            same; without it, the checkpoint's whole batch is split evenly over the processes).
            A config group given with it (``rearing=...``, ``+experiment=...``, ``preset=...``,
            ``plasticity=...``) must be the one the run was started with (which
            ``provenance.json``'s first session records; Hydra's ``.hydra/`` of the start stays
            too, a resume's record going to ``.hydra/resumed/``) and must set what the run holds:
            another is refused with one line naming it.
            ``auto``: resume the run folder's own checkpoint if it holds one, else start a new
            run there: the setting for jobs that are started again with the same command
            (``torchrun --max-restarts``, Slurm's ``--requeue``, re-launched Hydra sweeps). It
            needs the folder given (``hydra.run.dir``; ``hydra.sweep.dir`` for a sweep): Hydra's
            default folder is new at every start.
        overwrite: a new run into a folder that holds a run's files deletes them and starts
            afresh: exactly the files aectorch wrote (:data:`aectorch.runtime.outputs.RUN_FILES`,
            the run's figures and TensorBoard events, and the evaluations that
            ``python -m aectorch.evaluate`` wrote into the folder), never a file of the user's.
            Off (default), a new run into a folder that holds ``checkpoint.pt`` or any other of
            those files stops before it writes anything, naming what the folder holds and the
            ways on (``train.resume``, another folder); only a start killed before its first
            checkpoint (its ``provenance.json`` and no ``checkpoint.pt``) starts again there.
        log_every: append a line to ``metrics.jsonl`` and TensorBoard every this many
            iterations (>= 1).
        checkpoint_every: write ``checkpoint.pt`` every this many iterations (>= 1), and always
            at the end or on an interruption.
        readout_every: read the code out every this many iterations (>= 1) and at the end: a
            line ``{"iteration": N, "code": {"<cue>/<scale>": code_summary}}`` per read-out in
            ``code_readouts.jsonl`` (`aectorch.coding.readouts.code_summary` of each dictionary;
            `aectorch.runs.Run.code_readouts` reads them). A resume keeps the lines up to its
            checkpoint. ``null`` (default): none.
        threads: CPU threads: N >= 1 gives torch (``torch.set_num_threads``) and the fused
            kernels (``aectorch.ops.native.set_threads``) N each; 0 (default) gives the fused
            kernels (rendering, sparse coding) every core this process may use
            (``os.sched_getaffinity``, shared among a ``torchrun`` run's processes) and torch's
            own operations one, which measured fastest (docs/performance.md). ``train.py`` sets
            ``OMP_WAIT_POLICY=PASSIVE`` (unless set), so idle threads sleep instead of spinning on
            a core another process needs.
        progress: show tqdm progress bars.
        figures: draw the figures into ``figures/`` at the end.
        tensorboard: write TensorBoard events into ``tb/``.
        deterministic: ``torch.use_deterministic_algorithms(True, warn_only=True)`` for the
            run (and cuBLAS's workspace setting on CUDA): the same seed and config give the same
            run on the same machine. Its NaN fill of new tensors stays off
            (`aectorch.runtime.FILL_UNINITIALIZED_MEMORY`).
        keep_best: early stopping by the training signal: at every log line whose eq. (9)
            window is full (``metrics_window`` fixation ends), if the window's pursuit plus
            vergence MAE is the lowest so far, write the state to ``best.pt`` (the checkpoint's
            format); the final evaluation then evaluates ``best.pt``. Only training errors
            choose it, never held-out data. ``checkpoint.pt`` stays the latest state (to resume).
        metrics_window: fixation ends the training window's pursuit and vergence MAE (eq. 9) and
            trials its depth MAE average over (>= 1; the paper: 1000).
        recent_window: with perturbations: fixation ends of the short window that shows the
            transient (``<movement>_recent_deg``, ``<movement>_recent_1px`` in ``metrics.jsonl``,
            half as many trials for ``depth_recent_m``: the same stretch of iterations) and that the
            recovery read-out measures (>= 1; default 128: 4 fixations of 32 environments, 120
            iterations; the 1000-fixation window lags the errors by hundreds of iterations).
        depth_calibration_trials: after training, before the evaluation (so only with
            ``eval.enabled``): the evaluated state
            (``best.pt``, or the last state) runs this many greedy, frozen trials on the
            training textures (trial i: texture i mod T, distance i mod len(``env.distances_m``)),
            and its depth MLP is refitted on their final eye angles alone
            (``JointLearner.calibrate_depth``; during training the MLP learns from trials with
            *sampled* actions). Written to ``calibrated.pt``, which the evaluation then
            evaluates. 0 (default) turns it off; fewer than 10 skip it (>= 0; not in the paper;
            docs/results.md, "Depth", says why it is off).
    """

    iterations: int = 2400
    compile: bool = False
    resume: Optional[str] = None
    overwrite: bool = False
    log_every: int = 25
    checkpoint_every: int = 500
    readout_every: Optional[int] = None
    threads: int = 0
    progress: bool = True
    figures: bool = True
    tensorboard: bool = True
    deterministic: bool = True
    keep_best: bool = True
    metrics_window: int = PAPER_WINDOW
    recent_window: int = RECENT_WINDOW
    depth_calibration_trials: int = 0

    def __post_init__(self) -> None:
        owner = "train"
        for name, minimum in (("iterations", 1), ("depth_calibration_trials", 0), ("log_every", 1),
                              ("metrics_window", 1), ("recent_window", 1), ("checkpoint_every", 1), ("threads", 0)):
            check_int(getattr(self, name), f"{owner}.{name}", minimum)
        for name in ("compile", "overwrite", "progress", "figures", "tensorboard", "deterministic", "keep_best"):
            check_bool(getattr(self, name), f"{owner}.{name}")
        if self.readout_every is not None and not (is_int(self.readout_every) and self.readout_every >= 1):
            raise ValueError(f"{owner}.readout_every must be null (no read-outs) or an int >= 1, "
                             f"got {self.readout_every!r}")
        if self.resume is not None and (not isinstance(self.resume, str) or not self.resume):
            raise ValueError(f"{owner}.resume must be null, auto or a run folder, got {self.resume!r}")
        if self.resume is not None and self.overwrite:
            raise ValueError(f"{owner}.overwrite=true starts a run afresh and {owner}.resume={self.resume} continues "
                             "one: give one of them")


@dataclass
class EvalConfig:
    """Evaluation at the end of training (`aectorch.evaluation.evaluate`), frozen and greedy.

    Attributes:
        enabled: evaluate after training and write ``evaluation.json``.
        textures: a folder of held-out images; ``None`` uses ``TextureBank.default("test")``,
            40 procedural textures disjoint from the training set.
        distances_m: distances every texture is tested at, metres.
        batch_size: environments simulated at once (>= 1).
    """

    enabled: bool = True
    textures: Optional[str] = None
    distances_m: list[float] = field(default_factory=lambda: [1.0, 1.5, 2.0, 2.5, 3.0])
    batch_size: int = EVAL_BATCH_SIZE

    def __post_init__(self) -> None:
        owner = "eval"
        check_bool(self.enabled, f"{owner}.enabled")
        _check_folder(self.textures, f"{owner}.textures")
        self.distances_m = check_distances(self.distances_m, f"{owner}.distances_m")
        check_int(self.batch_size, f"{owner}.batch_size", 1)


@dataclass
class PerturbationConfig:
    """The paper's perturbation (section 4, Fig. 4) in short: a constant in-plane roll of the eyes.

    At ``first_fraction * train.iterations`` (rounded down) the eye ``first_eye`` is rolled by
    ``roll_deg`` about its optical axis; at ``second_fraction * train.iterations`` the other eye
    is rolled by the same angle too. Both stay rolled until the end. Shorthand for two ``roll``
    events of ``perturbations`` (:meth:`events`), which come before that list's own.

    Attributes:
        roll_deg: the roll, degrees (0 = no perturbation; the paper: 3).
        first_eye: ``"left"`` or ``"right"`` (the paper: right).
        first_fraction: when the first eye is rolled, a fraction of ``train.iterations``.
        second_fraction: when both eyes are rolled; ``0 < first_fraction < second_fraction <= 1``.
    """

    roll_deg: float = 0.0
    first_eye: Eye = Eye.right
    first_fraction: float = 0.5
    second_fraction: float = 0.75

    def __post_init__(self) -> None:
        owner = "perturbation"
        check_real(self.roll_deg, f"{owner}.roll_deg", unit="degrees")
        self.first_eye = check_choice(self.first_eye, f"{owner}.first_eye", Eye)
        for name in ("first_fraction", "second_fraction"):
            check_real(getattr(self, name), f"{owner}.{name}")
        if self.enabled and not (0 < self.first_fraction < self.second_fraction <= 1):
            raise ValueError(
                f"{owner}.first_fraction and {owner}.second_fraction must satisfy "
                f"0 < first_fraction < second_fraction <= 1, got {self.first_fraction!r} and "
                f"{self.second_fraction!r}"
            )

    @property
    def enabled(self) -> bool:
        return self.roll_deg != 0

    def events(self, iterations: int) -> list[Event]:
        """The two roll events (`aectorch.runtime.perturbations.Event`): ``first_eye`` rolled from
        iteration ``int(first_fraction * iterations)`` (0-based) on, the other eye from
        ``int(second_fraction * iterations)``; none when disabled. A second event at the run's
        end never acts."""
        if not self.enabled:
            return []
        other = "left" if self.first_eye == Eye.right else "right"
        entries = [{"kind": "roll", "start": int(self.first_fraction * iterations), "eye": str(self.first_eye),
                    "params": {"deg": float(self.roll_deg)}, "label": f"{self.first_eye} eye rolled"}]
        second = int(self.second_fraction * iterations)
        if second < iterations:
            entries.append({"kind": "roll", "start": second, "eye": other, "params": {"deg": float(self.roll_deg)},
                            "label": "both eyes rolled"})
        return resolve_events(entries, iterations, owner="perturbation")


@dataclass
class PlasticityConfig:
    """How plastic the learners stay around perturbations: a perturbation experiment's choice
    (``plasticity=decay|floor|raise``, :data:`PLASTICITY`). Today's rates decay (the
    dictionaries' ``learner.cues.<cue>.encoder.decay``, a natural actor-critic's
    ``nac.actor_decay``; PPO's step is constant); ``learner.cues.<cue>.encoder.floor`` and
    ``nac.actor_floor`` stop them at a floor.

    Attributes:
        raise_to: ``null`` (default), or a fraction in (0, 1]: at the start and the end of every
            perturbation event each decayed rate is raised back to this fraction of its starting
            value, from where it decays again (`aectorch.framework.JointLearner.raise_plasticity`).
    """

    raise_to: Optional[float] = None

    def __post_init__(self) -> None:
        if self.raise_to is not None and not (isinstance(self.raise_to, (int, float)) and not isinstance(
                self.raise_to, bool) and 0 < self.raise_to <= 1):
            raise ValueError(f"plasticity.raise_to must be null or a fraction in (0, 1], got {self.raise_to!r}")


@dataclass
class RecordConfig:
    """Recording training as a LeRobotDataset (`aectorch.integrations.lerobot`; needs LeRobot).

    Attributes:
        lerobot: a new folder to record into (``null``: no recording). Every finished fixation of
            the recorded environments becomes an episode (run ``train.py`` with
            ``.venv-lerobot/bin/python``; docs/lerobot.md). On resume it is taken from the command
            line (a resumed run records into a new folder, or not at all).
        envs: how many of the ``env.num_envs`` environments to record (the first ones, >= 1).
    """

    lerobot: Optional[str] = None
    envs: int = 1

    def __post_init__(self) -> None:
        if self.lerobot is not None and (not isinstance(self.lerobot, str) or not self.lerobot):
            raise ValueError(f"record.lerobot must be null or a new folder, got {self.lerobot!r}")
        check_int(self.envs, "record.envs", 1)


@dataclass
class ExperimentConfig:
    """The whole experiment: world, learner, training loop, final evaluation, perturbation.

    Attributes:
        env: the simulated world (:class:`EnvConfig`).
        learner: the agent (`aectorch.framework.LearnerConfig`; its ``control`` holds the
            actor-critics' `ActorCriticConfig`).
        train: the loop, logs and checkpoints (:class:`TrainConfig`).
        eval: the final evaluation on held-out textures (:class:`EvalConfig`).
        perturbation: the paper's roll perturbation in short (:class:`PerturbationConfig`).
        perturbations: perturbation events (`aectorch.runtime.perturbations.PerturbationEventConfig`:
            kind, start, end, eye, params, label), applied in this order after ``perturbation``'s.
        plasticity: how plastic the learners stay around the events (:class:`PlasticityConfig`).
        record: recording the training as a LeRobotDataset (:class:`RecordConfig`).
        watchdog: the health checks after every iteration (`aectorch.runtime.watchdog.WatchdogConfig`;
            on resume taken from the command line, since it changes nothing that is learned).
        seed: seeds the learner's generator (initial dictionaries and policies, actions) and the
            environments' (textures, distances) (>= 0).
    """

    env: EnvConfig = field(default_factory=EnvConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    perturbation: PerturbationConfig = field(default_factory=PerturbationConfig)
    perturbations: list[PerturbationEventConfig] = field(default_factory=list)
    plasticity: PlasticityConfig = field(default_factory=PlasticityConfig)
    watchdog: WatchdogConfig = field(default_factory=WatchdogConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.record.envs > self.env.num_envs:
            raise ValueError(f"record.envs={self.record.envs} exceeds env.num_envs={self.env.num_envs}")
        check_int(self.seed, "seed", 0)
        self.perturbations = [e if isinstance(e, PerturbationEventConfig) else PerturbationEventConfig(**e)
                              for e in self.perturbations]
        self.events()  # checked against the run's length: the errors name the entry's key
        self._check_served_cues_are_learned()
        if self.env.aperture_m == 0:
            refractive = [i for i, e in enumerate(self.perturbations) if str(e.kind) == "refractive_error"]
            if refractive:
                raise ValueError(f"perturbations[{refractive[0]}] is a refractive_error, which blurs only through an "
                                 "aperture, and env.aperture_m=0 makes the eyes pinholes; give env.aperture_m > 0")

    def _check_served_cues_are_learned(self) -> None:
        """``env.accommodation_start_D`` makes the environment serve the accommodation cue (and,
        unyoked, the right eye's): a cue no learner config learns would be a request that does
        nothing, and its error, never moved, would read as perfect focus."""
        if self.env.accommodation_start_D is None:
            return
        served = ["accommodation"] + ([] if self.env.yoked_accommodation else ["accommodation_right"])
        learned = self.learner.active_cues if self.learner.active_cues is not None else list(self.learner.cues)
        missing = [cue for cue in served if cue not in learned]
        if missing:
            raise ValueError(f"env.accommodation_start_D={self.env.accommodation_start_D} serves the {missing[0]} cue, "
                             f"which the learner does not learn (no learner.cues.{missing[0]}): add "
                             "+experiment=accommodation, or leave env.accommodation_start_D out")

    def events(self) -> list[Event]:
        """Every perturbation event of the run, checked, in their order: ``perturbation``'s rolls,
        then ``perturbations`` (`aectorch.runtime.perturbations.resolve_events`)."""
        iterations = self.train.iterations
        return self.perturbation.events(iterations) + resolve_events(self.perturbations, iterations)


def to_experiment_config(node) -> ExperimentConfig:
    """Build (and so validate) an :class:`ExperimentConfig` from a DictConfig or a plain dict.

    Hydra's ``defaults`` key, if present, is ignored. Raises ``ValueError`` naming the field
    for an impossible value, and OmegaConf's errors for unknown keys or wrong types.
    """
    from omegaconf import OmegaConf

    container = node if isinstance(node, dict) else OmegaConf.to_container(node, resolve=True)
    container = {k: v for k, v in container.items() if k != "defaults"}
    merged = OmegaConf.merge(OmegaConf.structured(ExperimentConfig), container)
    try:
        return OmegaConf.to_object(merged)
    except ValueError as err:
        raise ValueError(_located(str(err), merged)) from err


def _located(message: str, node, path: str = "") -> str:
    """``message`` of a nested config's check (``"cue.actions_deg must ..."``) with the owner
    replaced by the full path of the node that raised it (``"learner.cues.stereo.actions_deg
    must ..."``)."""
    from omegaconf import DictConfig, OmegaConf

    for key in node:
        child = node._get_node(key)
        if not isinstance(child, DictConfig) or child._is_missing() or child._is_none():
            continue
        where = f"{path}.{key}" if path else str(key)
        try:
            OmegaConf.to_object(child)
        except ValueError as err:
            if str(err) == message:
                return _located(message, child, where)
    owner, dot, rest = message.partition(".")
    if path and dot and owner.isidentifier() and " " not in owner:
        return f"{path}.{rest}"
    return message


def to_container(cfg: ExperimentConfig) -> dict:
    """The plain (JSON/YAML-ready) dict of a config, as stored in checkpoints."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True, enum_to_str=True)
