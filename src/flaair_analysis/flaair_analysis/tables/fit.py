"""The model fitted to a table: plant parameters (and any effect or term), started from the data.
Pure.

Residuals are the table's measured cells against the model's steady state (`steady_response`),
each weighted by its reading noise: an amplitude by hypot(`reading_noise_deg`,
`reading_noise_rel` x value), a phase by `phase_noise_deg` (wrapped): the table is a
`TableEvidence`, fitted by the one fit over evidence (`flaair_analysis.evidence.fit_evidence`),
plant parameters in log space within x/÷ `fit_range` of their start; its Jacobian is one batch
of the plant core (every parameter's step and every point at once).

The start comes from the table, not from the configured robot: the stroke natural frequency is
the stroke's peak frequency, the actuator gain the quasi-static amplitude per volt of the points
well below the peak (K A / V), the aerodynamic damping the peak's height (a sine of amplitude A at
resonance: G V = Gamma (8 / 3 pi) w^2 A^2). The pitch natural frequency starts from the best
of a grid (one batch), so a robot resonant far from nominal still fits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from flaair_analysis.discrepancy.evidence_search import (
    FIT_TOL,
    FreeParam,
    ParamFit,
    as_param_fit,
    fit_params,
    fit_space,
    plant_params,
    setter,
)
from flaair_analysis.discrepancy.identification import Stage, fit_stages
from flaair_analysis.discrepancy.runs import Run
from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .reader import AMPLITUDE_COLUMNS, PHASE_COLUMNS, Table, TableInputError
from .steady_state import steady_response
from .table_evidence import TableEvidence, normalised_residuals, stack_cells

__all__ = [
    "PITCH_KEYS",
    "STROKE_KEYS",
    "data_start",
    "fit_table",
    "identify_table",
    "misfit_warnings",
]

STROKE_KEYS: tuple[str, ...] = (
    "stroke_natural_frequency_hz",
    "aero_damping_nm_s2",
    "actuator_gain_nm_per_v",
)
PITCH_KEYS: tuple[str, ...] = (
    "pitch_natural_frequency_hz",
    "hinge_damping_nm_s_per_rad",
    "inertial_coupling_kg_m2",
    "aero_coupling_nm_s2",
)
_DESCRIBING = 8.0 / (3.0 * math.pi)
_PITCH_GRID = tuple(np.geomspace(0.5, 2.0, 15))


def fit_table(
    table: Table,
    model: Model,
    params: Sequence[FreeParam],
    s: TableSettings,
    columns: Sequence[str],
) -> ParamFit:
    """Least squares of `params` on the table's `columns` (noise-weighted cells)."""
    return fit_params([TableEvidence(table, s, columns)], model, params, s.max_nfev)


def _stroke_pp_rad(table: Table) -> np.ndarray | None:
    if "stroke_pp_deg" in table.responses:
        pp_rad: np.ndarray = np.radians(table.responses["stroke_pp_deg"])
        return pp_rad
    if "stroke_amplitude_deg" in table.responses:
        return np.radians(2.0 * table.responses["stroke_amplitude_deg"])
    return None


def data_start(table: Table, model: Model) -> tuple[dict[str, float], list[str]]:
    """Stroke plant parameters from the table's peaks and low-frequency gain, and notes.

    Returns the start values (model.yaml plant keys) and what the table could not give.
    """
    notes: list[str] = []
    pp = _stroke_pp_rad(table)
    if pp is None or not np.isfinite(pp).any():
        return {}, ["no stroke amplitude: the stroke plant starts from the model"]
    idx, f = table.level_index, table.frequency_hz
    peaks = []
    for i in range(table.levels_v.size):
        sel = (idx == i) & np.isfinite(pp)
        if sel.any():
            k = np.flatnonzero(sel)[np.argmax(pp[sel])]
            edge = f[k] in (f[sel].min(), f[sel].max())
            peaks.append((f[k], pp[k] / 2.0, table.drive_amplitude_v[k], edge))
    inner = [p for p in peaks if not p[3]]
    if not inner:
        notes.append(
            "no drive level peaks inside its frequency range: the resonance is outside the "
            "table, the start is the configured robot's"
        )
        return {}, notes
    fn = float(np.median([p[0] for p in inner]))
    inertia = model.plant.stroke_inertia_kg_m2
    k_stiff = inertia * (2.0 * math.pi * fn) ** 2
    low = np.isfinite(pp) & (f < 0.6 * fn)
    if low.any():
        amp = pp[low] / 2.0 * np.abs(1.0 - (f[low] / fn) ** 2)
        gain = float(np.median(k_stiff * amp / table.drive_amplitude_v[low]))
    else:
        gain = (
            model.plant.actuator_gain_nm_per_v * (fn / model.plant.stroke_natural_frequency_hz) ** 2
        )
        notes.append("no point below 0.6 x the peak frequency: the gain starts from the model's")
    w = 2.0 * math.pi * fn
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):  # checked by the caller
        gamma = float(np.median([gain * v / (_DESCRIBING * w**2 * a**2) for _, a, v, _ in inner]))
    return {
        "stroke_natural_frequency_hz": fn,
        "actuator_gain_nm_per_v": gain,
        "aero_damping_nm_s2": gamma,
    }, notes


def _pitch_grid_start(
    table: Table, model: Model, s: TableSettings, cols: Sequence[str]
) -> dict[str, float]:
    """The pitch natural frequency of a grid around the model's with the lowest cost."""
    f0 = model.plant.pitch_natural_frequency_hz
    grid = [
        replace(model, plant=replace(model.plant, pitch_natural_frequency_hz=f0 * g))
        for g in _PITCH_GRID
    ]
    resp = steady_response(grid, table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s)
    r = stack_cells(table, normalised_residuals(table, resp, s, cols))
    best = int(np.argmin((r**2).sum(axis=1)))
    return {"pitch_natural_frequency_hz": f0 * _PITCH_GRID[best]}


def _columns(table: Table, side: str) -> list[str]:
    return [
        c
        for c in (*AMPLITUDE_COLUMNS, *PHASE_COLUMNS)
        if c.startswith(side) and c in table.responses
    ]


def _side_problem(
    table: Table, side: str, cols: Sequence[str], n_keys: int, s: TableSettings
) -> str | None:
    """Why the table's `side` columns cannot be fitted (None when they can)."""
    cells = sum(int(np.isfinite(table.responses[c]).sum()) for c in cols)
    if cells < n_keys:
        return (
            f"{cells} measured {side} cell(s) for the {n_keys} {side} parameters (a fit needs at "
            "least as many cells as parameters)"
        )
    amps = [c for c in cols if c in AMPLITUDE_COLUMNS]
    values = np.concatenate([table.responses[c] for c in amps]) if amps else np.zeros(0)
    values = values[np.isfinite(values)]
    floor = s.reading_noise_deg / 2.0
    if values.size and values.max() < floor:
        return (
            f"every {side} amplitude is below the reading noise ({floor:g} deg; the largest is "
            f"{values.max():.3g} deg): the table shows no {side} motion (check the unit)"
        )
    return None


def _plausible_start(start: dict[str, float], model: Model, notes: list[str]) -> dict[str, float]:
    """`start` without the values that are not finite or lie beyond x/÷ 1e6 of the model's."""
    out = {}
    for k, v in start.items():
        nominal = float(getattr(model.plant, k))
        if math.isfinite(v) and v > 0 and (nominal <= 0 or 1e-6 < v / nominal < 1e6):
            out[k] = v
        else:
            notes.append(
                f"the table's peaks give {k} = {v:.3g}: implausible, started from the model"
            )
    return out


def misfit_warnings(table: Table, model: Model, s: TableSettings) -> list[str]:
    """Warnings where `model` misses a column by more than `gap_ratio` x the reading noise
    (as the joint fit warns), and what a phase column's miss suggests: a column that fits far
    better negated uses the opposite sign convention (lags written as positive numbers).
    """
    cols = list(table.responses)
    resp = steady_response(
        [model], table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s
    )
    res = normalised_residuals(table, resp, s, cols)
    out = []
    for c in cols:
        ok = np.isfinite(table.responses[c])
        if not ok.any():
            continue
        ratio = float(np.sqrt(np.mean(np.nan_to_num(res[c][0][ok], nan=1e6) ** 2)))
        if not ratio > s.gap_ratio:
            continue
        line = (
            f"warning: the fitted plant misses {c} by {ratio:.1f}x the reading noise (more than "
            f"{s.gap_ratio:g}x): the table and the model disagree"
        )
        if c in PHASE_COLUMNS:
            flipped = replace(table, responses={**table.responses, c: -table.responses[c]})
            alt = normalised_residuals(flipped, resp, s, [c])[c][0][ok]
            alt_ratio = float(np.sqrt(np.mean(np.nan_to_num(alt, nan=1e6) ** 2)))
            if alt_ratio < 0.5 * ratio:
                line += (
                    f"; its phases look like lags with the opposite sign (negated, they miss by "
                    f"{alt_ratio:.1f}x): the table's convention is negative = lag"
                )
        out.append(line)
    return out


def identify_table(
    table: Table, model: Model, s: TableSettings
) -> tuple[Model, list[ParamFit], dict[str, float], list[str]]:
    """The stroke plant fitted on the stroke columns, then the pitch plant on the pitch columns.

    Returns
    -------
    model, fits, start, notes
        The fitted model, each stage's `ParamFit`, the start from the data (plant keys) and
        what the table cannot tell (no resonance inside it, no pitch column, ...).
    """
    start, notes = data_start(table, model)
    start = _plausible_start(start, model, notes)
    fits = []
    stroke_cols = _columns(table, "stroke")
    pitch_cols = _columns(table, "pitch")
    problems = {}
    for side, cols, keys in (
        ("stroke", stroke_cols, STROKE_KEYS),
        ("pitch", pitch_cols, PITCH_KEYS),
    ):
        if cols and (problem := _side_problem(table, side, cols, len(keys), s)):
            problems[side] = problem
    if len(problems) == len([c for c in (stroke_cols, pitch_cols) if c]):
        raise TableInputError(f"{table.source}: nothing to fit: {'; '.join(problems.values())}")
    for side, problem in problems.items():
        notes.append(f"{problem}: the {side} plant stays the model's")
    if "stroke" in problems:
        stroke_cols = []
    if "pitch" in problems:
        pitch_cols = []
    columns = {"stroke_deg": stroke_cols, "pitch_deg": pitch_cols}
    chosen: list[tuple[Model, list[FreeParam]]] = []

    def stage_of(channel: str, keys: tuple[str, ...], current: Model, _: list[Run]) -> Stage | None:
        cols = columns[channel]
        if not cols:
            return None
        side_start = start
        if channel == "pitch_deg":  # the pitch started from a grid on the fitted stroke
            side_start = _pitch_grid_start(table, current, s, cols)
            start.update(side_start)
        params = plant_params(current, keys, side_start, s.fit_range)
        chosen.append((current, params))
        x0, lower, upper, steps = fit_space(params)
        return Stage(
            keys,
            (TableEvidence(table, s, cols),),
            (x0,),
            lower,
            upper,
            s.max_nfev,
            tol=FIT_TOL,
            to_model=setter(current, params),
            steps=steps,
        )

    staged = fit_stages(model, [], STROKE_KEYS + PITCH_KEYS, stage_of)
    model = staged.model
    fits = [
        as_param_fit(before, params, fit)
        for (before, params), (_, _, fit) in zip(chosen, staged.stages, strict=True)
    ]
    if not stroke_cols and "stroke" not in problems:
        notes.append("no stroke column: the stroke plant stays the model's")
    if not pitch_cols and "pitch" not in problems:
        notes.append("no pitch column: the pitch plant stays the model's")
    for fit in fits:
        if fit.singular:
            names = ", ".join(p.key.removeprefix("plant.") for p in fit.params)
            notes.append(
                f"the fit of {names} is singular: the table's {fit.n} cells cannot tell "
                "them apart (standard errors unbounded); measure more frequencies or levels"
            )
    fn = model.plant.stroke_natural_frequency_hz
    near = np.abs(table.frequency_hz / fn - 1.0) <= s.near_resonance
    if stroke_cols and not near.any():
        nearest = table.frequency_hz[np.argmin(np.abs(table.frequency_hz - fn))]
        notes.append(
            f"no point near the resonance (fitted {fn:.1f} Hz, nearest point {nearest:g} Hz): "
            "damping and gain are poorly separated"
        )
    notes.extend(misfit_warnings(table, model, s))
    return model, fits, start, notes
