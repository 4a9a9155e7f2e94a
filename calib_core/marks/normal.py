"""The standard normal's Gaussian, Phi and phi as polynomials the compiler vectorises
(numba): the dot fit's pixel model takes them at every pixel, where libm's exp and erfc
(15 ns a call) kept its loops scalar. ``VECTOR`` holds the compile options that let it
vectorise them (:mod:`calib_core.marks.dot_fit`)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.special import erfcx

_SQRT_HALF = math.sqrt(0.5)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
# Reassociation lets the compiler vectorise the normal equations' sums; NaN and infinity
# keep their meaning, because a diverging trial is refused by its cost not being finite.
FAST = {'reassoc', 'contract', 'nsz', 'arcp'}
# Numpy's error model: a division by zero gives infinity or NaN (refused as above) instead
# of a check and a raise on every division, which keeps the pixel loops from vectorising.
VECTOR = {'fastmath': FAST, 'error_model': 'numpy'}


# The Gaussian exp(-x^2 / 2) is taken at |x| <= this: beyond, its value there (2e-16),
# and Phi's tails under 1e-17, are zero to the model. The bound lets a polynomial stand for
# exp: (p(y / 2^k))^(2^k), with y / 2^k in [-1.13, 0] for k = _EXP_HALVINGS.
_GAUSS_CLAMP = 8.5
_EXP_HALVINGS = 5


def _exp_coefficients(degree=11):
    """Power-series coefficients (highest first) of exp(y) for y in [-c^2 / 2^(k + 1), 0]
    (c = _GAUSS_CLAMP, k = _EXP_HALVINGS): a least-squares fit at Chebyshev nodes, within
    4e-15 relatively, so the 2^k-th power of it is within 1e-13 of exp(-x^2 / 2)."""
    low = -0.5 * _GAUSS_CLAMP ** 2 / 2 ** _EXP_HALVINGS
    y = 0.5 * low * (1.0 - np.cos(np.pi * (np.arange(200) + 0.5) / 200))
    series = np.polynomial.Polynomial.fit(y, np.exp(y), degree, domain=[low, 0.0])
    return tuple(series.convert().coef[::-1].tolist())


_EXP = _exp_coefficients()


def _scaled_erfc_coefficients(degree=12):
    """Power-series coefficients c (in s = 2 t - 1, t = 1 / (1 + x / 2)) of
    ``erfc(x) = t exp(-x^2) sum_k c_k s^k`` for x >= 0: a Chebyshev fit of scipy's
    erfcx(x) / t, within 1e-9 of erfc everywhere. The pixel model shares exp(-x^2) with
    its slope, so the edge's coverage costs a division and a polynomial, not a libm erfc
    (15 ns a call). The series is made exactly 1 at x = 0 (s = 1), so Phi has no step
    there: the box profile's second differences over 1e-4 px would make a 1e-9 step one
    of 4e-6."""
    t = 0.5 * (1.0 - np.cos(np.pi * (np.arange(400) + 0.5) / 400))
    series = np.polynomial.chebyshev.chebfit(2 * t - 1, erfcx(2 / t - 2) / t, degree)
    power = np.polynomial.chebyshev.cheb2poly(series)
    power[0] += 1.0 - power.sum()
    return tuple(power[::-1].tolist())


_ERFC = _scaled_erfc_coefficients()


@njit(cache=True, **VECTOR)
def _gauss(x):
    """exp(-x^2 / 2) within 1e-13 relatively, for |x| <= _GAUSS_CLAMP (its value there
    beyond): a polynomial and squarings, which the compiler vectorises (libm's exp it
    calls one pixel at a time)."""
    y = -0.5 * min(x * x, _GAUSS_CLAMP * _GAUSS_CLAMP) * (0.5 ** _EXP_HALVINGS)
    value = 0.0
    for c in _EXP:
        value = value * y + c
    for _ in range(_EXP_HALVINGS):
        value *= value
    return value


@njit(cache=True, **VECTOR)
def normal_cdf_pdf(x):
    """Phi(x) and phi(x) of the standard normal; Phi from the erfc fit sharing the
    Gaussian (see _gauss: within 2e-16 of 0 and 1 beyond its clamp)."""
    gauss = _gauss(x)
    t = 1.0 / (1.0 + 0.5 * _SQRT_HALF * abs(x))
    s = 2.0 * t - 1.0
    series = 0.0
    for c in _ERFC:
        series = series * s + c
    tail = 0.5 * t * gauss * series
    return (tail if x < 0.0 else 1.0 - tail), gauss * _INV_SQRT_2PI
