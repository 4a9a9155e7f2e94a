"""Effects the uncertainty of an instrument's own calibration could give.

Some machines' rows are not measured directly but through a calibrated instrument: the
rotary table's poses come from a camera calibrated moments before, whose parameters are
known only to their covariance. An error of that calibration moves every row together,
in a pattern an effect of the machine may mimic (a camera's focal length off by its
sigma turns the board's measured tilts by a share of the tilt: a scale of the tilting
axis). The rows' own noise does not hold it, so the loop's tests do not either.

A machine that measures through such an instrument gives :meth:`MachineModel.
input_variants`: its data as measured through each one-sigma variant of the instrument's
calibration (one per column of a square root of its covariance). Each effect the loop
would add is fitted again, with the same base and effects, on every variant; how far its
parameters move is the calibration's share of their covariance. An effect whose
parameters stand out from the data's noise but not from the data's noise and the
calibration's together is not added: the data cannot tell it from the instrument's own
uncertainty (reported among ``rejected`` with both figures, never dropped).
"""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop.fitting import Fit, fit_model, model_residuals


def calibration_shares(machine, variants: list, final: Fit, rows) -> tuple[Fit, np.ndarray]:
    """``final``'s base and effects fitted on ``rows`` of ``machine``, and how far that fit's
    effect parameters move on each of the ``variants`` (the same machine measured through
    each one-sigma variant of an instrument's calibration; they change the residuals, not
    the model), to first order about the fit: the shifts (n_effect_parameters,
    n_variants), whose outer product is the calibration's share of their covariance."""
    reference = fit_model(machine, machine.initial(), final.effects, final.values, rows)
    at = (reference.base, reference.effects, reference.values, rows)
    r0 = model_residuals(machine, *at).ravel()
    # The fit's step for a change of the residuals at fixed parameters: -J^+ dr.
    solve = np.linalg.pinv(reference.jacobian)
    start = len(reference.base.free_names)
    shifts = [-(solve @ (model_residuals(variant, *at).ravel() - r0))[start:]
              for variant in variants]
    return reference, np.array(shifts).T


def within_calibration(machine, variants: list, final: Fit, rows,
                       alpha: float) -> tuple[dict, dict]:
    """The effects of ``final`` that stand out from the data's noise (chi-square of their
    parameters beyond the ``alpha`` quantile) but not once the instrument's calibration's
    share (:func:`calibration_shares`) is added to their covariance: name -> the reason,
    with both figures and each parameter's two standard deviations; and for every effect
    its parameters' standard deviations from the calibration alone (name -> parameter ->
    sigma, in the parameter's unit)."""
    from scipy.stats import chi2
    reference, shifts = calibration_shares(machine, variants, final, rows)
    data = reference.covariance()
    found, shares, offset = {}, {}, 0
    for k, (prepared, value) in enumerate(zip(reference.effects, reference.values)):
        value = np.ravel(value)
        block = reference.effect_slice(k)
        own = data[block, block]
        moved = shifts[offset:offset + len(value)]
        offset += len(value)
        share = moved @ moved.T
        shares[prepared.effect.name] = {name: float(np.sqrt(share[j, j]))
                                        for j, name in enumerate(prepared.names)}
        limit = float(chi2.ppf(1 - alpha, len(value)))
        alone = float(value @ np.linalg.pinv(own) @ value)
        together = float(value @ np.linalg.pinv(own + share) @ value)
        if alone > limit >= together:
            figures = '; '.join(
                f'{name} = {v:.3g} {unit} +- {np.sqrt(max(own[j, j], 0.0)):.2g} from the '
                f'data\'s noise, +- {np.sqrt(share[j, j]):.2g} from the calibration\'s'
                for j, (name, unit, v) in enumerate(zip(prepared.names, prepared.units, value))
                if j < 4)
            found[prepared.effect.name] = (
                f'it stands out from the data\'s noise (chi-square {alone:.3g} on '
                f'{len(value)}, limit {limit:.3g} at p = {alpha:g}) but not from the data\'s '
                f'noise and the uncertainty of the calibration the data were measured '
                f'through together ({together:.3g}): the data cannot tell it from that '
                f'calibration\'s own error ({figures})')
    return found, shares
