"""flaair_sim.core.drive: closed-form generators and the sample-exact block form."""

from __future__ import annotations

import numpy as np
import pytest

from flaair_sim.core.drive import (
    DriveError,
    DriveParams,
    DriveState,
    chirp,
    drive_record,
    drive_step,
    sine,
    stepped_sine,
    stepped_sine_frequencies_hz,
)

FS_HZ = 20_000.0


def t_s(n: int) -> np.ndarray:
    return np.arange(n) / FS_HZ


def test_sine_closed_form():
    t = t_s(1000)
    v = sine(t, 100.0, 140.0, bias_v=5.0, phase_rad=0.3)
    np.testing.assert_allclose(
        v, 5.0 + 100.0 * np.sin(2 * np.pi * 140.0 * t + 0.3), rtol=0, atol=1e-12
    )
    assert v.max() == pytest.approx(105.0, abs=0.05)


def test_chirp_is_linear_and_phase_continuous():
    n = int(FS_HZ)
    t = t_s(n)
    v = chirp(t, 100.0, 20.0, 200.0, 1.0)
    np.testing.assert_allclose(
        v, 100.0 * np.sin(2 * np.pi * (20.0 * t + 90.0 * t**2)), rtol=0, atol=1e-9
    )
    # instantaneous frequency from upward zero crossings ramps linearly 20 -> 200 Hz
    up = np.flatnonzero((v[:-1] < 0) & (v[1:] >= 0))
    crossing_t = t[up]
    f_inst = 1.0 / np.diff(crossing_t)
    mid_t = 0.5 * (crossing_t[1:] + crossing_t[:-1])
    np.testing.assert_allclose(f_inst, 20.0 + 180.0 * mid_t, rtol=0.01)
    # past duration: continues at stop_hz without a phase jump
    longer = chirp(t_s(2 * n), 100.0, 20.0, 200.0, 1.0)
    assert np.array_equal(longer[:n], v)
    tail_t = t_s(2 * n)[n:]
    phase_at_end = 2 * np.pi * (20.0 + 90.0)
    np.testing.assert_allclose(
        longer[n:], 100.0 * np.sin(phase_at_end + 2 * np.pi * 200.0 * (tail_t - 1.0)), atol=1e-8
    )
    assert np.max(np.abs(np.diff(longer))) <= 2 * np.pi * 200.0 * 100.0 / FS_HZ * 1.001


def test_stepped_sine_segments_and_continuity():
    freqs = [100.0, 125.0, 150.0]
    drive, freq = stepped_sine(FS_HZ, 50.0, freqs, 0.05)
    dwell = 1000
    assert drive.shape == freq.shape == (3 * dwell,)
    assert np.array_equal(freq, np.repeat(freqs, dwell))
    # each segment is a sine of its frequency and amplitude, and the phase runs on across steps
    phase = 0.0
    for i, f in enumerate(freqs):
        local = t_s(dwell)
        np.testing.assert_allclose(
            drive[i * dwell : (i + 1) * dwell],
            50.0 * np.sin(phase + 2 * np.pi * f * local),
            atol=1e-9,
        )
        phase += 2 * np.pi * f * dwell / FS_HZ
    assert np.max(np.abs(np.diff(drive))) <= 2 * np.pi * 150.0 * 50.0 / FS_HZ * 1.001
    np.testing.assert_allclose(
        stepped_sine_frequencies_hz(100.0, 180.0, 5.0), np.arange(100.0, 181.0, 5.0)
    )


@pytest.mark.parametrize(
    "params, whole",
    [
        (
            DriveParams("sine", 100.0, bias_v=2.0, frequency_hz=137.0),
            lambda n: sine(t_s(n), 100.0, 137.0, 2.0),
        ),
        (
            DriveParams("chirp", 100.0, bias_v=-1.0, start_hz=20.0, stop_hz=200.0, duration_s=0.2),
            lambda n: -1.0 + chirp(t_s(n), 100.0, 20.0, 200.0, 0.2),
        ),
        (
            DriveParams(
                "stepped_sine", 80.0, start_hz=100.0, stop_hz=180.0, step_hz=20.0, dwell_s=0.01
            ),
            lambda n: stepped_sine(FS_HZ, 80.0, [100.0, 120.0, 140.0, 160.0, 180.0], 0.01)[0][:n],
        ),
    ],
)
def test_drive_step_is_sample_exact(params, whole):
    n = 1000
    blocks = []
    state = DriveState()
    sizes = np.random.default_rng(0).choice([0, 1, 7, 64, 200], size=400)
    for size in sizes:
        size = int(min(size, n - state.sample_index))
        state, block = drive_step(state, size, FS_HZ, params)
        blocks.append(block)
        if state.sample_index == n:
            break
    assert state.sample_index == n
    record = np.concatenate(blocks)
    assert np.array_equal(record, whole(n))
    assert np.array_equal(record, drive_record(params, FS_HZ, n))


@pytest.mark.parametrize(
    "kind, extra",
    [
        ("sine", {"frequency_hz": 140.0}),
        ("chirp", {"start_hz": 20.0, "stop_hz": 200.0, "duration_s": 0.05}),
    ],
)
def test_lead_in_is_zero_then_the_waveform_from_its_own_start(kind, extra):
    lead_s, n = 0.0123, 2000
    lead = round(lead_s * FS_HZ)
    plain = drive_record(DriveParams(kind, 50.0, **extra), FS_HZ, n - lead)
    delayed = DriveParams(kind, 50.0, lead_in_s=lead_s, **extra)
    record = drive_record(delayed, FS_HZ, n)
    assert np.all(record[:lead] == 0.0) and np.array_equal(record[lead:], plain)
    blocks, state = [], DriveState()
    while state.sample_index < n:  # block form: 10-sample blocks across the boundary
        state, block = drive_step(state, 10, FS_HZ, delayed)
        blocks.append(block)
    assert np.array_equal(np.concatenate(blocks), record)


def test_drive_step_long_run_stays_exact():
    params = DriveParams("sine", 1.0, frequency_hz=140.0)
    start = 10**8  # ~1.4 h at 20 kHz
    _, block = drive_step(DriveState(start), 100, FS_HZ, params)
    np.testing.assert_allclose(
        block, np.sin(2 * np.pi * 140.0 * (start + np.arange(100)) / FS_HZ), atol=1e-6
    )


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"kind": "square", "amplitude_v": 1.0}, "kind"),
        ({"kind": "sine", "amplitude_v": 1.0}, "frequency_hz"),
        ({"kind": "sine", "amplitude_v": float("nan"), "frequency_hz": 1.0}, "amplitude_v"),
        ({"kind": "chirp", "amplitude_v": 1.0, "start_hz": 10.0, "stop_hz": 20.0}, "duration_s"),
        (
            {
                "kind": "stepped_sine",
                "amplitude_v": 1.0,
                "start_hz": 10.0,
                "stop_hz": 20.0,
                "step_hz": 5.0,
            },
            "dwell_s",
        ),
        (
            {
                "kind": "stepped_sine",
                "amplitude_v": 1.0,
                "start_hz": 30.0,
                "stop_hz": 20.0,
                "step_hz": 5.0,
                "dwell_s": 1.0,
            },
            "stop_hz",
        ),
        ({"kind": "sine", "amplitude_v": 1.0, "frequency_hz": 1.0, "lead_in_s": -0.1}, "lead_in_s"),
    ],
)
def test_drive_params_validation_names_parameter(kwargs, name):
    with pytest.raises(DriveError, match=name):
        DriveParams(**kwargs)
    assert issubclass(DriveError, ValueError)


def test_multisine_blocks_equal_the_designed_realization_from_any_start():
    from flaair_analysis.multisine.design import design_multisine, realization_drive
    from flaair_sim.core.drive import DriveParams, DriveState, drive_record, drive_step

    d = design_multisine(
        band_hz=(100.0, 250.0), base_hz=2.0, lines_per_group=3, rms_v=25.0, periods=2,
        transient_periods=1, realizations=2, fs_hz=20000.0, max_v=100.0, seed=3,
    )  # fmt: skip
    params = DriveParams(
        kind="multisine",
        amplitude_v=d.amplitude_v,
        frequency_hz=d.base_frequency_hz,
        lines=tuple(float(k) for k in d.excited_lines),
        phases_rad=d.phases_rad[1],
        lead_in_s=0.01,
    )
    whole = drive_record(params, 20000.0, 200 + d.n_samples)
    np.testing.assert_array_equal(whole[:200], 0.0)
    np.testing.assert_allclose(whole[200:], realization_drive(d, 1), rtol=0, atol=1e-9)
    state, blocks = DriveState(), []
    for _ in range(len(whole) // 10):
        state, block = drive_step(state, 10, 20000.0, params)
        blocks.append(block)
    np.testing.assert_array_equal(np.concatenate(blocks), whole)
    with pytest.raises(DriveError, match="whole number of samples"):
        drive_record(DriveParams(**{**params.__dict__, "frequency_hz": 3.0}), 20000.0, 10)
    with pytest.raises(DriveError, match="lines and phases_rad"):
        DriveParams(kind="multisine", amplitude_v=1.0, frequency_hz=2.0, lines=(51.0,))
