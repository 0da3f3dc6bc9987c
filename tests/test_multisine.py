"""The multisine core against the classic results (../shared/multisine.md): the design's lines
and RMS, a linear system at noise-level distortion with its noise estimate equal to the noise
injected, a static cubic with odd distortion only and a static quadratic with even only at the
closed-form levels (within 1 dB), an even nonlinearity inside dynamics showing odd lines too,
the transient found from the sensors, the model comparison and the localisation reading.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import signal

from flaair_analysis.multisine import nld
from flaair_analysis.multisine.analysis import (
    MultisineInputError,
    RunInput,
    analyse,
    find_design,
)
from flaair_analysis.multisine.design import DesignError, design_multisine, realization_drive
from flaair_analysis.multisine.localise import localise
from multisine_systems import (
    cubic_power,
    db,
    drives,
    noise_line_power,
    square_power,
    static_design,
)

pytestmark = pytest.mark.timeout(60)


def _runs(design, outputs, pitch=None, drive=None):
    fs = design.fs_hz
    u = drives(design) if drive is None else drive
    runs = []
    for m in range(design.realizations):
        cols = {
            "time_s": np.arange(u.shape[1]) / fs,
            "drive_v": u[m],
            "stroke_sensor_v": outputs[m],
            "pitch_sensor_v": outputs[m] if pitch is None else pitch[m],
        }
        runs.append(RunInput(f"run_{m + 1}.csv", fs, cols))
    return runs


def test_the_default_design_has_the_contracts_lines_rms_and_period() -> None:
    d = design_multisine(
        band_hz=(100.0, 250.0),
        base_hz=2.0,
        lines_per_group=3,
        rms_v=25.0,
        periods=4,
        transient_periods=1,
        realizations=4,
        fs_hz=20000.0,
        max_v=100.0,
        seed=51,
    )
    assert d.period_samples == 10000
    assert (len(d.excited_lines), len(d.odd_detection_lines)) == (26, 12)
    assert d.excited_lines[0] == 51 and d.excited_lines[-1] == 125
    assert all(k % 2 == 1 for k in d.excited_lines + d.odd_detection_lines)
    assert not set(d.excited_lines) & set(d.odd_detection_lines)
    groups = [range(53 + 6 * g, 59 + 6 * g, 2) for g in range(12)]
    assert all(sum(k in d.odd_detection_lines for k in g) == 1 for g in groups)
    u = realization_drive(d, 0)
    assert u.size == 50000
    assert np.sqrt(np.mean(u**2)) == pytest.approx(25.0, rel=1e-9)
    assert 2.0 * 25 < np.abs(u).max() <= 100.0
    np.testing.assert_allclose(u[10000:20000], u[:10000], atol=1e-9)
    with pytest.raises(DesignError, match="--max-v"):
        design_multisine(
            band_hz=(100.0, 250.0), base_hz=2.0, lines_per_group=3, rms_v=25.0, periods=4,
            transient_periods=1, realizations=4, fs_hz=20000.0, max_v=40.0, seed=51,
        )  # fmt: skip
    with pytest.raises(DesignError, match="whole number"):
        design_multisine(
            band_hz=(100.0, 250.0), base_hz=3.0, lines_per_group=3, rms_v=25.0, periods=4,
            transient_periods=1, realizations=4, fs_hz=20000.0, max_v=100.0, seed=51,
        )  # fmt: skip


def test_a_linear_system_reads_noise_level_distortion_and_the_injected_noise() -> None:
    d = static_design(periods=4)
    u = drives(d)
    b, a = [0.2, 0.1], [1.0, -0.6]
    sigma = 1e-3
    rng = np.random.default_rng(1)
    y = signal.lfilter(b, a, u, axis=1) + sigma * rng.standard_normal(u.shape)
    result = analyse(_runs(d, y))
    assert result.design.transient_periods == 1  # found from the drive and the sensors
    ch = result.doc["channels"]["stroke_sensor_v"]
    expected_noise = db(noise_line_power(sigma, d.period_samples, d.periods))
    assert ch["levels_db"]["noise"] == pytest.approx(expected_noise, abs=0.5)
    assert ch["levels_db"]["odd"] == pytest.approx(expected_noise, abs=1.0)
    assert ch["levels_db"]["even"] == pytest.approx(expected_noise, abs=1.0)
    assert ch["class"] == "linear"
    f = np.array([e["freq_hz"] for e in ch["bla"]])
    _, h = signal.freqz(b, a, worN=f, fs=d.fs_hz)
    g = np.array([e["mag"] * np.exp(1j * np.radians(e["phase_deg"])) for e in ch["bla"]])
    std = np.array([e["std_noise"] for e in ch["bla"]])
    assert np.all(np.abs(g - h) < 5 * std + 1e-12)
    # std_noise agrees with the injected noise: sigma_G^2 = noise line power / |U|^2 / M
    u_line = d.amplitude_v / np.sqrt(2.0)
    want = np.sqrt(noise_line_power(sigma, d.period_samples, d.periods) / u_line**2 / 4)
    assert np.median(std) == pytest.approx(want, rel=0.15)


def test_a_static_cubic_reads_odd_only_at_the_closed_form_level() -> None:
    d = static_design()
    u = drives(d)
    c, sigma = 0.05, 1e-5
    y = u + c * u**3 + sigma * np.random.default_rng(2).standard_normal(u.shape)
    ch = analyse(_runs(d, y)).doc["channels"]["stroke_sensor_v"]
    sets = nld.line_sets(d.excited_lines)
    noise = noise_line_power(sigma, d.period_samples, d.periods)
    expected_odd = db(float(np.mean(cubic_power(d, c, sets.odd))) + noise)
    assert ch["levels_db"]["odd"] == pytest.approx(expected_odd, abs=1.0)
    assert ch["levels_db"]["even"] == pytest.approx(db(noise), abs=1.0)
    assert ch["class"] == "odd"


def test_a_static_quadratic_reads_even_only_at_the_closed_form_level() -> None:
    d = static_design()
    u = drives(d)
    c, sigma = 0.05, 1e-5
    y = u + c * u**2 + sigma * np.random.default_rng(3).standard_normal(u.shape)
    ch = analyse(_runs(d, y)).doc["channels"]["stroke_sensor_v"]
    sets = nld.line_sets(d.excited_lines)
    noise = noise_line_power(sigma, d.period_samples, d.periods)
    expected_even = db(float(np.mean(square_power(d, c, sets.even))) + noise)
    assert ch["levels_db"]["even"] == pytest.approx(expected_even, abs=1.0)
    assert ch["levels_db"]["odd"] == pytest.approx(db(noise), abs=1.0)
    assert ch["class"] == "even"


def _quadratic_feedback(u: np.ndarray, c: float) -> np.ndarray:
    y = np.zeros_like(u)
    for m in range(u.shape[0]):
        prev = 0.0
        for n in range(u.shape[1]):
            prev = 0.5 * prev + 0.3 * u[m, n] - c * prev * prev
            y[m, n] = prev
    return y


def test_an_even_nonlinearity_inside_dynamics_shows_odd_lines_too() -> None:
    d = static_design()
    u = drives(d)
    sigma = 1e-6
    noise = sigma * np.random.default_rng(4).standard_normal(u.shape)
    inside = analyse(_runs(d, _quadratic_feedback(u, 0.05) + noise))
    ch = inside.doc["channels"]["stroke_sensor_v"]
    assert ch["class"] == "odd+even"
    assert ch["levels_db"]["odd"] > ch["levels_db"]["noise"] + 20.0
    # the same square outside the loop (static, after the linear part) leaves the odd lines alone
    lin = signal.lfilter([0.3], [1.0, -0.5], u, axis=1)
    outside = analyse(_runs(d, lin - 0.05 * lin**2 + noise)).doc["channels"]["stroke_sensor_v"]
    assert outside["class"] == "even"


def test_the_transient_is_found_and_dropped() -> None:
    d = static_design(periods=4)
    u = drives(d)
    noise = 1e-6 * np.random.default_rng(5).standard_normal(u.shape)
    fast = signal.lfilter([0.3], [1.0, -0.5], u, axis=1) + noise
    assert analyse(_runs(d, fast)).design.transient_periods == 1
    pole = np.exp(-1.5 / d.period_samples)  # settles by e^-1.5 a period
    slow = signal.lfilter([1.0 - pole], [1.0, -pole], u, axis=1) + noise
    found = analyse(_runs(d, slow)).design
    assert found.transient_periods == 3 and found.periods == 2
    with_design = analyse(_runs(d, slow), d).design  # the design's T wins
    assert (with_design.transient_periods, with_design.source) == (1, "design")


def test_a_chirp_a_short_run_an_even_line_and_a_repeated_realization_are_refused() -> None:
    d = static_design()
    u = drives(d)
    runs = _runs(d, u)
    t = np.arange(u.shape[1]) / d.fs_hz
    chirp = dict(runs[0].columns, drive_v=signal.chirp(t, 10, t[-1], 300))
    with pytest.raises(MultisineInputError, match=re.escape("run_1.csv: no periodic excitation")):
        find_design([RunInput("run_1.csv", d.fs_hz, chirp)], None)
    short = {k: v[: 2 * d.period_samples + 10] for k, v in runs[1].columns.items()}
    with pytest.raises(
        MultisineInputError, match=re.escape("run_2.csv: holds fewer than 2 whole periods")
    ):
        find_design([runs[0], RunInput("run_2.csv", d.fs_hz, short)], d)
    even = dict(runs[0].columns, drive_v=u[0] + np.cos(2 * np.pi * 20 * t))
    with pytest.raises(MultisineInputError, match=re.escape("not an odd multisine (even line 20")):
        find_design([RunInput("x.csv", d.fs_hz, even)], None)
    with pytest.raises(
        MultisineInputError, match=re.escape("run_2.csv: repeats the realization of run_1")
    ):
        find_design([runs[0], RunInput("run_2.csv", d.fs_hz, runs[0].columns)], None)
    other = static_design(seed=99)
    with pytest.raises(MultisineInputError, match="another design than --design"):
        find_design(_runs(other, drives(other)), d)


def test_a_saturated_sensor_is_refused() -> None:
    d = static_design()
    u = drives(d)
    y = u.copy()
    y[1] = np.clip(u[1], -1.0, np.inf)  # run 2 stops at -1 (rms 1)
    with pytest.raises(
        MultisineInputError, match=re.escape("run_2.csv: stroke_sensor_v saturated")
    ):
        analyse(_runs(d, y))


def test_the_model_comparison_names_only_the_distortion_the_model_lacks() -> None:
    d = static_design()
    u = drives(d)
    rng = np.random.default_rng(6)
    base = u + 0.05 * u**3  # both measured and model share this odd distortion
    measured = base + 0.03 * u**2 + 1e-5 * rng.standard_normal(u.shape)
    model = [{c: base[m] for c in ("stroke_sensor_v", "pitch_sensor_v")} for m in range(4)]
    runs = _runs(d, measured, pitch=base + 1e-5 * rng.standard_normal(u.shape))
    doc = analyse(runs, None, model).doc
    stroke, pitch = doc["channels"]["stroke_sensor_v"], doc["channels"]["pitch_sensor_v"]
    assert stroke["class"] == "odd+even" and stroke["model"]["class"] == "odd"
    assert stroke["disagrees"] == ["even"]
    assert pitch["disagrees"] == []
    assert pitch["model"]["unexplained_db"]["odd"] == pytest.approx(
        pitch["levels_db"]["noise"], abs=1.0
    )


def test_the_localisation_reading() -> None:
    def chans(**disagree):
        names = ("stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg")
        return {n: {"class": "linear", "disagrees": disagree.get(n, [])} for n in names}

    film = localise(chans(pitch_sensor_v=["even"]), {}, True)["findings"]
    assert film == [
        {
            "distortion": "even",
            "channels": ["pitch_sensor_v"],
            "points_to": "the hinge film (the pitch video does not show it)",
            "sites": ["pitch_sensor_v"],
        }
    ]
    hinge = localise(chans(pitch_sensor_v=["even"], pitch_deg=["even"]), {}, True)
    assert hinge["findings"][0]["points_to"] == "the hinge"
    assert hinge["findings"][0]["sites"] == ["pitch_dynamics"]
    stroke = localise(chans(stroke_sensor_v=["even"], pitch_sensor_v=["even"]), {}, True)
    assert stroke["findings"][0]["points_to"].startswith("the stroke or the drive")
    odd = localise(chans(stroke_sensor_v=["odd"], pitch_sensor_v=["odd"]), {}, True)
    assert "stiffening, saturation" in odd["findings"][0]["points_to"]


def test_odd_distortion_growing_with_the_drive_level_points_to_stiffening_or_saturation() -> None:
    d = static_design()
    u = drives(d)
    u[2:] *= 2.0  # realizations 3 and 4 at twice the drive: 6 dB up
    rng = np.random.default_rng(8)
    cubic = u + 0.002 * u**3 + 1e-5 * rng.standard_normal(u.shape)
    runs = _runs(d, cubic, pitch=0.5 * u + 1e-5 * rng.standard_normal(u.shape), drive=u)
    doc = analyse(runs).doc
    trend = doc["localisation"]["level_trend"]["stroke_sensor_v"]
    assert [round(t["rms_v"], 6) for t in trend] == [1.0, 2.0]
    rise = (trend[1]["odd_db"] - trend[1]["signal_db"]) - (
        trend[0]["odd_db"] - trend[0]["signal_db"]
    )
    assert rise == pytest.approx(12.0, abs=1.0)  # a cubic: odd / signal power goes as A^4
    (odd,) = doc["localisation"]["findings"]
    assert odd["grows_with_level"] == ["stroke_sensor_v"]
    assert odd["points_to"].startswith("stiffening or saturation")
    assert doc["channels"]["pitch_sensor_v"]["class"] == "linear"
