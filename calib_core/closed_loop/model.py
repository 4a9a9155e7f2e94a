"""What the closed loop needs from a machine (:class:`MachineModel`: base parameters,
channels, covariates, residuals) and how it runs (:class:`LoopConfig`)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calib_core.effects import CATEGORICAL_COVARIATES, Effect, Prepared
from calib_core.errors import InvalidInputError
from calib_core.parameters import ParameterSet


class MachineModel:
    """What the loop needs from a machine. Rows are observations (an axis target, a pose,
    an image point); ``rows`` arguments are integer index arrays into them.

    Subclasses set ``name``, ``base_model`` (a sentence), ``unit`` (of the residuals),
    ``channels`` (names of the quantities effects act on), ``candidates`` (effect names)
    and implement ``__len__``, :meth:`initial`, :meth:`context` and :meth:`residuals`.
    """

    name = ''
    base_model = ''
    unit = 'm'
    channels: tuple = ()
    channel_units: tuple = ()   # per channel when not every one is in m (rad: rotary axis)
    effect_channels: dict = {}  # candidate name -> the channels it may act on (default all)
    # Channels whose view of a residual is found together (least squares per row); each
    # block explains the whole residual on its own. One block of every channel unless a
    # machine has more channels than a row has residuals (a target's turn beside its axes').
    channel_blocks: tuple = ()
    candidates: tuple = ()
    min_effect = 50e-9   # smallest effect worth adding, RMS in the residuals' unit
    # Fit the loop's models to first order about the base solution (see
    # calib_core.closed_loop.linearised): for machines whose prediction is costly.
    linearise = False

    def __len__(self) -> int:
        raise NotImplementedError

    def initial(self) -> ParameterSet:
        """Starting values of the base parameters (free ones are fitted)."""
        raise NotImplementedError

    def context(self, base: ParameterSet, rows: np.ndarray) -> dict:
        """Covariates of ``rows`` (see :mod:`calib_core.effects`); may depend on ``base``."""
        raise NotImplementedError

    def residuals(self, base: ParameterSet, delta: np.ndarray, rows: np.ndarray,
                  context: dict) -> np.ndarray:
        """Measured minus predicted, shape (n, k), with effect terms ``delta`` (n, C) added
        to the channels; ``context`` is :meth:`context` of the same base and rows, which
        the loop has computed already."""
        raise NotImplementedError

    def input_variants(self) -> list | None:
        """This machine's data as measured through each one-sigma variant of the
        instrument's calibration they were measured through (one per column of a square
        root of its covariance), for the effects to be checked against what that
        calibration's uncertainty gives (:mod:`calib_core.closed_loop.inputs`); None where
        the rows carry no error but their own."""
        return None

    def base_sparsity(self, base: ParameterSet, rows: np.ndarray) -> np.ndarray | None:
        """Which residuals (n k, row-major) each free base parameter can change, bool
        (n k, P), or None when any may change any. A camera's view pose moves only its
        view's points: finite differences then step many parameters at once."""
        return None

    def channel_residuals(self, base: ParameterSet, delta: np.ndarray, rows: np.ndarray,
                          context: dict) -> np.ndarray:
        """Residuals expressed in the channels (what ``delta`` lacks), shape (n, C)."""
        return self.residuals(base, delta, rows, context)

    def channel_scale(self, base: ParameterSet) -> np.ndarray | None:
        """Per channel, the residuals' unit per the channel's (C,), where the channels are
        in another unit than the residuals (a camera's normalised image coordinates against
        its pixels); None where they are the same. What is found in the channels (the
        structure tests' sizes) is reported in the residuals' unit through it."""
        return None

    def to_channels(self, jacobian: np.ndarray) -> np.ndarray:
        """The map (n, C, k) from a row's residual to the channel shifts that best explain
        it, from the residuals' channel Jacobian ``jacobian`` (n, k, C): least squares per
        row within each of :attr:`channel_blocks`."""
        out = np.zeros(jacobian.shape[:1] + jacobian.shape[2:] + jacobian.shape[1:2])
        for block in self.channel_blocks or (self.channels,):
            index = [self.channels.index(c) for c in block]
            out[:, index] = -np.linalg.pinv(jacobian[:, :, index])
        return out

    def strata(self) -> np.ndarray:
        """Label per row; hold-out and folds sample every label (e.g. camera views)."""
        return np.zeros(len(self), dtype=int)

    # What a stratum is to the user ('view'), where the strata are things a user can check
    # or leave out; '' where they are not (one stratum). Outliers are then counted per
    # stratum, and a stratum that most of its rows disagree with is named.
    stratum_name = ''

    def stratum_label(self, stratum: int) -> str:
        """The user's name of ``stratum`` (a value of :meth:`strata`): its id in the data."""
        return str(stratum)

    def replicates(self) -> np.ndarray | None:
        """A label per row that repeated measurements of one setting share (an ISO 230-2
        target approached from one direction), or None. With replicates, the loop's
        F-tests take the noise from the scatter within them (pure error), which structure
        not yet modelled does not inflate."""
        return None

    def row_errors(self, residuals: np.ndarray) -> np.ndarray:
        """Error magnitudes in which to report max and RMS: the norm per row."""
        return np.linalg.norm(residuals, axis=1)

    def workspace(self) -> np.ndarray | None:
        """2-D position of each row for a residual vector plot, (N, 2), or None."""
        return None


def prepare_effect(effect: Effect, machine: MachineModel, context: dict,
                   channel_residuals: np.ndarray, channels: tuple | None = None):
    """``effect`` prepared on the channels the machine lets it act on (its
    ``effect_channels``, else every channel) or on ``channels`` when given (those the data
    determine it on), its term widened back to every channel and its units in the
    channels' own; or why it cannot be tested."""
    allowed = channels or machine.effect_channels.get(effect.name)
    if not allowed:
        prepared = effect.prepare(context, machine.channels, channel_residuals)
        return prepared if isinstance(prepared, str) else in_channel_units(prepared, machine)
    index = [machine.channels.index(c) for c in allowed]
    width = len(machine.channels)

    def narrow(ctx):
        return {k: v[:, index] if np.ndim(v) == 2 and np.shape(v)[1] == width else v
                for k, v in ctx.items()}
    prepared = effect.prepare(narrow(context), tuple(allowed), channel_residuals[:, index])
    if isinstance(prepared, str):
        return prepared

    def term(params, ctx, inner=prepared.term):
        part = inner(params, narrow(ctx))
        out = np.zeros((len(part), width))
        out[:, index] = part
        return out
    determined = prepared.determined and (lambda ctx, inner=prepared.determined: inner(narrow(ctx)))
    return in_channel_units(replace(prepared, term=term, determined=determined), machine)


def in_channel_units(prepared: Prepared, machine: MachineModel) -> Prepared:
    """``prepared`` with the length unit of each parameter named after a channel
    (``rate_c``, ``backlash_a``) replaced by that channel's own unit: an effect's term is in
    its channel's unit, rad for a rotary axis (m/s becomes rad/s)."""
    if not machine.channel_units:
        return prepared
    own = dict(zip(machine.channels, machine.channel_units))
    units = []
    for name, unit in zip(prepared.names, prepared.units):
        channel = next((c for c in machine.channels if name.endswith(f'_{c}')), None)
        if channel and own[channel] != 'm' and (unit == 'm' or unit.startswith('m/')):
            unit = own[channel] + unit[1:]
        units.append(unit)
    return replace(prepared, units=tuple(units))


SCALAR_COVARIATES = ('time', 'temperature', 'sequence') + CATEGORICAL_COVARIATES


def is_reference(key: str) -> bool:
    """Context entries that are one value for the whole dataset, not a column."""
    return key.endswith(('_ref', '_start'))


def covariate_columns(machine, context: dict) -> dict:
    """A context flattened into named scalar covariates per row (``position_leg2``)."""
    out = {}
    for key, value in context.items():
        if is_reference(key) or isinstance(value, dict):
            continue
        value = np.asarray(value, float)
        if value.ndim > 2:      # a per-row matrix (a rotor's housing frame), not a covariate
            continue
        if value.ndim == 1:
            out[key] = value
        elif key == 'normalized':
            out['image_radius'] = np.linalg.norm(value, axis=1)
        elif key == 'map_position':        # the machine's XY, whatever its channels
            out['map_x'], out['map_y'] = value[:, 0], value[:, 1]
        else:
            for c, name in enumerate(machine.channels):
                out[f'{key}_{name}'] = value[:, c]
    return out


def scalar_covariates(covariates: dict) -> dict:
    """The per-row covariates of a dataset the effects use: time (s), temperature (K),
    sequence (approach number, 0 first) and the categorical columns (block, setup, run,
    cycle), with the reference values the effects need: the means of time, temperature and
    sequence (``time_ref``, ``temperature_ref``, ``sequence_ref``) and the starts of time
    and sequence
    (``time_start``, ``sequence_start``), all over every row of the dataset."""
    out = {k: np.asarray(covariates[k], float) for k in SCALAR_COVARIATES if k in covariates}
    references = {f'{k}_ref': float(np.mean(out[k])) for k in ('time', 'temperature', 'sequence')
                  if k in out}
    references.update({f'{k}_start': float(np.min(out[k])) for k in ('time', 'sequence')
                       if k in out})
    out.update(references)
    return out


def select_rows(covariates: dict, rows: np.ndarray) -> dict:
    """``covariates`` from :func:`scalar_covariates` restricted to ``rows``."""
    return {k: v if is_reference(k) else v[rows] for k, v in covariates.items()}


@dataclass(frozen=True)
class LoopConfig:
    """Settings of :func:`analyze`.

    Attributes
    ----------
    holdout_fraction : float
        Rows kept out of every fit, to report before/after on.
    folds : int
        Cross-validation folds within the fitting rows.
    alpha : float
        Family-wise significance level per round (Bonferroni over the candidates tried).
    max_effects : int
        Stop after adding this many effects.
    seed : int
        Of the first random hold-out and fold assignment; split k uses ``seed + k``.
    splits : int
        Hold-out splits the selection is repeated over.
    min_frequency : float
        An effect is added only if the selection chose it in at least this share of the
        splits.
    min_effect : float or None
        Smallest effect worth adding, as the RMS of the structure it explains, in the
        residuals' unit (m or px); None takes the machine's ``min_effect``.
    linearise : bool
        Fit a machine that asks for it (``MachineModel.linearise``) to first order about
        its base solution; False fits the full model every time (minutes on the stage).
    """

    holdout_fraction: float = 0.3
    folds: int = 5
    alpha: float = 1e-3
    max_effects: int = 4
    seed: int = 0
    splits: int = 5
    min_frequency: float = 0.6
    min_effect: float | None = None
    linearise: bool = True

    def __post_init__(self):
        if not 0.05 <= self.holdout_fraction <= 0.6:
            raise InvalidInputError('holdout_fraction must be in [0.05, 0.6]')
        if self.folds < 2:
            raise InvalidInputError('folds must be at least 2')
        if not 0 < self.alpha < 0.5:
            raise InvalidInputError('alpha must be in (0, 0.5)')
        if self.max_effects < 0:
            raise InvalidInputError('max_effects must be >= 0')
        if self.splits < 1:
            raise InvalidInputError('splits must be at least 1')
        if not 0 < self.min_frequency <= 1:
            raise InvalidInputError('min_frequency must be in (0, 1]')
        if self.min_effect is not None and not (np.isfinite(self.min_effect)
                                                and self.min_effect >= 0):
            raise InvalidInputError('min_effect must be a finite number >= 0')
