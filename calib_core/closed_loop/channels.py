"""Decisions per channel: on which of its channels (feeds, chains, legs, axes) the data
determine a candidate effect.

An effect fitted on every channel at once pays for the channels where it is absent: on a
clean feed a periodic term fits noise at whatever period the periodogram peaks, its
parameters dilute the candidate's F-test, and they would be reported as part of the
effect. So after the joint fit, each channel's block of the effect's parameters gets a
Wald test (the joint fit's covariance, the F-test's noise), corrected for what was
searched on that channel (periods, degrees) and over the channels; the effect is then
refitted on the channels that pass and scored there, and the others are reported as
undetermined with their p-values.
"""
from __future__ import annotations

import numpy as np
from scipy import special


def channel_groups(prepared, channels: tuple) -> dict | None:
    """Channel -> indices of ``prepared``'s parameters acting on it, or None when some
    parameter belongs to no single channel (a squareness, a lens distortion) or channels
    share parameters (``prepared.separable`` false).

    A channel's parameters end in ``_<channel>``; a period (``period_<channel>``) is left
    out, since a zero amplitude, not a period, is what says the term is absent.
    """
    if not prepared.separable:
        return None
    groups = {}
    for i, name in enumerate(prepared.names):
        channel = next((c for c in channels if name.endswith(f'_{c}')), None)
        if channel is None:
            return None
        if not name.startswith('period_'):
            groups.setdefault(channel, []).append(i)
    return groups


def channel_p_values(prepared, groups: dict | None, values: np.ndarray,
                     covariance: np.ndarray, dof: int) -> dict | None:
    """Per channel of ``prepared`` (its :func:`channel_groups`), the p-value of its term
    being zero.

    Wald statistic of the channel's parameters with ``covariance`` (the effect's block of
    the joint fit's, at the F-test's noise), as an F with ``dof`` residual degrees of
    freedom, times the alternatives searched on that channel and the number of channels
    the effect was fitted on (Bonferroni). None when the effect's parameters are not per
    channel (or channels share them) or it acts on one channel only.
    """
    if not groups or len(groups) < 2:
        return None
    out = {}
    for channel, index in groups.items():
        theta = np.asarray(values, float)[index]
        block = covariance[np.ix_(index, index)]
        wald = float(theta @ np.linalg.pinv(block) @ theta)
        q = len(index)
        p = float(special.fdtrc(q, max(dof, 1), wald / q))
        out[channel] = min(1.0, p * prepared.trials_of(channel) * len(groups))
    return out


def determined_channels(p_values: dict | None, alpha: float):
    """(kept, undetermined) channels from :func:`channel_p_values`, or None when the
    effect should stay on every channel it was fitted on: its terms are not per channel,
    every channel passes, or none does on its own (an effect spread thinly over every
    channel is then judged as a whole)."""
    if not p_values:
        return None
    kept = tuple(c for c, p in p_values.items() if p < alpha)
    if not kept or len(kept) == len(p_values):
        return None
    return kept, {c: p for c, p in p_values.items() if c not in kept}
