"""The sensor chain's numba kernels: high-pass, delay and reference voltage of one channel; the
noise added to both.
"""

from __future__ import annotations

from numba import njit

__all__ = ["add_sensor_noise", "sensor_channel_kernel"]


@njit(cache=True)
def sensor_channel_kernel(out, hp_on, b0, b1, a1, z, hist, whole, frac, v_ref):
    """Turn the deviations in `out` into sensor volts in place: high-pass, delay, + v_ref.

    `hist` holds the last len(hist) high-passed deviations (oldest first) and is updated in
    place; returns the high-pass state.
    """
    n = out.shape[0]
    if hp_on != 0.0:
        for k in range(n):
            y = b0 * out[k] + z
            z = b1 * out[k] - a1 * y
            out[k] = y
    length = hist.shape[0]
    if length == 0:
        for k in range(n):
            out[k] = v_ref + out[k]
        return z
    dev = out.copy()
    # sample j of the concatenation [hist, dev] is hist[j] for j < length, else dev[j - length]
    for k in range(n):
        j = length + k - whole
        newest = dev[j - length] if j >= length else hist[j]
        if frac == 0.0:
            out[k] = v_ref + newest
        else:
            older = dev[j - 1 - length] if j - 1 >= length else hist[j - 1]
            out[k] = v_ref + ((1.0 - frac) * newest + frac * older)
    if n >= length:
        for j in range(length):
            hist[j] = dev[n - length + j]
    else:
        for j in range(length - n):
            hist[j] = hist[j + n]
        for j in range(n):
            hist[length - n + j] = dev[j]
    return z


@njit(cache=True)
def add_sensor_noise(sensor_v, noise, rms):
    """``sensor_v[c, k] += noise[k, c] * rms`` in place: the two channels' rows (2, n) and the
    noise as drawn, (n, 2). numpy's ``noise *= rms; sensor_v += noise.T`` to the bit (no fused
    multiply-add), in one call instead of three array operations a block.
    """
    for c in range(sensor_v.shape[0]):
        for k in range(sensor_v.shape[1]):
            sensor_v[c, k] += noise[k, c] * rms
