"""Checkpoints of earlier formats, read as today's: one migration per format version, in one place.

A checkpoint's ``format`` is :data:`CHECKPOINT_FORMAT` when it was written by this version;
:func:`migrate` turns an older one into today's layout step by step (``MIGRATIONS[v]`` turns
format v into v + 1), so that every checkpoint written since the first release of ``train.py``
loads (``tests/runtime/test_migrations.py`` loads one stored checkpoint of every version that changed what
a checkpoint holds). Nothing else in the package knows an old layout.

Format 1 (commits 30ee905 to a9b2aa6): the learner's two cues were written out: the state dict named
the parts ``parallax.*``, ``pursuit.*`` (its agent), ``stereo.*``, ``vergence.*``, ``depth.*``,
and the config's ``learner`` section was flat (one ``control`` for both agents, ``symmetry`` a
list of cues). Fields that later versions of format 1 added are absent from older files: each
gets the value that reproduces what the file's version did (:data:`_ADDED_1`).

Format 2 (commits 62f2eb0 to 430fb6a): the cues are data: ``learner.cues.<cue>.*`` in the config and
``cues.<cue>.encoder.*`` / ``cues.<cue>.agent.*`` in the state dict; the metrics keep their
windows per eye movement.

Format 3 (this version): each cue's config has ``motor_cost``, ``readout`` and
``encoder.start``, and ``env`` has ``q_iterations``; a format 2 file gets the values that
reproduce what it did (:data:`_ADDED_2`: no motor cost, the argmax read-out, a random start, q
of the last iteration), whatever today's defaults are. Later versions of format 3 added to the
environment's state its perturbations' ``optics`` and ``first_optics``; a file
without them gets ``None``, which the environment reads as what it was: no perturbation but the
roll its ``roll_deg`` holds; and to each cue's config the rates' floors ``encoder.floor`` and
``nac.actor_floor``, ``None`` (no floor) where absent, and no critical period (``encoder.close_at``
``None``, ``close_over`` 0) (:data:`_ADDED_3`); and to ``env`` the
oculomotor range, where absent the eye pan limits alone (``pan_range_deg [-45, 45]``,
``vergence_range_deg [-90, 90]``), what such a run did. The config's new
sections (``perturbations``, ``plasticity``, ``train.recent_window``) get their defaults, which
change nothing for a run without events.
"""

from __future__ import annotations

import copy
from typing import Callable

import torch

__all__ = ["CHECKPOINT_FORMAT", "MIGRATIONS", "migrate"]

#: The format this version writes.
CHECKPOINT_FORMAT = 3

#: Format 1's two cues: name, its symmetry's kind, its old state-dict prefixes (encoder, agent),
#: the eye movement it drives and its key in the old per-cue extra state.
_CUES_1 = (("parallax", "mirror", "parallax.", "pursuit.", "pursuit", "m"),
           ("stereo", "swap", "stereo.", "vergence.", "vergence", "s"))

#: Fields that versions of format 1 added over time, with the value that reproduces what a file
#: written before the field existed did (section -> field -> value).
_ADDED_1 = {
    "env": {"shift_iterations": 1, "yoked_pursuit": False, "pursuit_start_spread_deg": 0.0,
            "vergence_start_spread_deg": 0.0},
    "learner": {"symmetry": [], "render_scales": False, "centred_patches": False, "dictionary_decay": None,
                "dictionary_decay_power": 1.0, "reward": "coding", "features": "pooled"},
    "control": {"normalize_window": None, "normalize_samples": None, "feature_norm": None, "batch_reference": None,
                "actor_decay": None, "actor_decay_power": 1.0},
    "train": {"keep_best": False, "metrics_window": 1000, "depth_calibration_trials": 0, "deterministic": False},
}


def _with_added(section: dict, added: dict) -> dict:
    return {**added, **section}


def _learner_config_1(old: dict) -> dict:
    """Format 1's flat ``learner`` section as format 2's, with one cue config per cue."""
    old = _with_added(old, _ADDED_1["learner"])
    control = _with_added(old.get("control") or {}, _ADDED_1["control"])
    encoder = {"num_atoms": old["num_atoms"], "sparsity": old["sparsity"], "algorithm": old["algorithm"],
               "pooling": old["pooling"], "lr": old["dictionary_lr"], "decay": old["dictionary_decay"],
               "decay_power": old["dictionary_decay_power"], "centred": old["centred_patches"]}
    cues = {name: {"agent": "nac", "actions_deg": list(old["actions_deg"]), "scales": list(old["scales"]),
                   "symmetry": kind if name in old["symmetry"] else None, "encoder": dict(encoder),
                   "nac": dict(control), "features": old["features"], "feature_scale": old["feature_scale"],
                   "reward": old["reward"]}
            for name, kind, *_ in _CUES_1}
    new = {"cues": cues, "active_cues": None, "render_scales": old["render_scales"],
           "skip_fixation_boundary": old["skip_fixation_boundary"]}
    new.update({k: v for k, v in old.items() if k.startswith("depth_")})
    return new


def _learner_state_1(state: dict, learner_config: dict) -> dict:
    """Format 1's learner state dict under format 2's names."""
    renames = [("depth.", "depth_learner.mlp."), ("depth_inputs", "depth_learner.inputs"),
               ("depth_targets", "depth_learner.targets"), ("depth_trained", "depth_learner.trained")]
    for name, _, encoder, agent, *_ in _CUES_1:
        renames += [(encoder, f"cues.{name}.encoder."), (agent, f"cues.{name}.agent.")]
    new = {}
    for key, value in state.items():
        if key == "_extra_state":
            continue
        for old, replacement in renames:
            if key.startswith(old):
                key = replacement + key[len(old):]
                break
        new[key] = value
    extra = state.get("_extra_state", {})
    previous = extra.get("previous", {})
    steps = extra.get("dictionary_steps", {})  # before it existed the rates were constant: any count
    for name, _, _, _, _, short in _CUES_1:
        new[f"cues.{name}._extra_state"] = {"previous": previous.get(short)}
        new[f"cues.{name}.encoder._extra_state"] = {"steps": int(steps.get(short, 0))}
        # Before the actor's step count existed the actor's step was constant: start it at 0.
        new.setdefault(f"cues.{name}.agent.step_count", torch.zeros((), dtype=torch.float64))
    new["_extra_state"] = {k: extra[k] for k in ("trials_seen", "trials_at_last_fit", "generator")}
    return new


def _metrics_state_1(state: dict, learner_config: dict) -> dict:
    scales = state.get("scales") or learner_config["cues"]["parallax"]["scales"]
    new = {k: v for k, v in state.items() if k not in ("pursuit", "vergence", "scales")}
    new["cues"] = {name: list(scales) for name, *_ in _CUES_1}
    new["errors"] = {movement: state[movement] for *_, movement, _ in _CUES_1}
    return new


def _from_1(payload: dict) -> dict:
    out = dict(payload)
    config = copy.deepcopy(payload["config"])
    for section in ("env", "train"):
        if isinstance(config.get(section), dict):
            config[section] = _with_added(config[section], _ADDED_1[section])
    config["learner"] = _learner_config_1(config["learner"])
    out["config"] = config
    for key in ("learner",):
        out[key] = _learner_state_1(payload[key], config["learner"])
    if "metrics" in payload:
        out["metrics"] = _metrics_state_1(payload["metrics"], config["learner"])
    out.setdefault("best", {"iteration": None, "score": None})
    out["format"] = 2
    return out


#: Fields of each cue (and of its encoder) that format 3 added, with format 2's behaviour.
_ADDED_2 = {"cue": {"motor_cost": 0.0, "readout": "argmax"}, "encoder": {"start": "random"},
            "env": {"q_iterations": 1}}


def _from_2(payload: dict) -> dict:
    out = dict(payload)
    config = copy.deepcopy(payload["config"])
    cues = (config.get("learner") or {}).get("cues") or {}
    for name, cue in cues.items():
        cue = _with_added(cue, _ADDED_2["cue"])
        cue["encoder"] = _with_added(cue.get("encoder") or {}, _ADDED_2["encoder"])
        cues[name] = cue
    if isinstance(config.get("env"), dict):
        config["env"] = _with_added(config["env"], _ADDED_2["env"])
    # The environment's running sum of q (zero between iterations with q of the last iteration).
    states = payload.get("env")
    for state in states if isinstance(states, list) else [states]:
        if isinstance(state, dict) and isinstance(state.get("q_deg"), torch.Tensor) and "q_sum_deg" not in state:
            state["q_sum_deg"] = torch.zeros(state["q_deg"].shape[0], 2, dtype=state["q_deg"].dtype)
    out["config"] = config
    out["format"] = 3
    return out


#: Fields that versions of format 3 added, with what a file without them did: the environment's
#: optics (``None``: the roll of ``roll_deg`` and nothing else), the cues' reconstruction efficiency
#: and no proprioception (``efficiency``, ``proprioception``), a reward of all their scales (``reward_scales``
#: empty), learning for the whole run (``learn_until``) and a closed cue never reopening (``reopen_drop``), their rates without a floor (``encoder.floor``, ``nac.actor_floor``) and without a critical period
#: (``encoder.close_at``, ``close_over``), every patch alike (``encoder.fovea_px``), and the oculomotor range of
#: the config's ``env`` (``pan_range_deg``, ``vergence_range_deg``): the eye pan limits alone, no vergence
#: range but theirs.
_ADDED_3 = {"env": {"optics": None, "first_optics": None}, "cue": {"efficiency": "reconstruction", "proprioception": [], "reward_scales": [],
                                                               "learn_until": None, "reopen_drop": None,
                                                               "reopen_window": 200, "reopen_for": 2400},
            "encoder": {"floor": None, "close_at": None, "close_over": 0, "fovea_px": None}, "nac": {"actor_floor": None},
            "config_env": {"pan_range_deg": [-45.0, 45.0], "vergence_range_deg": [-90.0, 90.0]}}


def _complete_3(payload: dict) -> dict:
    """A format 3 payload with the fields later versions of format 3 added (in place: the payload
    is the caller's own, just read)."""
    states = payload.get("env")
    for state in states if isinstance(states, list) else [states]:
        if isinstance(state, dict) and "pan_deg" in state:
            for key, value in _ADDED_3["env"].items():
                state.setdefault(key, value)
    config = payload.get("config")
    if isinstance(config, dict) and isinstance(config.get("env"), dict):
        for key, value in _ADDED_3["config_env"].items():
            config["env"].setdefault(key, list(value))
    cues = ((config.get("learner") or {}).get("cues") or {}) if isinstance(config, dict) else {}
    for cue in cues.values():
        if isinstance(cue, dict):
            for key, value in _ADDED_3["cue"].items():
                cue.setdefault(key, copy.copy(value))
        for section in ("encoder", "nac"):
            if isinstance(cue, dict) and isinstance(cue.get(section), dict):
                for key, value in _ADDED_3[section].items():
                    cue[section].setdefault(key, value)
    return payload


#: ``MIGRATIONS[v]`` turns a payload of format v into one of format v + 1.
MIGRATIONS: dict[int, Callable[[dict], dict]] = {1: _from_1, 2: _from_2}


def migrate(payload: dict) -> dict:
    """``payload`` (a checkpoint's dict) in today's format (:data:`CHECKPOINT_FORMAT`); a new dict
    when it was older, the same one when it is current. ``ValueError`` for a format this version
    does not know (a newer aectorch's, or none)."""
    version = payload.get("format") if isinstance(payload, dict) else None
    if not isinstance(version, int) or not 1 <= version <= CHECKPOINT_FORMAT:
        raise ValueError(f"format {version!r} is not one this aectorch reads (1 to {CHECKPOINT_FORMAT})")
    while version < CHECKPOINT_FORMAT:
        payload = MIGRATIONS[version](payload)
        version = payload["format"]
    return _complete_3(payload)
