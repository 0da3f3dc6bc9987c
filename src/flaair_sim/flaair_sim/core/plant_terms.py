"""A model's discovered terms at the drive and at the sensor outputs (`flaair_model.terms`).

Terms acting on the dynamics are inside the RK4 kernel (`plant_params` writes them into the
kernel's parameter vector); the others act outside it, on numpy blocks:

- drive terms: the drive the actuator sees is the commanded drive plus each term;
- sensor terms: added to a charge amplifier's output after its high-pass and delay.

State between blocks (`terms_state`): the last commanded drive sample (for ``ddrive_v``), the
last angles (for the sensor sites' ``dphi`` and ``dpsi``) and one low-pass state per term; the
sample index (for ``t``) is the plant's. Stepping block by block equals one whole record, like
the rest of the plant.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from flaair_model.model import Model
from flaair_model.terms import SENSOR_SITES, DiscoveredTerm, TermSignals

__all__ = [
    "add_batch_sensor_terms",
    "add_sensor_terms",
    "batch_drives",
    "drive_seen",
    "has_outside_terms",
    "outside_terms",
    "terms_state",
]


def outside_terms(model: Model) -> tuple[DiscoveredTerm, ...]:
    """The model's discovered terms that act outside the equations of motion."""
    return tuple(t for t in model.discovered if not t.is_dynamics)


def has_outside_terms(model: Model) -> bool:
    """The model has drive or sensor terms (the drive or the sensor output need more work)."""
    return any(not t.is_dynamics for t in model.discovered)


# terms_state's layout: the last drive (V), the last stroke and pitch (rad), then the filters.
_LAST_DRIVE, _LAST_PHI, _LAST_PSI, _FILTERS = 0, 1, 2, 3


def terms_state(model: Model, state: np.ndarray | None = None) -> np.ndarray:
    """[last drive V, last stroke rad, last pitch rad, low-pass state per outside term] (at
    rest, or `state` fitted to `model`: the last samples kept, the filters at rest if the
    model's terms changed).
    """
    n = _FILTERS + (len(outside_terms(model)) if model.discovered else 0)
    if state is not None and state.shape == (n,):
        return state.copy()
    fresh = np.zeros(n)
    if state is not None and state.size >= _FILTERS:
        fresh[:_FILTERS] = state[:_FILTERS]
    return fresh


def drive_seen(
    model: Model, fs_hz: float, drive_v: np.ndarray, first_index: int, state: np.ndarray
) -> np.ndarray:
    """The drive the actuator sees (V); `state` (from `terms_state`) updated in place.

    Does not update the last drive sample: `add_sensor_terms` reads it after, then stores it.
    """
    if not model.discovered:  # the common case, without building the tuple below
        return drive_v
    terms = outside_terms(model)
    if not any(t.acts_on == "drive" for t in terms):
        return drive_v
    out = drive_v.copy()
    for i, term in enumerate(terms):
        if term.acts_on != "drive":
            continue
        sig = TermSignals.of_block(
            fs_hz, drive_v, first_index, state[_LAST_DRIVE], state[_FILTERS + i]
        )
        out += term.coefficient * term.feature(sig)
        state[_FILTERS + i] = sig.zf
    return out


def add_sensor_terms(
    model: Model,
    fs_hz: float,
    drive_v: np.ndarray,
    first_index: int,
    stroke_rad: np.ndarray,
    pitch_rad: np.ndarray,
    stroke_sensor_v: np.ndarray,
    pitch_sensor_v: np.ndarray,
    state: np.ndarray,
) -> None:
    """Add the sensor terms to both outputs in place; `state` updated in place (the last drive
    and angles too).
    """
    terms = outside_terms(model) if model.discovered else ()
    if terms and any(t.acts_on in SENSOR_SITES for t in terms):
        vref = model.sensors.reference_voltage_v
        dev = {"stroke_sensor_v": stroke_sensor_v - vref, "pitch_sensor_v": pitch_sensor_v - vref}
        out = {"stroke_sensor_v": stroke_sensor_v, "pitch_sensor_v": pitch_sensor_v}
        for i, term in enumerate(terms):
            if term.acts_on not in SENSOR_SITES:
                continue
            sig = TermSignals.of_block(
                fs_hz,
                drive_v,
                first_index,
                state[_LAST_DRIVE],
                state[_FILTERS + i],
                (state[_LAST_PHI], state[_LAST_PSI]),
                phi=stroke_rad,
                psi=pitch_rad,
                **dev,
            )
            out[term.acts_on] += term.coefficient * term.feature(sig)
            state[_FILTERS + i] = sig.zf
    if drive_v.shape[0]:
        state[_LAST_DRIVE] = drive_v[-1]
        state[_LAST_PHI], state[_LAST_PSI] = stroke_rad[-1], pitch_rad[-1]


def batch_drives(
    models: Sequence[Model], fs_hz: float, drive_v: np.ndarray
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """The drive each model of a batch sees, from rest: ((1 or m, n) drive, term states).

    `drive_v` is (1, n) shared or (m, n); it is returned as it is (states None) when no model
    has drive or sensor terms.
    """
    if not any(has_outside_terms(m) for m in models):
        return drive_v, None
    states = [terms_state(m) for m in models]
    rows = [
        drive_seen(m, fs_hz, drive_v[0 if drive_v.shape[0] == 1 else i], 0, states[i])
        for i, m in enumerate(models)
    ]
    return np.ascontiguousarray(np.array(rows).reshape(len(models), drive_v.shape[1])), states


def add_batch_sensor_terms(
    models: Sequence[Model],
    fs_hz: float,
    drive_v: np.ndarray,
    states: list[np.ndarray] | None,
    stroke_rad: np.ndarray,
    pitch_rad: np.ndarray,
    stroke_sensor_v: np.ndarray,
    pitch_sensor_v: np.ndarray,
) -> None:
    """`add_sensor_terms` for each model of a batch ((m, n) outputs, in place)."""
    if states is None:
        return
    for i, m in enumerate(models):
        add_sensor_terms(
            m,
            fs_hz,
            drive_v[0 if drive_v.shape[0] == 1 else i],
            0,
            stroke_rad[i],
            pitch_rad[i],
            stroke_sensor_v[i],
            pitch_sensor_v[i],
            states[i],
        )
