"""What the loop's figure draws is what its report says (issue 52): an effect drawn on the
channels the report names it on, each against its own channel's covariate."""
from types import SimpleNamespace

import numpy as np

from calib_core.loop_plots import effect_panels


def test_a_legs_play_is_drawn_against_its_own_load_and_only_where_it_was_found():
    """Play named on legs 2 and 5; leg 4 carries the mean play (not a finding) with a
    larger term; leg 1's load is as smooth a covariate for leg 2's term as its own (the
    loads move together): the panels are legs 2 and 5 against load_leg2 and load_leg5."""
    rng = np.random.default_rng(1)
    channels = tuple(f'leg{k}' for k in range(1, 7))
    base = rng.uniform(-200, 200, 120)
    loads = {f'load_{c}': base * (1 + 0.01 * k) for k, c in enumerate(channels)}
    term = np.zeros((120, 6))
    for k, play in ((1, 4e-6), (4, 5e-6), (3, 6e-6)):
        term[:, k] = -play / 2 * np.sign(loads[f'load_{channels[k]}'])
    machine = SimpleNamespace(channels=channels)
    result = SimpleNamespace(
        effect_terms={'leg_play': term}, covariates=dict(loads, time=np.arange(120.0)),
        report={'effects_added': [{'name': 'leg_play', 'parameters': {
            'play_leg2': 4e-6, 'play_leg5': 5e-6, 'closing_force': 5.0}}]})
    panels = effect_panels(machine, result)
    assert sorted(panels) == [('leg_play', 1, 'load_leg2'), ('leg_play', 4, 'load_leg5')]


def test_a_squareness_is_drawn_against_the_other_axis_and_a_period_folded():
    """The gantry's squareness moves x with y: its panel is against position_y, where it is
    a line, not against position_x, where a line through it zigzags. A 16 mm screw error
    sampled every 5.5 mm is drawn against the position modulo 16 mm: one period."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from calib_core.loop_plots import _draw_effect
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 0.2, 80), rng.uniform(0, 0.15, 80)
    period = 0.016
    squareness = np.column_stack([40e-6 * y, np.zeros(80)])
    screw = np.column_stack([np.zeros(80), 2e-6 * np.sin(2 * np.pi * y / period)])
    machine = SimpleNamespace(channels=('x', 'y'), channel_units=('m', 'm'), unit='m')
    result = SimpleNamespace(
        effect_terms={'squareness': squareness, 'periodic': screw},
        covariates={'position_x': x, 'position_y': y},
        channel_after=rng.normal(0, 0.1e-6, (80, 2)),
        report={'effects_added': [{'name': 'squareness', 'parameters': {'gamma': 40e-6}},
                                  {'name': 'periodic', 'parameters': {
                                      'amplitude_y': 2e-6, 'period_y': period}}]})
    panels = effect_panels(machine, result)
    assert ('squareness', 0, 'position_y') in panels
    assert ('periodic', 1, 'position_y') in panels
    figure, ax = plt.subplots()
    _draw_effect(ax, machine, result, 'periodic', 1, 'position_y')
    folded = np.concatenate([line.get_xdata() for line in ax.get_lines()])
    assert folded.max() < period * 1e3 and folded.min() >= 0      # mm, within one period
    assert 'modulo the fitted period 16 (mm)' in ax.get_xlabel()
    plt.close(figure)
