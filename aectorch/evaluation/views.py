"""What a trial's eyes see at its start: the texture statistics that explain a trial's outcome.

A view of little texture (a flat background, a blurred region) gives the coder nothing to
measure: every patch reaches it at unit norm, so its reward is flat there and what the policy
does is arbitrary. :func:`view_statistics` measures, for each trial, how much there was to see
when it started: the RMS contrast of the rendered window and the energy at each of the coder's
scales (`aectorch.coding.patch_energy`); `run_trials` puts them in its output and the per-trial
rows (``view_*``).
"""

from __future__ import annotations

from torch import Tensor

from aectorch.coding.patches import SCALE_NAMES, WINDOW, as_scale, patch_energy

__all__ = ["VIEW_PREFIX", "view_statistics"]

#: The key prefix of the view's statistics in `run_trials`' output and the per-trial rows.
VIEW_PREFIX = "view_"


def view_statistics(env, scales=SCALE_NAMES) -> dict[str, Tensor]:
    """The texture statistics of the stereo pair ``env`` shows now (both eyes), per environment.

    Renders the pair once (`ActiveDepthEnv.stereo_observation`, the window and each scale at its
    resolution, as the coder reads them); moves nothing and draws nothing at random.

    Args:
        env: an `aectorch.sim.ActiveDepthEnv`.
        scales: the coder's scales to measure (names or `aectorch.coding.Scale`; default all four).

    Returns:
        ``view_contrast`` ``[B]``: the RMS contrast of the window (standard deviation over mean
        intensity, both eyes' pixels together; 0 for a flat view); ``view_energy_<scale>`` ``[B]``
        for each scale: `aectorch.coding.patch_energy` of the pair at that scale (intensity^2).
    """
    scales = [as_scale(s) for s in scales]
    pair = env.stereo_observation(scales, window=True)
    window = pair[WINDOW].flatten(1)
    mean = window.mean(dim=1)
    contrast = window.std(dim=1, correction=0) / mean.clamp_min(1e-12)
    out = {f"{VIEW_PREFIX}contrast": contrast}
    out.update({f"{VIEW_PREFIX}energy_{s.name}": patch_energy(pair[s.name], s) for s in scales})
    return out
