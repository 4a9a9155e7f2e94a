"""The closed loop's effect library: physical effects a machine model may lack.

An effect adds a term to the machine's *channels*: the quantities it acts on directly,
such as an axis position (m), a hexapod leg length (m) or a normalised image coordinate.
Each machine says what its channels are and supplies the covariates an effect needs in a
*context* (a dict of arrays for the rows being evaluated):

``position``     (n, C) channel positions, m (axis command, gantry axis, leg length)
``direction``    (n, C) direction of approach, +1 from below, -1 from above
``time``         (n,) s, ``temperature`` (n,) K (differences matter, not the zero)
``load``         (n, C) static axial force per channel, N, compression positive
``normalized``   (n, 2) normalised image coordinates of a camera (x/z, y/z)
``angle``        (n, C) rad, the angle of each rotary channel (NaN for a linear one)

Names are stable (they appear in reports):

==========================  ============================================================
``offset``                  constant shift per channel (m)
``scale``                   scale error per channel, term = s * position (1)
``squareness``              non-orthogonality of two axes: channel 0 gains gamma * position 1 (rad)
``reversal``                backlash / lost motion: the carriage lags the drive by b/2 against
                            the direction of approach, term = -b/2 * direction (m)
``periodic``                cyclic error per channel, e.g. once per lead-screw revolution,
                            a cos(2 pi x / P) + b sin(2 pi x / P), period P found from the data (m)
``drift_time``              linear drift with time, term = rate * (t - t_ref) (m/s)
``drift_sequence``          linear drift over the run by approach number where no clock was
                            logged, term = rate * (s - s_mean) (m per approach)
``drift_temperature``       thermal expansion and zero drift, term = (k (x - x_mean) + g)
                            (T - T_ref) (k in 1/K, g the growth at the mean position, m/K)
``radial_distortion``       lens distortion k1, k2 (OpenCV): x_n (k1 r^2 + k2 r^4) (1)
``radial_distortion_k3``    its sixth order k3 (OpenCV): x_n k3 r^6 (1); tried once
                            ``radial_distortion`` is in the model (``follows``)
``tangential_distortion``   decentring distortion p1, p2 (OpenCV) (1)
``leg_play``                joint play taken up by the static leg force,
                            term = -play/2 * sign(load) (m)
``compliance``              elastic deflection, term = -c * load (m/N)
``angular_harmonics``       a rotary axis's angular error repeating every turn (worm gear,
                            encoder eccentricity), sum of a_k cos(k theta) + b_k sin(k theta),
                            orders resolved by the angles sampled (rad)
``smooth_map``              a smooth 2-D error map over an XY machine's travel: per axis 2-D
                            Legendre products of total degree 2 to d (2-4, by BIC) (m)
``error_motion``            radial, axial and tilt error motion of a rotary axis (ISO 230-7): the
                            rotor shifting (m) and tilting (rad) with its angle, orders 2 and up
                            per component; needs ``rotor_frame`` (n, C, C, 5), each axis's
                            housing frame in the channels (``rotor_view`` if they see it
                            otherwise)
==========================  ============================================================

Modules: ``base`` (Effect, Prepared and shared shapes), ``per_channel``, ``leg_play``,
``periodic``, ``position``, ``categorical``, ``camera``, ``rotary``, ``error_motion``,
``smooth_map``.
"""
from calib_core.effects.base import Effect, Prepared
from calib_core.effects.camera import (
    RadialDistortion, RadialDistortionK3, TangentialDistortion)
from calib_core.effects.categorical import CATEGORICAL_COVARIATES, BlockStep, WarmUp
from calib_core.effects.error_motion import ErrorMotion
from calib_core.effects.leg_play import LegPlay
from calib_core.effects.per_channel import (
    Compliance, DriftSequence, DriftTemperature, DriftTime, Offset, Reversal, Scale,
    Squareness)
from calib_core.effects.periodic import Periodic, resolvable_periods
from calib_core.effects.position import LeadError, ReversalByPosition
from calib_core.effects.rotary import RotaryHarmonics, resolvable_orders
from calib_core.effects.smooth_map import SmoothMap

LIBRARY = {e.name: e for e in (Offset(), Scale(), Squareness(), Reversal(), Periodic(),
                               ReversalByPosition(), LeadError(), BlockStep(), WarmUp(),
                               DriftTime(), DriftSequence(), DriftTemperature(),
                               RadialDistortion(), RadialDistortionK3(),
                               TangentialDistortion(), LegPlay(), Compliance(),
                               RotaryHarmonics(), ErrorMotion(), SmoothMap())}
# Effects that describe the run measured, not the machine: in force they would act on later
# runs with that run's clock, temperature or blocks (a drift with temperature could be
# compensated only from a live temperature, which no consumer here reads).
OF_THE_RUN = ('drift_time', 'drift_sequence', 'drift_temperature', 'block_step', 'warm_up')

__all__ = ['CATEGORICAL_COVARIATES', 'LIBRARY', 'BlockStep', 'Compliance', 'DriftSequence',
           'DriftTemperature',
           'DriftTime', 'Effect', 'ErrorMotion', 'LeadError', 'LegPlay', 'OF_THE_RUN', 'Offset',
           'Periodic', 'Prepared',
           'RadialDistortion', 'RadialDistortionK3', 'Reversal', 'ReversalByPosition',
           'RotaryHarmonics', 'Scale',
           'SmoothMap', 'Squareness', 'TangentialDistortion', 'WarmUp', 'resolvable_orders',
           'resolvable_periods']
