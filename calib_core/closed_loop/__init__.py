"""The closed loop: from a calibration's residual to the effect the model lacks.

A :class:`MachineModel` gives named base parameters, a context of covariates and residuals
(measured minus predicted) in which the effects of :mod:`calib_core.effects` enter through
the machine's channels. :func:`analyze`

1. holds out a fraction of the rows (stratified by the machine's strata) that no fit sees;
2. fits the base model on the rest;
3. refits every candidate effect jointly with the base model and the effects already
   added (effects correlate with geometric parameters, so they cannot be fitted to the
   residual alone), scores it with an extra-sum-of-squares F-test (Bonferroni-corrected
   for the number of candidates and, for searched periods, the number of periods tried)
   and with K-fold cross-validation, and adds the best candidate that is significant and
   lowers the cross-validated error; then repeats;
4. reports the held-out error of the base model and of the extended model, and tests the
   remaining residual against every covariate for structure no candidate explained.

Modules: ``model`` (MachineModel, LoopConfig), ``fitting``, ``identifiability``,
``trial`` (one candidate on one split), ``selection`` (:func:`analyze`), ``evidence``,
``channels``, ``linearised``, ``report`` (LoopResult, :func:`format_report`).
"""
from calib_core.closed_loop.fitting import evaluate, refit
from calib_core.closed_loop.model import LoopConfig, MachineModel, scalar_covariates, select_rows
from calib_core.closed_loop.report import LoopResult, format_report, why_not_in_force
from calib_core.closed_loop.selection import analyze

__all__ = ['LoopConfig', 'LoopResult', 'MachineModel', 'analyze', 'evaluate', 'format_report',
           'refit', 'scalar_covariates', 'select_rows', 'why_not_in_force']
