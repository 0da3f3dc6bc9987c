"""A model's discovered terms at the drive and at the sensor outputs (`flaair_model.terms`).

Terms acting on the dynamics are inside the RK4 kernel (`plant_params` writes them into the
kernel's parameter vector); the others act outside it, on numpy blocks:

- drive terms: the drive the actuator sees is the commanded drive plus each term;
- sensor terms: added to a charge amplifier's output after its high-pass and delay.

State between blocks (`TermState`): the last commanded drive sample (for ``ddrive_v``), the
sample index (for ``t``) and one low-pass state per term, so that stepping block by block equals
one whole record, like the rest of the plant.
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


def terms_state(model: Model, state: np.ndarray | None = None) -> np.ndarray:
    """[last drive V, low-pass state per outside term] (at rest, or `state` fitted to `model`)."""
    n = 1 + len(outside_terms(model)) if model.discovered else 1
    if state is not None and state.shape == (n,):
        return state.copy()
    fresh = np.zeros(n)
    if state is not None and state.size:
        fresh[0] = state[0]
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
        sig = TermSignals.of_block(fs_hz, drive_v, first_index, state[0], state[1 + i])
        out += term.coefficient * term.feature(sig)
        state[1 + i] = sig.zf
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
    """Add the sensor terms to both outputs in place; `state` updated in place (last drive too)."""
    terms = outside_terms(model) if model.discovered else ()
    if any(t.acts_on in SENSOR_SITES for t in terms):
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
                state[0],
                state[1 + i],
                phi=stroke_rad,
                psi=pitch_rad,
                **dev,
            )
            out[term.acts_on] += term.coefficient * term.feature(sig)
            state[1 + i] = sig.zf
    if drive_v.shape[0]:
        state[0] = drive_v[-1]


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
