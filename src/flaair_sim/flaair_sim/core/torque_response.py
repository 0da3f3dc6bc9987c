"""The plant's response to small added torques, linearised about its own motion.

A discovered dynamics term c f(x, v, t) added to the stroke or pitch equation moves the motion by
c times the response of the linearised plant to the forcing f along the motion, plus O(c^2). For
many forms at once that response is far cheaper than one simulation each: the plant is stepped
once (the kernel's own step, so the motion is the simulation's bit for bit), and at each sample
the state's Jacobian A of the accelerations (central differences of the kernel's own
`_accelerations`) gives the sample's transition (Phi, Gamma) of the linear system
d' = A d + B u with u held over the sample; every form's deviation d then moves by a 4x4
product. A is taken at the sample's start (an O(h) approximation on the wingbeat's scale), and
a low-pass term already in the model keeps its filter state along the motion.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from flaair_model.model import Model
from flaair_sim.core import plant_params as pp
from flaair_sim.core.plant_kernel import linear_responses
from flaair_sim.core.plant_params import prepare
from flaair_sim.core.plant_terms import drive_seen, has_outside_terms, terms_state

__all__ = ["EQUATIONS", "torque_responses"]

# The equations a forcing may be added to (the kernel's numbering of `dynamics_terms`).
EQUATIONS = {"stroke": 1, "pitch": 2}


def torque_responses(
    model: Model,
    drive_v: np.ndarray,
    fs_hz: float,
    mechanical0: Sequence[float] | np.ndarray,
    equation: str,
    torque_nm: np.ndarray,
    angle: str,
) -> np.ndarray:
    """How each of many small added torques moves one angle, to first order.

    Parameters
    ----------
    model
        The model whose motion the plant is linearised about.
    drive_v
        (n,) the drive (V), as `simulate_batch_from` takes it.
    fs_hz
        Sample rate.
    mechanical0
        (4,) initial [phi rad, phi' rad/s, psi rad, psi' rad/s].
    equation
        'stroke' or 'pitch': the equation the forcing is added to.
    torque_nm
        (n, m) added torque (N m) per sample, one column per form (held over the sample, like
        the drive; a form's value at the sample's midpoint is the closest to what the kernel
        integrates).
    angle
        'stroke' or 'pitch': the angle reported.

    Returns
    -------
    np.ndarray
        (n, m) change of the angle (rad) at each sample, per column.
    """
    prep = prepare(model, fs_hz)
    drive = np.ascontiguousarray(drive_v, dtype=np.float64)
    if has_outside_terms(model):
        drive = np.ascontiguousarray(drive_seen(model, fs_hz, drive, 0, terms_state(model)))
    # the equation's inertia as the kernel resolves it (with the model's effects)
    inertia = prep.params[pp.P_I if equation == "stroke" else pp.P_IP]
    torque = np.ascontiguousarray(torque_nm, dtype=np.float64)
    if torque.ndim != 2 or torque.shape[0] != drive.shape[0]:
        raise ValueError(f"torque_nm is {torque.shape}, expected ({drive.shape[0]}, m)")
    out = np.empty(torque.shape)
    linear_responses(
        np.array(mechanical0, dtype=np.float64),
        drive,
        1.0 / fs_hz,
        prep.n_substeps,
        prep.n_substeps_contact,
        prep.params,
        EQUATIONS[equation],
        torque,
        float(inertia),
        0 if angle == "stroke" else 2,
        out,
    )
    return out
