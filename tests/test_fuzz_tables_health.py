"""Property tests, issue 52: frequency-response tables and health calibrations.

A table (as text and as a file) with cells replaced by hostile values (NaN, inf, 1e300, 3081,
tiny amplitudes, other separators, a byte-order mark, random bytes) is either read into tables
whose every value is finite and plausible, or refused with one TableInputError line; an accepted
table is fitted or refused in one line, never with another exception. A calibration with any
value in any field gives finite film lags and gains within their range, or one ParameterError
line naming the field.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from flaair_analysis.tables.fit import identify_table
from flaair_analysis.tables.reader import PLAUSIBLE_DEG, TableInputError, TableLimits, read_table
from flaair_control.health_io import MAX_FILM_LAG_S, film_calibration
from flaair_model import settings as config
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from flaair_tools.tables.table_io import load_tables

pytestmark = pytest.mark.timeout(240)

PROPERTY = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
LIMITS = TableLimits(20.0, 1000.0, 150.0)
HEADER = "drive_amplitude_v,drive_bias_v,frequency_hz,stroke_pp_deg,stroke_phase_deg,pitch_pp_deg"
ROWS = [
    [25, 0, 100, 18.9559, -8.1, 6.8071],
    [25, 0, 128.571, 42.1199, -60.2, 29.0520],
    [25, 0, 157.143, 31.0960, -150.3, 35.2689],
    [25, 0, 200, 8.8298, -178.8, 15.5360],
    [65, 0, 100, 50.1046, -15.1, 18.1812],
    [65, 0, 128.571, 76.0843, -70.4, 53.7877],
    [65, 0, 157.143, 57.0457, -140.2, 69.8974],
    [65, 0, 200, 22.2791, -170.0, 40.6306],
]
HOSTILE_CELLS = [
    "",
    "nan",
    "-inf",
    "1e300",
    "-1e300",
    "3081",
    "1e-199",
    "0",
    "-0",
    "1e-320",
    "9" * 40,
    "0x10",
    "30,81",
    "30;81",
    "\t",
    '"7"',
    "\ufeff1",
    "abc",
    "\x00",
    "-5",
]
cell = st.one_of(
    st.sampled_from(HOSTILE_CELLS),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=6),
)


@st.composite
def table_texts(draw) -> str:
    """The valid table with some cells replaced, rows dropped, a BOM or another separator."""
    rows = [[str(v) for v in r] for r in ROWS]
    for _ in range(draw(st.integers(0, 4))):
        i, j = draw(st.integers(0, len(rows) - 1)), draw(st.integers(0, len(rows[0]) - 1))
        rows[i][j] = draw(cell)
    keep = draw(st.lists(st.booleans(), min_size=len(rows), max_size=len(rows)))
    rows = [r for r, k in zip(rows, keep, strict=True) if k] or rows[:1]
    sep = draw(st.sampled_from([",", ",", ",", ";", "\t"]))
    text = "\n".join(sep.join(r) for r in [HEADER.split(","), *rows]) + "\n"
    return draw(st.sampled_from(["", "\ufeff", "# robot A\n"])) + text


def _check_read(tables) -> None:
    """Every value of every table read is finite, in the plant's range and plausible."""
    for t in tables:
        assert t.n_points > 0
        assert np.all(t.frequency_hz >= LIMITS.min_frequency_hz)
        assert np.all(t.frequency_hz <= LIMITS.max_frequency_hz)
        assert np.all(t.drive_amplitude_v > 0)
        assert np.all(t.drive_amplitude_v + np.abs(t.drive_bias_v) <= LIMITS.drive_limit_v)
        for column, values in t.responses.items():
            measured = values[np.isfinite(values)]
            assert measured.size == np.count_nonzero(~np.isnan(values))  # no inf
            assert np.all(np.abs(measured) <= PLAUSIBLE_DEG[column]), column


def _one_line(exc: Exception) -> None:
    text = str(exc)
    assert text and "\n" not in text and "Traceback" not in text, text


@PROPERTY
@given(st.one_of(table_texts(), st.binary(max_size=300).map(lambda b: b.decode("latin-1"))))
def test_a_table_text_is_read_plausibly_or_refused_in_one_line(text: str) -> None:
    try:
        tables = read_table(text, "fuzz.csv", LIMITS)
    except TableInputError as exc:
        _one_line(exc)
        return
    _check_read(tables)


@settings(PROPERTY, max_examples=60)
@given(st.one_of(table_texts().map(str.encode), st.binary(max_size=300)))
def test_a_table_file_is_read_or_refused_in_one_line(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzz.csv"
        path.write_bytes(data)
        try:
            tables = load_tables([path], LIMITS)
        except TableInputError as exc:
            _one_line(exc)
            return
    _check_read(tables)


@pytest.mark.slow  # a plant fit per accepted example: ~15 s
@settings(PROPERTY, max_examples=12)
@given(table_texts())
def test_an_accepted_table_is_fitted_to_finite_values_or_refused_in_one_line(text: str) -> None:
    try:
        (table,) = read_table(text, "fuzz.csv", LIMITS)
    except (TableInputError, ValueError):
        return
    try:
        _, fits, _, notes = identify_table(table, load_model(), config.tables())
    except TableInputError as exc:
        _one_line(exc)
        return
    for fit in fits:
        assert all(math.isfinite(v) and v > 0 for v in fit.values.values()), fit.values
        assert fit.singular or np.allclose(np.diag(fit.correlation), 1.0)
    assert all("\n" not in n for n in notes)


FIELD_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-3, 3),
    st.sampled_from([0.0, -0.0, 1e-320, 1e300, -1e-4, 0.02, 25.0, True, None, "x", "1e3", [1]]),
)


@st.composite
def calibrations(draw) -> dict:
    """A calibration whose fields are any values, some missing."""
    doc: dict = {}
    for channel in ("stroke", "pitch"):
        section = {"gain_deg_per_v": 25.0, "polarity": 1, "lag_s": 0.0002}
        for key in list(section):
            action = draw(st.sampled_from(["keep", "keep", "replace", "drop"]))
            if action == "replace":
                section[key] = draw(FIELD_VALUES)
            elif action == "drop":
                del section[key]
        doc[channel] = draw(st.sampled_from([section, section, section, None, 3, "s"]))
    return doc


def _yaml_value(v) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return ".nan"
        if math.isinf(v):
            return ".inf" if v > 0 else "-.inf"
        return repr(v)
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def _yaml(doc: dict) -> str:
    lines = []
    for channel, section in doc.items():
        if isinstance(section, dict):
            cells = ", ".join(f"{k}: {_yaml_value(v)}" for k, v in section.items())
            lines.append(f"{channel}: {{{cells}}}")
        else:
            lines.append(f"{channel}: {_yaml_value(section)}")
    return "\n".join(lines) + "\n"


@pytest.mark.slow  # property test: many calibrations
@settings(PROPERTY, max_examples=200)
@given(calibrations())
def test_a_calibration_gives_sound_lags_and_gains_or_one_line_naming_its_field(doc) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "calibration.yaml"
        path.write_text(_yaml(doc))
        try:
            got = film_calibration(path)
        except ParameterError as exc:
            _one_line(exc)
            assert "calibration_file" in str(exc)
            return
    for channel in ("stroke", "pitch"):
        assert 0.0 <= got[f"{channel}_film_delay_s"] <= MAX_FILM_LAG_S
        volts = got.get(f"{channel}_volts_per_rad")
        if volts is not None:
            assert math.isfinite(volts) and volts != 0.0
