"""The actuator's hysteresis: a Bouc-Wen operator on the drive, in numba (`flaair_model.effects`
`ActuatorHysteresis`).

With n = 1 and gamma = beta, the Bouc-Wen law dh = alpha dV - beta |dV| h - beta dV |h| reads,
for a rising drive, dh/dV = alpha while h < 0 and alpha - 2 beta h once h >= 0 (a falling drive
mirrors it). Both pieces solve in closed form, and the law is rate-independent, so the jump of
the held drive from one sample to the next is taken exactly, whatever the sample rate: the
operator has no integration error of its own.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["hysteretic_voltage"]


@njit(cache=True)
def hysteretic_voltage(drive, fraction, saturation_v, state, out):
    """The hysteretic voltage h after each drive sample's jump, into `out` (V).

    Parameters
    ----------
    drive : (n,) drive samples (V).
    fraction : alpha, the share of each volt h takes after a reversal (0 < alpha < 1).
    saturation_v : alpha / (2 beta), the bound h approaches (V).
    state : (2,) [h, the last drive sample] before the block; updated in place.
    out : (n,) written.
    """
    h, last = state[0], state[1]
    rate = fraction / saturation_v  # 2 beta
    for k in range(drive.shape[0]):
        v = drive[k]
        step = v - last
        last = v
        if step != 0.0:
            sign = 1.0 if step > 0.0 else -1.0
            u = sign * h  # the law for a rising drive, mirrored for a falling one
            left = abs(step)
            if u < 0.0:
                to_zero = -u / fraction
                if left <= to_zero:
                    u += fraction * left
                    left = 0.0
                else:
                    u = 0.0
                    left -= to_zero
            if left > 0.0:
                u = saturation_v - (saturation_v - u) * math.exp(-rate * left)
            h = sign * u
        out[k] = h
    state[0], state[1] = h, last
