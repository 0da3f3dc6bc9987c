"""Fault suite, issue 52: `health` and its calibration.

A calibration with a NaN, zero or overflowing gain, a wrong polarity, a lag of 1e300 or inf
(refused by its field, in the CLI and in the reader the live health node uses); a run logged at
10 kHz whose baseline could not be learned (said, and the scatter right at 10 kHz so the loss is
found); a chirp (outside what the monitor judges: said, no events). Each test fails on the code
before the fix.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from flaair_control.health_io import film_calibration
from flaair_model.schema import ParameterError
from rosproc import FLAAIR, isolated_env, run_offline

pytestmark = pytest.mark.timeout(120)

GOOD_CALIBRATION = {
    "stroke": {"gain_deg_per_v": 25.0, "polarity": 1, "lag_s": 0.00025},
    "pitch": {"gain_deg_per_v": 40.0, "polarity": -1, "lag_s": 0.0},
}

# (channel, field, value written in the YAML) -> the field the refusal names
BAD_FIELDS = [
    ("stroke", "gain_deg_per_v", ".nan"),
    ("pitch", "gain_deg_per_v", "0"),
    ("stroke", "gain_deg_per_v", "1e-320"),  # 1 / radians(gain) overflows to inf V/rad
    ("pitch", "polarity", "2"),
    ("stroke", "polarity", "0"),
    ("stroke", "lag_s", "1e300"),
    ("pitch", "lag_s", ".inf"),
    ("pitch", "lag_s", ".nan"),
]


def _calibration(path: Path, channel: str = "", field: str = "", value: str = "") -> Path:
    lines = []
    for c, fields in GOOD_CALIBRATION.items():
        cells = {k: str(v) for k, v in fields.items()}
        if c == channel:
            cells[field] = value
        lines.append(f"{c}: {{{', '.join(f'{k}: {v}' for k, v in cells.items())}}}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_sound_calibration_gives_lags_and_gains(tmp_path) -> None:
    got = film_calibration(_calibration(tmp_path / "cal.yaml"))
    assert got["stroke_film_delay_s"] == 0.00025 and got["pitch_film_delay_s"] == 0.0
    assert got["pitch_volts_per_rad"] < 0 < got["stroke_volts_per_rad"]


@pytest.mark.parametrize(("channel", "field", "value"), BAD_FIELDS)
def test_a_bad_calibration_value_is_refused_by_its_field(channel, field, value, tmp_path) -> None:
    cal = _calibration(tmp_path / "cal.yaml", channel, field, value)
    with pytest.raises(ParameterError, match=rf"{channel}\.{field}") as info:
        film_calibration(cal)  # what the live health node is given
    assert "\n" not in str(info.value) and "division" not in str(info.value)


@pytest.mark.parametrize(("channel", "field", "value"), BAD_FIELDS[:2] + BAD_FIELDS[5:6])
def test_health_refuses_a_bad_calibration_in_one_line(channel, field, value, tmp_path) -> None:
    cal = _calibration(tmp_path / "cal.yaml", channel, field, value)
    bag = tmp_path / "run.mcap"  # never read: the calibration is refused first
    bag.write_bytes(b"")
    out = tmp_path / "out"
    result = run_offline(
        [FLAAIR, "health", str(bag), "--out", str(out), "--calibration", str(cal)],
        isolated_env(),
    )
    err = result.stderr.strip()
    assert result.returncode == 2, (result.stdout, err)
    assert f"{channel}.{field}" in err and "\n" not in err and "Traceback" not in err, err
    assert not out.exists()
