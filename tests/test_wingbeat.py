"""Per-wingbeat summary core against closed forms: sines of known amplitude and frequency."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flaair_analysis import wingbeat

FS = 20000.0
PARAMS = wingbeat.WingbeatParams(
    sample_rate_hz=FS, hysteresis_deg=2.0, min_frequency_hz=30.0, max_frequency_hz=400.0
)


def _sines(
    amplitude_deg: float,
    frequency_hz: float,
    pitch_deg: float,
    duration_s: float,
    phase_rad: float = 0.3,
):
    t = np.arange(int(duration_s * FS)) / FS
    stroke = amplitude_deg * np.sin(2 * np.pi * frequency_hz * t + phase_rad)
    pitch = pitch_deg * np.sin(2 * np.pi * frequency_hz * t + phase_rad + 1.0)
    return stroke, pitch, np.ones(t.size, bool)


@pytest.mark.parametrize(
    "amplitude_deg,frequency_hz,pitch_deg",
    [(20.5, 144.2, 35.0), (6.5, 90.0, 3.0), (40.0, 211.7, 50.0)],
)
def test_sine_gives_its_amplitude_frequency_and_pitch_amplitude(
    amplitude_deg, frequency_hz, pitch_deg
) -> None:
    stroke, pitch, valid = _sines(amplitude_deg, frequency_hz, pitch_deg, 0.5, phase_rad=0.3)
    beats = wingbeat.summarize(stroke, pitch, valid, PARAMS)
    # first crossing after t=0 (phase 0.3 rad) starts
    # the count; every full period after is one wingbeat
    first_crossing_s = (2 * np.pi - 0.3) / (2 * np.pi * frequency_hz)
    expected = int(np.floor((0.5 - 1 / FS - first_crossing_s) * frequency_hz))
    assert len(beats.amplitude_deg) == expected
    # a sampled peak lies within A (1 - cos(pi f / fs)) below
    # the true one; crossing interpolation ~(pi f / fs)^3
    worst = 1 - np.cos(np.pi * frequency_hz / FS)
    for measured, true in (
        (beats.amplitude_deg, amplitude_deg),
        (beats.pitch_amplitude_deg, pitch_deg),
    ):
        assert np.all(measured <= true * (1 + 1e-12)) and np.all(measured >= true * (1 - worst))
    np.testing.assert_allclose(beats.frequency_hz, frequency_hz, rtol=1e-5)
    # crossings sit where the sine crosses zero upward: t = (2 pi k - phase) / (2 pi f)
    k = np.arange(1, expected + 2)
    np.testing.assert_allclose(
        beats.start_sample,
        ((2 * np.pi * k - 0.3) / (2 * np.pi * frequency_hz) * FS)[:expected],
        atol=1e-3,
    )
    assert np.all(np.isnan(beats.collision_score)) and np.all(np.isnan(beats.k_r))


def test_blocks_of_ten_equal_the_whole_record_and_carry_the_latest_slow_values() -> None:
    stroke, pitch, valid = _sines(20.0, 140.0, 30.0, 0.3)
    whole = wingbeat.summarize(stroke, pitch, valid, PARAMS)
    state, parts = wingbeat.initial_state(PARAMS), []
    for first in range(0, stroke.size, 10):
        score, k_r = first / stroke.size, 1.0 - first / stroke.size
        inputs = wingbeat.WingbeatInputs(
            first,
            stroke[first : first + 10],
            pitch[first : first + 10],
            valid[first : first + 10],
            score,
            k_r,
        )
        state, out = wingbeat.step(state, inputs, PARAMS)
        parts.append(out)
        assert np.all(out.collision_score == score) and np.all(out.k_r == k_r)
    blocks = wingbeat.concatenate(parts)
    for name in (
        "start_sample",
        "end_sample",
        "amplitude_deg",
        "frequency_hz",
        "pitch_amplitude_deg",
    ):
        np.testing.assert_array_equal(getattr(blocks, name), getattr(whole, name))
    # the slow values are those of the block that ended each wingbeat
    np.testing.assert_allclose(
        blocks.collision_score, (np.floor(blocks.end_sample / 10) * 10) / stroke.size, atol=0.01
    )


def test_invalid_samples_idle_wing_and_gaps_drop_wingbeats() -> None:
    stroke, pitch, valid = _sines(20.0, 100.0, 30.0, 0.2)
    clean = wingbeat.summarize(stroke, pitch, valid, PARAMS)
    valid[1000] = False  # inside the wingbeat from ~sample 995 (crossings every 200 samples)
    broken = wingbeat.summarize(stroke, pitch, valid, PARAMS)
    assert len(broken.amplitude_deg) == len(clean.amplitude_deg) - 1  # only the wingbeat holding it
    assert not np.any((broken.start_sample < 1000) & (broken.end_sample > 1000))
    # below the hysteresis nothing arms: no wingbeats from a 1.5 deg wobble
    small, pitch_small, ok = _sines(1.5, 140.0, 3.0, 0.2)
    assert wingbeat.summarize(small, pitch_small, ok, PARAMS).amplitude_deg.size == 0
    # 20 Hz is below min_frequency_hz: not a wingbeat
    slow, pitch_slow, ok = _sines(20.0, 20.0, 3.0, 0.5)
    assert wingbeat.summarize(slow, pitch_slow, ok, PARAMS).amplitude_deg.size == 0
    # a gap in the stream starts over
    state, _ = wingbeat.step(
        wingbeat.initial_state(PARAMS),
        wingbeat.WingbeatInputs(0, stroke[:500], pitch[:500], valid[:500], math.nan, math.nan),
        PARAMS,
    )
    state, out = wingbeat.step(
        state,
        wingbeat.WingbeatInputs(
            600, stroke[600:900], pitch[600:900], valid[600:900], math.nan, math.nan
        ),
        PARAMS,
    )
    assert out.start_sample.size == 0 or out.start_sample[0] > 600


def test_parameters_and_inputs_are_checked_by_name() -> None:
    with pytest.raises(wingbeat.WingbeatParameterError, match="hysteresis_deg"):
        wingbeat.WingbeatParams(
            sample_rate_hz=FS, hysteresis_deg=-1.0, min_frequency_hz=30.0, max_frequency_hz=400.0
        )
    with pytest.raises(wingbeat.WingbeatParameterError, match="max_frequency_hz"):
        wingbeat.WingbeatParams(
            sample_rate_hz=FS, hysteresis_deg=1.0, min_frequency_hz=300.0, max_frequency_hz=200.0
        )
    with pytest.raises(wingbeat.WingbeatParameterError, match="one length"):
        wingbeat.summarize(np.zeros(10), np.zeros(9), np.ones(10, bool), PARAMS)
    assert wingbeat.collision_score(3.23, 1.0) == pytest.approx(3.23)
