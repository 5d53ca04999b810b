"""The experiment's named settings, each a dict of dotted keys (or events) that Hydra's groups
apply (`aectorch.runtime.store.register_configs`):

- ``preset``: ``default`` (no change, selected by default) and ``paper`` (:data:`PAPER_PRESET`,
  the paper's values), chosen with ``preset=paper``;
- ``experiment``: ``roll_perturbation`` (the paper's Fig. 4 experiment: one eye rolled 7 deg at
  0.4 of a 3000-iteration run, the other too at 0.8, :data:`ROLL_PERTURBATION`), added with
  ``+experiment=roll_perturbation``, and ``accommodation`` (:data:`ACCOMMODATION`, the
  accommodation cue beside pursuit and vergence), added with ``+experiment=accommodation``, and
  ``slip`` (:data:`SLIP`, a pursuit velocity learned from the retinal slip), ``+experiment=slip``,
  and ``robust_vergence`` (:data:`ROBUST_VERGENCE`, vergence robust past its optimum and over
  training length), ``+experiment=robust_vergence``;
- ``plasticity``: ``decay`` (the default, no change), ``floor`` and ``raise``
  (:data:`PLASTICITY`): how plastic the learners stay, a perturbation experiment's choice;
- ``rearing``: the AEC lineage's rearing conditions (:data:`REARING`), each a list of
  perturbation events: ``python train.py -m rearing=normal,monocular,...``.
"""

from __future__ import annotations

from typing import Any

from aectorch.framework import PAPER_ACTIONS_DEG, default_cues

__all__ = ["ACCOMMODATION", "ADDED_GROUPS", "GROUPS", "GROUP_DEFAULTS", "LIFELONG", "PAPER_PRESET", "PLASTICITY", "REARING", "REARING_CONDITION_SETTINGS", "REARING_SETTINGS", "ROBUST_VERGENCE", "ROLL_PERTURBATION", "SLIP", "STRABISMUS_VERGENCE_RANGE_DEG"]

#: The paper's values (Wong et al. 2017) where they differ from the defaults, applied by
#: ``preset=paper``: dotted key -> value. What the paper states and the defaults change: its
#: natural actor-critic with its greedy (argmax) policy, its seven actions, its two scales and no
#: symmetries of the cues (its matching pursuit with 288
#: atoms and 10 coefficients, and its protocol's 30 iterations and 0.1 m, are the defaults). What
#: it leaves unstated keeps the defaults (docs/paper-mapping.md): the step sizes and the critic,
#: the z-scored features, the body movement spread over 20 iterations with yoked pursuit, the
#: centred pyramid, the decaying rates, B = 32 robots. One value it leaves unstated is chosen
#: to make its configuration learn vergence: the stereo dictionaries start binocular (each atom
#: tuned to zero disparity; with a random start and no symmetry, vergence settled 0.66 deg off).
#: Its own length: within 20 minutes on two CPU cores.
PAPER_PRESET: dict[str, Any] = {
    **{f"learner.cues.{cue}.{key}": value for cue in default_cues()
       for key, value in (("actions_deg", list(PAPER_ACTIONS_DEG)), ("symmetry", None),
                          ("scales", ["coarse", "fine"]), ("agent", "nac"), ("readout", "argmax"))},
    "learner.cues.stereo.encoder.start": "binocular",
    "train.iterations": 6000,
}

#: The paper's perturbation experiment (section 4, Fig. 4), ``+experiment=roll_perturbation``:
#: the right eye rolled 7 deg at iteration 1200 (0.4 of a 3000-iteration run), the left eye too
#: at 2400 (0.8), both until the end: the one-eye stretch is long enough for the recovery
#: (experiments/roll_adaptation/README.md says why this angle and this length).
ROLL_PERTURBATION: dict[str, Any] = {
    "perturbations": [
        {"kind": "roll", "start": 0.4, "eye": "right", "params": {"deg": 7.0}, "label": "right eye rolled"},
        {"kind": "roll", "start": 0.8, "eye": "left", "params": {"deg": 7.0}, "label": "both eyes rolled"},
    ],
    "train.iterations": 3000,
}

#: Accommodation learned with vergence, ``+experiment=accommodation``: the environment
#: serves the accommodation cue (each fixation starts with both eyes focused at infinity, 0 D, as
#: vergence starts parallel) and the learner learns it with the information reward, which prefers
#: focus (`aectorch.coding.focus`); its actions are degrees of the blur disc's diameter (at the
#: default 16 mm aperture 0.92 deg per dioptre), at most 0.1 (a faster focus left vergence farther
#: off: docs/results.md). It codes the two finest scales only: at the wide and coarse scales' 3.6
#: and 1.8 deg pixels a dioptre's blur is a fraction of a pixel. Its agent senses the vergence angle
#: and the focus (``proprioception``) and not the code (``features: none``): blur is alike either
#: side of the object, and the vergence angle, once vergence is right, says where the object's focus
#: lies; the code's features let the policy fit the training textures (docs/results.md).
ACCOMMODATION: dict[str, Any] = {
    "env.accommodation_start_D": 0.0,
    "learner.cues.accommodation": {"efficiency": "information", "symmetry": None, "scales": ["fine", "full"],
                                   "actions_deg": [-0.1, -0.05, -0.02, 0.0, 0.02, 0.05, 0.1],
                                   "proprioception": ["vergence", "focus"], "features": "none"},
}

#: A pursuit velocity learned from the retinal slip, to follow a moving object, ``+experiment=slip``:
#: the eyes keep a velocity that moves them on between iterations, and the ``slip`` cue (the left
#: eye's previous frame against its current one; its actions change the velocity, degrees per
#: iteration) learns it beside pursuit's position steps and vergence. Mirroring the world mirrors
#: both frames and negates the velocity change, as for the parallax cue. Pursuit's steps also go on
#: as velocity (``velocity_memory``): without it the eye lags (experiments/moving_objects/README.md).
SLIP: dict[str, Any] = {
    "env.pursuit_velocity": True,
    "env.velocity_memory": True,
    "learner.cues.slip": {"symmetry": "mirror"},
}

#: Vergence that is robust past its optimum and over training length (experiments/long_training),
#: ``+experiment=robust_vergence``: training fixations start anywhere from 2 deg diverged to 4 deg
#: converged (``vergence_start_deg`` 1 +- ``vergence_start_spread_deg`` 3), so the states past the
#: optimum are learned too, and both cues' PPO policies decay their weights (AdamW's decoupled
#: decay, ``ppo.weight_decay``: 1.0 on the stereo cue, a time constant of about 600 iterations;
#: 0.1 on the parallax cue, about 6,000), so a policy that the rewards stop pushing relaxes toward
#: the uniform one instead of sharpening onto the training textures. 4,800 iterations, the study's
#: best stage on the choosing photographs: pursuit still unlearns with longer training.
ROBUST_VERGENCE: dict[str, Any] = {
    "env.vergence_start_deg": 1.0,
    "env.vergence_start_spread_deg": 3.0,
    "learner.cues.stereo.ppo.weight_decay": 1.0,
    "learner.cues.parallax.ppo.weight_decay": 0.1,
    "train.iterations": 4800,
}

#: Eyes that can train for as long as they see (experiments/long_training), ``+experiment=lifelong``:
#: the robust_vergence settings, pursuit's training fixations start up to 8 deg off their target
#: (``pursuit_start_error_deg``), so its policy learns to return from both sides, and the parallax
#: cue's plasticity closes at 2,400 iterations (``learn_until``: its code, policy and feature
#: statistics stay as they are from there on, while vergence keeps learning). Pursuit's policy
#: unlearns the views far from its optimum when it trains on (the study's "What drives the far
#: steps"); none of the plant changes the study measures touches the left eye, which pursuit alone
#: sees. 24,000 iterations, ten times the defaults'. A run continued past them (``train.resume=...
#: train.iterations=48000``) closes the stereo cue too, which then learns again only when its coding
#: reward falls 10 % below its level since closing (``reopen_drop``: a change of the plant) for
#: 2,400 iterations: vergence on photographs keeps its 24,000-iteration state instead of unlearning
#: it, and re-learns a roll or a vertical misalignment of the right eye.
LIFELONG: dict[str, Any] = {
    **{key: value for key, value in ROBUST_VERGENCE.items() if key != "train.iterations"},
    "env.pursuit_start_error_deg": 8.0,
    "learner.cues.parallax.learn_until": 2400,
    "learner.cues.stereo.learn_until": 24000,
    "learner.cues.stereo.reopen_drop": 0.1,
    "train.iterations": 24000,
}

#: The plasticity regimes a perturbation experiment chooses from (``plasticity=<name>``): name ->
#: dotted key -> value. ``decay``: today's (the dictionaries' rates decay as tau / (tau + t),
#: PPO's step is constant); ``floor``: the decaying rates fall no lower than half their start;
#: ``raise``: every event's start and end raises them back to their start, from where they decay
#: again.
PLASTICITY: dict[str, dict[str, Any]] = {
    "decay": {},
    "floor": {**{f"learner.cues.{cue}.encoder.floor": 0.5 for cue in default_cues()},
              **{f"learner.cues.{cue}.nac.actor_floor": 0.5 for cue in default_cues()}},
    "raise": {"plasticity.raise_to": 1.0},
}

#: What every rearing condition (``rearing=<name>``, ``normal`` included) sets besides its events:
#: dotted key -> value. A stereo code that can be reared: no swap symmetry (it forces the
#: binocularity histogram to be symmetric) and a constant dictionary rate of 16, 160x the
#: default's start (with the default decaying 0.1, the atoms end within a cosine of 0.996-0.999 of
#: their random start and no histogram moves; a strabismic code needs about 16 x 2,400 of rate
#: times iterations to turn monocular). A critical period: the rate closes linearly from iteration
#: 1,200 to 0 at 1,800 (half and three quarters of the suite's 2,400 iterations), so a world
#: changed before it reshapes the code and one changed after it meets the code it left. A world
#: of natural-image statistics, the dead-leaves textures (occluding discs, sharp edges): on the
#: default 1/f noise textures, which are Gaussian, no basis is better than another and a code
#: of two uncorrelated halves stays binocular. docs/sensory-coding.md, "Rearing", has the
#: measurements behind each. The evaluation reads the final state (no ``best.pt``: a window
#: chosen under the reared eyes is not what rearing left); the code is read out every 100
#: iterations (`experiments/rearing/report.py --curves`).
REARING_SETTINGS: dict[str, Any] = {
    "learner.cues.stereo.symmetry": None,
    "learner.cues.stereo.encoder.decay": None,
    "learner.cues.stereo.encoder.lr": 16.0,
    "learner.cues.stereo.encoder.close_at": 1200,
    "learner.cues.stereo.encoder.close_over": 600,
    "env.textures": "dead-leaves",
    "train.keep_best": False,
    "train.readout_every": 100,
}

#: The lineage's vergence range under strabismus (Klimmasch et al. 2021): 0 to 11.4 deg of
#: commanded vergence, so that the squinting eye cannot be turned back onto the object.
STRABISMUS_VERGENCE_RANGE_DEG = [0.0, 11.4]

#: The rearing conditions of the AEC lineage (Klimmasch et al. 2021, Eckmann et al. 2020), each a
#: list of perturbation events over the whole run (``rearing=<name>``, which also sets
#: :data:`REARING_SETTINGS` and the condition's :data:`REARING_CONDITION_SETTINGS`; the evaluation
#: afterwards sees with normal eyes): name -> events.
REARING: dict[str, list[dict[str, Any]]] = {
    "normal": [],
    "monocular": [{"kind": "monocular_deprivation", "start": 0, "eye": "right", "params": {"contrast": 0.0}}],
    "strabismus": [{"kind": "strabismus", "start": 0, "eye": "right", "params": {"deg": 10.0}}],
    "strabismus_3deg": [{"kind": "strabismus", "start": 0, "eye": "right", "params": {"deg": 3.0}}],
    "anisometropia_early": [{"kind": "anisometropia", "start": 0, "end": 0.25, "eye": "right",
                             "params": {"arcmin": 120.0}, "label": "right eye blurred, corrected early"}],
    "anisometropia_late": [{"kind": "anisometropia", "start": 0, "end": 0.75, "eye": "right",
                            "params": {"arcmin": 120.0}, "label": "right eye blurred, corrected late"}],
    # Refractive anisometropia: the right eye 2 D myopic, blurred through the world's
    # defocus (a 110 arcmin disc at the 16 mm aperture), never corrected or corrected early / late.
    "refractive": [{"kind": "refractive_error", "start": 0, "eye": "right", "params": {"dioptres": 2.0},
                    "label": "right eye 2 D myopic"}],
    "refractive_early": [{"kind": "refractive_error", "start": 0, "end": 0.25, "eye": "right",
                          "params": {"dioptres": 2.0}, "label": "right eye 2 D myopic, corrected early"}],
    "refractive_late": [{"kind": "refractive_error", "start": 0, "end": 0.75, "eye": "right",
                         "params": {"dioptres": 2.0}, "label": "right eye 2 D myopic, corrected late"}],
    "vertical": [{"kind": "orientation_rearing", "start": 0, "params": {"orientation": "vertical"}}],
    "horizontal": [{"kind": "orientation_rearing", "start": 0, "params": {"orientation": "horizontal"}}],
}

#: What a condition sets besides :data:`REARING_SETTINGS`: name -> dotted key -> value. Strabismus
#: as the lineage has it: the vergence range :data:`STRABISMUS_VERGENCE_RANGE_DEG`, which cannot
#: undo the squint (at 10 deg inward the eyes converge at least 10 deg while the objects at 1-3 m
#: need 1.15-3.44 deg: at least 6.6 deg of disparity, wider than a fine or full patch, 3.6 and
#: 1.8 deg; at 3 deg up to 1.9 deg, the objects nearer than 1.15 m reachable).
REARING_CONDITION_SETTINGS: dict[str, dict[str, Any]] = {
    "strabismus": {"env.vergence_range_deg": STRABISMUS_VERGENCE_RANGE_DEG},
    "strabismus_3deg": {"env.vergence_range_deg": STRABISMUS_VERGENCE_RANGE_DEG},
}


#: Every config group of ``train.py`` (`aectorch.runtime.store.register_configs` registers them):
#: group -> option -> the dotted keys it sets. A resume compares a group given on its command line
#: with the run's (`aectorch.runtime.checkpoint.check_resume_groups`).
GROUPS: dict[str, dict[str, dict[str, Any]]] = {
    "preset": {"default": {}, "paper": PAPER_PRESET},
    "experiment": {"roll_perturbation": ROLL_PERTURBATION, "accommodation": ACCOMMODATION, "slip": SLIP,
                   "robust_vergence": ROBUST_VERGENCE, "lifelong": LIFELONG},
    "plasticity": PLASTICITY,
    # "normal" adds no events: a run's own perturbations stay.
    "rearing": {name: {**REARING_SETTINGS, **REARING_CONDITION_SETTINGS.get(name, {}),
                       **({"perturbations": events} if events else {})} for name, events in REARING.items()},
}

#: Each group's option when the command line names none (``None``: the group is not applied).
GROUP_DEFAULTS: dict[str, str | None] = {"preset": "default", "experiment": None, "plasticity": "decay",
                                         "rearing": None}

#: The groups that ``train.py``'s defaults list does not name: added with ``+`` (``+experiment=slip``).
ADDED_GROUPS = ("experiment",)
