"""The choice fields' values, as string enums (subclasses of :class:`Choice`).

A member equals, prints and serialises as its string (``RendererName.torch == "torch"``), so code
and configs may pass either; the structured configs (`aectorch.runtime.config`) type their fields
with these enums, and OmegaConf rejects any other value with the list of choices.
`aectorch._checks.check_choice` turns a string into a member, or an error naming the argument.
"""

from __future__ import annotations

from enum import Enum

__all__ = ["AgentName", "Algorithm", "Choice", "DictionaryStart", "DType", "Eye", "Features", "PerturbationKind", "Policy", "Pooling", "Proprioception", "Readout", "RendererName", "Reward",
           "Symmetry", "WatchdogMode"]


class Choice(str, Enum):
    """A string enum whose members print, format and compare as their string values."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    def __repr__(self) -> str:
        return repr(str(self.value))

    @classmethod
    def values(cls) -> tuple[str, ...]:
        return tuple(str(m.value) for m in cls)


class RendererName(Choice):
    """``torch``: differentiable ray casting (CPU and GPU); ``pyrender``: OpenGL (OSMesa or EGL)."""

    torch = "torch"
    pyrender = "pyrender"


class DType(Choice):
    """The floating-point type of the environment and the learner."""

    float32 = "float32"
    float64 = "float64"


class Algorithm(Choice):
    """Sparse coding: the paper's matching pursuit or orthogonal matching pursuit."""

    mp = "mp"
    omp = "omp"


class Pooling(Choice):
    """Pooling of the patches' activities: mean (the lineage) or sum (eq. 3 literally)."""

    mean = "mean"
    sum = "sum"


class Features(Choice):
    """What the actor-critics see: the pooled activities, them normalised to unit length, or none
    of the code (the agent senses its proprioception alone)."""

    pooled = "pooled"
    unit = "unit"
    none = "none"


class Reward(Choice):
    """The paper's coding reward, its improvement R(s') - R(s), or the improvement over a running
    root mean square of itself (`aectorch.control.rewards`)."""

    coding = "coding"
    improvement = "improvement"
    scaled = "scaled"


class Efficiency(Choice):
    """What a cue's reward R measures: the code's ``reconstruction`` (R = -sum e, eq. 6) or the
    ``information`` it keeps of the input (R = sum 1/2 log(E (1 - e)), `aectorch.coding.focus`)."""

    reconstruction = "reconstruction"
    information = "information"


class AgentName(Choice):
    """The learning algorithm of a cue's eye movement: the natural actor-critic or PPO."""

    nac = "nac"
    ppo = "ppo"


class Symmetry(Choice):
    """A cue's image-pair symmetry: both images mirrored left-right, or the two images exchanged."""

    mirror = "mirror"
    swap = "swap"


class Eye(Choice):
    left = "left"
    right = "right"


class DictionaryStart(Choice):
    """A dictionary's first atoms: Gaussian random, or random with both eyes' halves equal."""

    random = "random"
    binocular = "binocular"


class Proprioception(Choice):
    """What a cue's agent may sense of its own eyes and body besides the images
    (`ActiveDepthEnv.proprioception`): the commanded vergence angle (degrees), the left eye's commanded
    pan (degrees), its focus (dioptres), or the body's sideways shift since the fixation's start
    (metres, positive to the robot's left)."""

    vergence = "vergence"
    pan = "pan"
    focus = "focus"
    shift = "shift"


class Readout(Choice):
    """The greedy policy's increment: the most probable action's, or the policy's mean increment."""

    argmax = "argmax"
    mean = "mean"


class Policy(Choice):
    """Evaluation actions: the argmax (the protocol) or sampled as in training."""

    greedy = "greedy"
    sampled = "sampled"


class WatchdogMode(Choice):
    """``stop`` raises at the first problem, ``warn`` warns once per kind, ``off`` skips the checks."""

    stop = "stop"
    warn = "warn"
    off = "off"


class PerturbationKind(Choice):
    """The perturbations of `aectorch.sim.perturbations` (`PERTURBATIONS`): of one eye's mounting
    (``roll``, ``strabismus``, ``camera_shift``, ``vertical_misalignment``), of one eye's image (``anisometropia``,
    ``monocular_deprivation``, ``aniseikonia``), of one eye's focus (``refractive_error``) or of the
    world's textures (``orientation_rearing``)."""

    roll = "roll"
    strabismus = "strabismus"
    anisometropia = "anisometropia"
    refractive_error = "refractive_error"
    monocular_deprivation = "monocular_deprivation"
    aniseikonia = "aniseikonia"
    orientation_rearing = "orientation_rearing"
    camera_shift = "camera_shift"
    vertical_misalignment = "vertical_misalignment"
