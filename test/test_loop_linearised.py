"""The closed loop's first-order model of a costly machine (calib_core.closed_loop.
linearised): it must reproduce the machine's own residuals, channel residuals and Jacobian
near the base solution, and the loop on it must decide and fit as the full model does."""
import dataclasses

import numpy as np
import pytest

from calib_core.closed_loop import LoopConfig, analyze
from calib_core.closed_loop.fitting import fit_model
from calib_core.closed_loop.linearised import LinearisedModel
from calib_core.effects import LIBRARY
from platform_calib.core.geometry import nominal_geometry
from platform_calib.core.loop_model import PlatformLoopModel
from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
from printer_alignment.core.loop_models import StageLoopModel
from printer_alignment.sim.stage import TRUE_STAGE, simulate_calibration_run

NOMINAL = nominal_geometry()


@pytest.fixture(scope='module')
def stage():
    machine = StageLoopModel(simulate_calibration_run(TRUE_STAGE, seed=5))
    every = np.arange(len(machine))
    base = fit_model(machine, machine.initial(), [], [], every).base
    return machine, LinearisedModel(machine, base), base


def _platform(**errors):
    sim = PlatformSim(true_geometry(1, 0.15), 1, lead=5e-3, **errors)
    return PlatformLoopModel(measure_poses(sim, plan_poses(80, 1), NOMINAL), NOMINAL)


def test_residuals_agree_to_second_order(stage):
    machine, linear, base = stage
    rows = np.arange(len(machine))
    rng = np.random.default_rng(0)
    x = base.free_vector()
    # a base shift of the size subsets of the rows move it by, and chain inputs of 5 um
    moved = base.with_free_vector(x + 1e-5 * np.maximum(1, np.abs(x)) * rng.normal(size=len(x)))
    delta = rng.normal(0, 5e-6, (len(rows), 3))
    exact = machine.residuals(moved, delta, rows, machine.context(moved, rows))
    approx = linear.residuals(moved, delta, rows, linear.context(moved, rows))
    change = exact - machine.residuals(base, 0 * delta, rows, machine.context(base, rows))
    assert np.max(np.abs(change)) > 1e-6          # the shift matters ...
    assert np.max(np.abs(approx - exact)) < 1e-3 * np.max(np.abs(change))   # ... and is linear


def test_channel_residuals_are_the_machines_own(stage):
    machine, linear, base = stage
    rows = np.arange(0, len(machine), 3)
    delta = np.zeros((len(rows), 3))
    own = machine.channel_residuals(base, delta, rows, machine.context(base, rows))
    assert linear.channel_residuals(base, delta, rows, linear.context(base, rows)) \
        == pytest.approx(own, abs=1e-3 * np.max(np.abs(own)))


def test_jacobian_of_an_effect_matches_finite_differences(stage):
    machine, linear, base = stage
    rows = np.arange(len(machine))
    context = linear.context(base, rows)
    effect = LIBRARY['reversal']
    prepared = effect.prepare(context, machine.channels, np.zeros((len(rows), 3)))
    values = np.array([3e-6, -2e-6, 1e-6])[:len(prepared.names)]
    jacobian = linear.jacobian([prepared], [values], rows, context)
    assert jacobian.shape == (rows.size * 4, len(base.free_names) + len(values))
    for j in range(len(values)):
        step = np.zeros(len(values))
        step[j] = 1e-7
        plus = machine.residuals(base, prepared.term(values + step, context), rows,
                                 machine.context(base, rows))
        minus = machine.residuals(base, prepared.term(values - step, context), rows,
                                  machine.context(base, rows))
        column = ((plus - minus) / 2e-7).ravel()
        assert jacobian[:, len(base.free_names) + j] == pytest.approx(column, abs=1e-4)


@pytest.mark.parametrize('errors', [{'backlash': (8e-6,) * 3}, {}])
def test_loop_decides_as_the_full_model(errors):
    """Platform, 80 poses, true backlash 8 um per feed or none: the same effects, their
    values within a tenth of their sigma and the held-out RMS pooled over the splits within
    0.5 % of the full model's fits (each split refits the base linearised about the
    all-rows solution: second-order terms of 0.1-0.3 % on a split's rows)."""
    linear = analyze(_platform(**errors), LoopConfig(linearise=True)).report
    exact = analyze(_platform(**errors), LoopConfig(linearise=False)).report
    assert [e['name'] for e in linear['effects_added']] == \
        [e['name'] for e in exact['effects_added']] == (['reversal'] if errors else [])
    for a, b in zip(linear['effects_added'], exact['effects_added']):
        for name, value in b['parameters'].items():
            assert abs(a['parameters'][name] - value) < 0.1 * b['std_devs'][name]
    for key in ('rms_before', 'rms_after'):
        assert linear[key] == pytest.approx(exact[key], rel=5e-3)


def test_machines_that_are_cheap_are_not_linearised():
    """The loop's full fits stay where they cost little; the four machines whose
    prediction is a solve or a chain of poses ask for the first-order model."""
    from calib_core.axis import AxisModel
    from dispenser_calib.core.loop_model import RotaryLoopModel
    from hexapod_calib.core.loop_models import HexapodLoopModel
    from printer_alignment.core.loop_models import CameraLoopModel, GantryLoopModel
    assert not any(m.linearise for m in (AxisModel, GantryLoopModel, CameraLoopModel))
    assert all(m.linearise for m in (StageLoopModel, RotaryLoopModel, HexapodLoopModel,
                                     PlatformLoopModel))
    assert dataclasses.replace(LoopConfig(), linearise=False).linearise is False
