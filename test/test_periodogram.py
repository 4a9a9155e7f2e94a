"""The generalised Lomb-Scargle periodogram (calib_core.periodogram) against the fit it
stands for (at every frequency, the sum of squares a sinusoid plus a mean explains, found
by least squares on unevenly spaced samples) and against scipy's, whose computation it
repeats."""
import numpy as np
import pytest

from calib_core.periodogram import explained_power

TRUE_PERIOD = 3.2e-3      # m
AMPLITUDE = 1e-6          # m
NOISE = 3e-7              # m


def _samples(seed: int, count: int = 130):
    rng = np.random.default_rng(seed)
    x = np.sort(rng.uniform(0.0, 0.02, count))
    y = (AMPLITUDE * np.sin(2 * np.pi * x / TRUE_PERIOD + 0.4) + 5e-6
         + rng.normal(0.0, NOISE, count))
    return x, y


def _explained_by_fit(x, y, frequency: float) -> float:
    design = np.column_stack([np.ones_like(x), np.cos(2 * np.pi * frequency * x),
                              np.sin(2 * np.pi * frequency * x)])
    residual = y - design @ np.linalg.lstsq(design, y, rcond=None)[0]
    return float(np.sum((y - y.mean()) ** 2) - np.sum(residual ** 2))


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_power_is_the_sum_of_squares_a_fitted_sinusoid_explains(seed):
    x, y = _samples(seed)
    frequencies = np.linspace(60.0, 2000.0, 57)       # cycles per m
    power = explained_power(x, y, frequencies)
    expected = [_explained_by_fit(x, y, f) for f in frequencies]
    np.testing.assert_allclose(power, expected, rtol=1e-9, atol=1e-12 * max(expected))


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_peak_is_at_the_true_period(seed):
    x, y = _samples(seed)
    frequencies = np.linspace(60.0, 2000.0, 4000)
    best = frequencies[np.argmax(explained_power(x, y, frequencies))]
    # Within a tenth of the peak's width (1 / span).
    assert abs(best - 1 / TRUE_PERIOD) < 0.1 / np.ptp(x)


def test_chunks_give_what_one_block_gives(monkeypatch):
    x, y = _samples(3)
    frequencies = np.linspace(60.0, 2000.0, 301)
    whole = explained_power(x, y, frequencies)
    monkeypatch.setattr('calib_core.periodogram.CHUNK_ELEMENTS', 7 * len(x))
    np.testing.assert_allclose(explained_power(x, y, frequencies), whole, rtol=1e-12)


def test_on_a_regular_grid_up_to_its_nyquist_frequency_it_is_scipys_periodogram():
    """Where a sinusoid degenerates on the samples (a grid at its Nyquist frequency, or a
    whole number of periods apart) the guard is scipy's, so the loop decides as before."""
    from scipy.signal import lombscargle
    x = np.arange(14) * 1e-3                      # m, a target every millimetre
    y = np.random.default_rng(4).normal(0.0, 1e-6, 14)
    frequencies = np.linspace(20.0, 1000.0, 99)   # up to one cycle per target
    expected = 2 * lombscargle(x, y, 2 * np.pi * frequencies, floating_mean=True)
    np.testing.assert_allclose(explained_power(x, y, frequencies), expected, rtol=1e-9,
                               atol=1e-12 * expected.max())
