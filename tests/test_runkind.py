"""Drive recognition (flaair_tools.analysis.runkind) on synthetic drives with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_model.config import node_parameters
from flaair_sim.core.drive import (
    DriveParams,
    drive_record,
    stepped_sine,
    stepped_sine_frequencies_hz,
)
from flaair_tools.analysis.runkind import RecognitionParams, RunKindError, recognise

FS = 20000.0
PARAMS = RecognitionParams.from_mapping(node_parameters("flaair.yaml", "analyze"))


def test_paper_stepped_sine_steps_are_found_from_the_drive() -> None:
    freqs = stepped_sine_frequencies_hz(60.0, 200.0, 10.0)
    drive, track = stepped_sine(FS, 100.0, freqs, 0.2)
    kind = recognise(drive + np.random.default_rng(0).normal(0, 0.2, drive.size), FS, PARAMS)
    assert kind.kind == "stepped_sine", kind.reason
    assert [round(s.frequency_hz, 2) for s in kind.steps] == pytest.approx(list(freqs), abs=0.02)
    for step, f in zip(kind.steps, freqs, strict=True):
        # every dwell lies inside its true 0.2 s step and holds most of it
        true_start = int(np.flatnonzero(track == f)[0])
        assert true_start <= step.start < step.stop <= true_start + 4000
        # the record's ends are unreliable
        edge = 1.5 * FS / f if f in (freqs[0], freqs[-1]) else 0.0
        assert step.stop - step.start >= 3500 - edge
    assert kind.drive_amplitude_v == pytest.approx(100.0, rel=0.02)
    recognised_track = kind.frequency_track(drive.size)
    inside = recognised_track > 0
    assert inside.mean() > 0.9 and np.max(np.abs(recognised_track[inside] - track[inside])) < 0.02


def test_paper_chirp_is_a_sweep_with_its_range() -> None:
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        FS,
        20000,
    )
    kind = recognise(drive, FS, PARAMS)
    assert kind.kind == "chirp", kind.reason
    assert kind.steps == ()
    assert 20.0 <= kind.sweep_hz[0] < 40.0 and kind.sweep_hz[1] == pytest.approx(200.0, abs=5.0)


def test_slow_chirp_is_not_mistaken_for_steps() -> None:
    """20 Hz/s: every 40 ms stays within tolerance, but it drifts, so it is no dwell."""
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=50.0, start_hz=100.0, stop_hz=160.0, duration_s=3.0),
        FS,
        60000,
    )
    assert recognise(drive, FS, PARAMS).kind == "chirp"


def test_single_sine_with_rest_before_it() -> None:
    t = np.arange(int(2.0 * FS)) / FS
    drive = np.where(t >= 0.25, 75.0 * np.sin(2 * np.pi * 100.0 * t), 0.0)
    kind = recognise(drive, FS, PARAMS)
    assert kind.kind == "sine", kind.reason
    assert kind.frequency_hz == pytest.approx(100.0, abs=1e-3)
    (step,) = kind.steps
    assert (
        0.25 * FS <= step.start <= 0.25 * FS + 300
        and step.stop >= drive.size - 1.5 * FS / 100.0 - 200
    )


def test_controller_drive_is_a_transition_and_no_drive_is_a_free_run() -> None:
    noise = np.random.default_rng(1).normal(0.0, 0.05, 20000)
    assert recognise(noise, FS, PARAMS).kind == "free"
    assert recognise(np.zeros(20000), FS, PARAMS).kind == "free"
    assert (
        recognise(100 * np.sin(np.arange(20000) / 20.0), FS, PARAMS, has_controller_state=True).kind
        == "transition"
    )


def test_random_drive_is_unrecognised() -> None:
    drive = np.random.default_rng(2).normal(0.0, 50.0, 20000)
    assert recognise(drive, FS, PARAMS).kind == "unrecognised"


def test_bad_parameters_are_named() -> None:
    values = dict(node_parameters("flaair.yaml", "analyze"))
    del values["min_dwell_s"]
    with pytest.raises(RunKindError, match="min_dwell_s"):
        RecognitionParams.from_mapping(values)
    values["min_dwell_s"] = float("nan")
    with pytest.raises(RunKindError, match="min_dwell_s"):
        RecognitionParams.from_mapping(values)


@settings(max_examples=25, deadline=None)
@given(
    start=st.floats(50.0, 150.0),
    step=st.floats(5.0, 30.0),
    n=st.integers(2, 6),
    dwell_s=st.floats(0.15, 0.3),
    amplitude=st.floats(10.0, 150.0),
)
def test_any_stepped_sine_is_recognised_with_its_frequencies(
    start: float, step: float, n: int, dwell_s: float, amplitude: float
) -> None:
    freqs = start + step * np.arange(n)
    drive, _ = stepped_sine(FS, amplitude, freqs, dwell_s)
    kind = recognise(drive, FS, PARAMS)
    assert kind.kind == "stepped_sine", kind.reason
    assert [s.frequency_hz for s in kind.steps] == pytest.approx(list(freqs), abs=0.05)


@settings(max_examples=25, deadline=None)
@given(
    frequency=st.floats(30.0, 300.0),
    amplitude=st.floats(5.0, 150.0),
    duration_s=st.floats(0.3, 2.0),
)
def test_any_sine_is_one_frequency(frequency: float, amplitude: float, duration_s: float) -> None:
    t = np.arange(int(duration_s * FS)) / FS
    kind = recognise(amplitude * np.sin(2 * np.pi * frequency * t + 0.3), FS, PARAMS)
    assert kind.kind == "sine", kind.reason
    assert kind.frequency_hz == pytest.approx(frequency, abs=0.01)
