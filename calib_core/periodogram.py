"""The generalised Lomb-Scargle periodogram (Zechmeister and Kuerster 2009: a sinusoid and
a floating mean fitted at each trial frequency) of unevenly sampled residuals.

This is scipy.signal.lombscargle's computation for unit weights and a floating mean (its
phase offset tau, its guard of the degenerate sums), so the loop decides as it did with it,
with the sums at the shifted phase taken from the angle-sum identities rather than a second
pass of cosines and sines; importing scipy.signal loads scipy.stats too, 0.35 s of every loop command's
start-up, for this one function.
"""
from __future__ import annotations

import numpy as np

CHUNK_ELEMENTS = 2_000_000
"""Frequencies times samples evaluated at once (bounds the memory to some 100 MB)."""


def explained_power(x, y, frequencies) -> np.ndarray:
    """Sum of squares of ``y`` explained by ``a cos(2 pi f x) + b sin(2 pi f x)`` on top of
    a floating mean, at each frequency.

    Parameters
    ----------
    x : array_like, shape (n,)
        Sample positions (any unit, e.g. m or s).
    y : array_like, shape (n,)
        Values at them (any unit u).
    frequencies : array_like, shape (f,)
        Trial frequencies in cycles per unit of ``x``.

    Returns
    -------
    ndarray, shape (f,)
        Explained sum of squares (u^2), twice what
        ``scipy.signal.lombscargle(x, y, 2 pi f, floating_mean=True)`` gives. Where the
        samples cannot see one of the two sinusoids (a regular grid at its Nyquist
        frequency), its sums are held at machine epsilon as scipy holds them, which all but
        drops that sinusoid.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    frequencies = np.atleast_1d(np.asarray(frequencies, float))
    n = len(x)
    power = np.empty(len(frequencies))
    step = max(1, CHUNK_ELEMENTS // max(n, 1))
    mean_y = y.mean()
    epsilon = np.finfo(float).epsneg
    for start in range(0, len(frequencies), step):
        phase = np.multiply.outer(2 * np.pi * frequencies[start:start + step], x)   # (f, n)
        cos, sin = np.cos(phase), np.sin(phase)
        c, s = cos.mean(axis=1), sin.mean(axis=1)
        cc = np.einsum('fn,fn->f', cos, cos) / n
        ss = 1.0 - cc - s * s
        cc = cc - c * c
        cs = np.einsum('fn,fn->f', cos, sin) / n - c * s
        # The phase offset that makes the centred cross term vanish; the sums at the
        # shifted phase follow from those at the phase by the angle-sum identities.
        tau = 0.5 * np.arctan2(2.0 * cs, cc - ss)
        cos_tau, sin_tau = np.cos(tau), np.sin(tau)
        yc0, ys0 = cos @ y / n, sin @ y / n
        cc0 = cc + c * c                       # the mean of cos^2, uncentred
        cs0 = cs + c * s
        yc = cos_tau * yc0 + sin_tau * ys0
        ys = cos_tau * ys0 - sin_tau * yc0
        cc = cos_tau ** 2 * cc0 + 2 * cos_tau * sin_tau * cs0 + sin_tau ** 2 * (1.0 - cc0)
        ss = 1.0 - cc
        c, s = cos_tau * c + sin_tau * s, cos_tau * s - sin_tau * c
        yc, ys = yc - mean_y * c, ys - mean_y * s
        cc, ss = cc - c * c, ss - s * s
        cc, ss = np.maximum(cc, epsilon), np.maximum(ss, epsilon)
        power[start:start + step] = n * (yc * yc / cc + ys * ys / ss)
    return power
