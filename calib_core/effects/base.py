"""What every effect is: :class:`Effect` (name, parameters, what it needs from the
context) prepared on the rows of a fit as :class:`Prepared` (the term and its Jacobian),
and the shapes most effects share (one parameter per channel, fixed parameter sets)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Prepared:
    """An effect set up for one dataset: its free parameters and how they enter.

    Attributes
    ----------
    effect : Effect
    names, units : tuple of str
        One per parameter (channel names are part of the parameter names).
    initial : ndarray (p,)
    term : callable (params (p,), context) -> ndarray (n, C)
    trials : float
        Independent alternatives searched while preparing (periods scanned), for the
        look-elsewhere correction of the significance test; 1 for effects with nothing
        searched.
    determined : callable (context) -> bool ndarray (p,), optional
        Which parameters the rows of ``context`` can determine. A fit on other rows than
        those prepared on (another hold-out split) holds the others at their given values
        instead of letting them drift along a direction the data do not constrain.
    channel_trials : dict
        Alternatives searched per channel (channel name -> count) where the search is per
        channel; ``trials`` is then their product. A channel not named here counts
        ``trials``, the conservative choice.
    separable : bool
        Whether each channel's term depends on that channel's parameters alone, so the
        effect can be decided channel by channel; False where channels share parameters
        (legs without their own play taking the mean of the others').
    """

    effect: 'Effect'
    names: tuple
    units: tuple
    initial: np.ndarray
    term: Callable
    trials: float = 1.0
    notes: dict = field(default_factory=dict)
    determined: Callable | None = None
    channel_trials: dict = field(default_factory=dict)
    separable: bool = True

    def trials_of(self, channel: str) -> float:
        """Alternatives searched for ``channel``'s terms (for its own significance)."""
        return float(self.channel_trials.get(channel, self.trials))

    def describe(self, values: np.ndarray, std_devs: np.ndarray) -> dict:
        """Parameters (SI) and their 1-sigma standard deviations, as a report entry."""
        out = {'name': self.effect.name, 'meaning': self.effect.meaning,
               'parameters': dict(zip(self.names, map(float, values))),
               'std_devs': dict(zip(self.names, map(float, std_devs))),
               'units': dict(zip(self.names, self.units))}
        out.update(self.notes)
        return out


class Effect:
    """A candidate effect. Subclasses set ``name``, ``meaning``, ``requires`` and
    implement :meth:`_prepare`."""

    name = ''
    meaning = ''
    requires: tuple = ()
    supersedes: tuple = ()   # effects this one includes and replaces when added
    # An effect that is a higher order of another (k3 of k1, k2) is tried only once that
    # one is in the model: alone it is no physical effect, and trying it costs a round.
    follows: str = ''

    def prepare(self, context: dict, channels: tuple, channel_residuals: np.ndarray):
        """A :class:`Prepared` for this data, or a string saying why the effect cannot be
        tested on it (a covariate in ``requires`` missing, or the data cannot show it)."""
        lacking = [k for k in self.requires if k not in context]
        if lacking:
            return f'needs covariate(s) {", ".join(lacking)}, which the data lack'
        return self._prepare(context, channels, channel_residuals)

    def _prepare(self, context: dict, channels: tuple, channel_residuals: np.ndarray):
        raise NotImplementedError


class FixedParameters(Effect):
    """An effect whose parameters (``parameters``, ``units``) do not depend on the data
    and start at zero; subclasses implement :meth:`term` and may refuse data in
    :meth:`unobservable`."""

    parameters: tuple = ()
    units: tuple = ()

    def unobservable(self, context: dict) -> str | None:
        return None

    def term(self, params: np.ndarray, context: dict) -> np.ndarray:
        raise NotImplementedError

    def _prepare(self, context, channels, channel_residuals):
        reason = self.unobservable(context)
        if reason:
            return reason
        return Prepared(self, self.parameters, self.units, np.zeros(len(self.parameters)),
                        self.term)


def varying(values: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """Which columns of ``values`` (n, C) take more than one value."""
    return np.ptp(values, axis=0) > tolerance


def both_signs(values: np.ndarray, needed: int = 5) -> np.ndarray:
    """Which columns of ``values`` (n, C) have ``needed`` rows of each sign: enough for a
    sign-dependent term to be told from an offset in every cross-validation fold."""
    return ((values > 0).sum(axis=0) >= needed) & ((values < 0).sum(axis=0) >= needed)


class PerChannel(Effect):
    """An effect linear in one parameter per channel: term[:, c] = p_c * basis[:, c]."""

    covariate = 'position'
    unit = 'm'
    suffix = ''

    def basis(self, context: dict, width: int) -> np.ndarray:
        """The term per unit parameter, shape (n, width)."""
        raise NotImplementedError

    def active(self, context: dict, width: int) -> np.ndarray:
        """Which channels the data can inform, shape (width,) bool."""
        return varying(self.basis(context, width))

    def inactive_reason(self) -> str:
        return f'{self.covariate} does not vary in any channel'

    def _prepare(self, context, channels, channel_residuals):
        width = len(channels)
        active = self.active(context, width)
        if not active.any():
            return self.inactive_reason()
        index = np.flatnonzero(active)

        def term(params, ctx, basis=self.basis, index=index, width=width):
            b = basis(ctx, width)
            out = np.zeros((len(b), width))
            out[:, index] = b[:, index] * params
            return out

        names = tuple(f'{self.suffix}_{channels[i]}' if self.suffix else channels[i]
                      for i in index)
        return Prepared(self, names, (self.unit,) * len(index), np.zeros(len(index)), term)


def bic(design: np.ndarray, r: np.ndarray) -> float:
    """Bayesian information criterion of the least-squares fit of ``r`` (n,) on
    ``design`` (n, p): n log(RSS / n) + p log n."""
    rss = float(np.sum((r - design @ np.linalg.lstsq(design, r, rcond=None)[0]) ** 2))
    return len(r) * np.log(max(rss, 1e-300) / len(r)) + design.shape[1] * np.log(len(r))
