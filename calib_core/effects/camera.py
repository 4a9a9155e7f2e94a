"""Lens distortion as OpenCV models it, acting on normalised image coordinates."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import FixedParameters


class RadialDistortion(FixedParameters):
    name = 'radial_distortion'
    meaning = 'radial lens distortion (OpenCV k1, k2): x_n (k1 r^2 + k2 r^4)'
    requires, parameters, units = ('normalized',), ('k1', 'k2'), ('1', '1')

    def term(self, params, context):
        n = context['normalized']
        r2 = np.sum(n ** 2, axis=1, keepdims=True)
        return n * (params[0] * r2 + params[1] * r2 ** 2)


class RadialDistortionK3(FixedParameters):
    name = 'radial_distortion_k3'
    meaning = 'radial lens distortion of sixth order (OpenCV k3): x_n k3 r^6'
    requires, parameters, units = ('normalized',), ('k3',), ('1',)
    follows = 'radial_distortion'

    def term(self, params, context):
        n = context['normalized']
        r2 = np.sum(n ** 2, axis=1, keepdims=True)
        return n * (params[0] * r2 ** 3)


class TangentialDistortion(FixedParameters):
    name = 'tangential_distortion'
    meaning = 'decentring lens distortion (OpenCV p1, p2)'
    requires, parameters, units = ('normalized',), ('p1', 'p2'), ('1', '1')

    def term(self, params, context):
        x, y = context['normalized'][:, 0], context['normalized'][:, 1]
        p1, p2 = params
        r2 = x ** 2 + y ** 2
        return np.column_stack([2 * p1 * x * y + p2 * (r2 + 2 * x ** 2),
                                p1 * (r2 + 2 * y ** 2) + 2 * p2 * x * y])
