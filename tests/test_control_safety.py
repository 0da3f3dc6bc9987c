"""Drive safety core (flaair_control.core.safety): clamp, slew limit, watchdog."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from flaair_control.core import safety

FS = 20000.0

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
blocks = hnp.arrays(np.float64, st.integers(0, 64), elements=any_float)
params_st = st.builds(
    safety.SafetyParams,
    drive_limit_v=st.floats(0.0, 500.0),
    slew_limit_v_per_s=st.one_of(st.just(math.inf), st.floats(1.0, 1e8)),
    invalid_timeout_s=st.floats(1e-4, 1.0),
    ramp_down_s=st.floats(0.0, 1.0),
    sample_rate_hz=st.just(FS),
)


def sp(**kw) -> safety.SafetyParams:
    """Safety parameters: these tests' values, overridden by ``kw``."""
    base = dict(
        drive_limit_v=100.0,
        slew_limit_v_per_s=math.inf,
        invalid_timeout_s=0.01,
        ramp_down_s=0.05,
        sample_rate_hz=FS,
    )
    base.update(kw)
    return safety.SafetyParams(**base)


@settings(max_examples=300, deadline=None)
@given(block=blocks, limit=st.floats(0.0, 1e3))
def test_clamp_output_is_finite_and_within_limit(block, limit):
    y = safety.clamp(block, limit)
    assert y.shape == block.shape
    assert np.all(np.isfinite(y))
    assert np.all(np.abs(y) <= limit)
    finite = np.isfinite(block)
    np.testing.assert_array_equal(y[~finite], 0.0)  # NaN/inf -> 0
    np.testing.assert_array_equal(y[finite], np.clip(block[finite], -limit, limit))


@settings(max_examples=200, deadline=None)
@given(
    params=params_st,
    seq=st.lists(st.tuples(blocks, st.sampled_from([None, True, False])), min_size=1, max_size=8),
    t0=st.floats(-10.0, 10.0),
)
def test_step_never_exceeds_the_limit_or_the_slew_rate(params, seq, t0):
    state = safety.initial_state(params, t_s=t0)
    t = t0
    prev = 0.0
    for block, valid in seq:
        state, out = safety.step(state, safety.SafetyInputs(block, t, valid), params)
        y = out.drive_v
        assert y.shape == block.shape
        assert np.all(np.isfinite(y))
        assert np.all(np.abs(y) <= params.drive_limit_v)
        if y.size:
            steps = np.abs(np.diff(np.concatenate([[prev], y])))
            assert np.all(steps <= params.slew_limit_v_per_s / FS * (1 + 1e-12) + 1e-12)
            prev = y[-1]
        assert out.nonfinite_count == int(np.count_nonzero(~np.isfinite(block)))
        t += block.size / FS


def _sine(n, t0, amp=80.0, f=100.0):
    return amp * np.sin(2 * np.pi * f * (t0 + np.arange(n) / FS))


def test_passes_a_safe_drive_untouched_while_sensors_are_fresh():
    p = sp(drive_limit_v=100.0, slew_limit_v_per_s=1e6, invalid_timeout_s=2e-3, ramp_down_s=0.02)
    state = safety.initial_state(p)
    for k in range(200):
        t = k * 10 / FS
        d = _sine(10, t)
        state, out = safety.step(state, safety.SafetyInputs(d, t, True), p)
        np.testing.assert_array_equal(out.drive_v, d)
        assert not out.tripped


def test_timeout_trips_at_the_deadline_and_ramps_to_zero():
    p = sp(drive_limit_v=100.0, invalid_timeout_s=2e-3, ramp_down_s=0.01)
    state = safety.initial_state(p)
    for t_block in np.arange(0.0005, 0.0051, 0.0005):  # fresh blocks every 0.5 ms up to 5 ms
        state = safety.note_sensor_block(state, float(t_block), True, p)
    assert state.status == safety.OK
    # sensors go silent after t = 5 ms: deadline 7 ms
    outs, times = [], []
    for k in range(60):
        t = k * 10 / FS
        state, out = safety.step(state, safety.SafetyInputs(_sine(10, t), t), p)
        outs.append(out.drive_v)
        times.append(t + np.arange(10) / FS)
    y, t = np.concatenate(outs), np.concatenate(times)
    assert state.status == safety.TRIPPED and state.trip_reason == safety.REASON_TIMEOUT
    assert state.trip_time_s == pytest.approx(0.007)
    before = t < 0.007
    np.testing.assert_allclose(y[before], _sine(len(t), 0.0)[before])
    ramp = (t >= 0.007) & (t < 0.017)
    expected = _sine(len(t), 0.0) * np.clip(1 - (t - 0.007) / 0.01, 0, 1)
    np.testing.assert_allclose(y[ramp], expected[ramp], atol=1e-9)
    assert np.all(y[t >= 0.017] == 0.0)


def test_first_block_later_than_the_timeout_trips_at_the_deadline():
    p = sp(drive_limit_v=100.0, invalid_timeout_s=2e-3)
    state = safety.note_sensor_block(safety.initial_state(p), 0.005, True, p)
    assert state.status == safety.TRIPPED and state.trip_time_s == pytest.approx(0.002)


def test_invalid_block_trips_immediately_and_latches():
    p = sp(drive_limit_v=100.0, invalid_timeout_s=0.1, ramp_down_s=0.0)
    state = safety.initial_state(p)
    state, out = safety.step(state, safety.SafetyInputs(np.full(10, 50.0), 0.0, True), p)
    assert np.all(out.drive_v == 50.0)
    state, out = safety.step(state, safety.SafetyInputs(np.full(10, 50.0), 0.0005, False), p)
    assert out.tripped and state.trip_reason == safety.REASON_INVALID_BLOCK
    assert np.all(out.drive_v == 0.0)  # ramp_down_s = 0
    state, out = safety.step(state, safety.SafetyInputs(np.full(10, 50.0), 0.001, True), p)
    assert out.tripped and np.all(out.drive_v == 0.0)  # latched
    state = safety.reset(state, 0.0015)
    state, out = safety.step(state, safety.SafetyInputs(np.full(10, 50.0), 0.0015, True), p)
    assert not out.tripped and np.all(out.drive_v == 50.0)


def test_slew_limit_spreads_a_step():
    p = sp(drive_limit_v=100.0, slew_limit_v_per_s=2e5)  # 10 V per sample
    _state, out = safety.step(
        safety.initial_state(p), safety.SafetyInputs(np.full(12, 100.0), 0.0, True), p
    )
    np.testing.assert_allclose(out.drive_v, [10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 100, 100])


def test_nan_and_inf_drive_become_zero_not_rail():
    p = sp(drive_limit_v=100.0)
    d = np.array([np.nan, np.inf, -np.inf, 1e9, -1e9, 42.0])
    _, out = safety.step(safety.initial_state(p), safety.SafetyInputs(d, 0.0, True), p)
    np.testing.assert_array_equal(out.drive_v, [0, 0, 0, 100, -100, 42])
    assert out.nonfinite_count == 3


@pytest.mark.parametrize(
    "field,value",
    [
        ("drive_limit_v", -1.0),
        ("drive_limit_v", math.nan),
        ("slew_limit_v_per_s", 0.0),
        ("invalid_timeout_s", 0.0),
        ("ramp_down_s", -0.1),
    ],
)
def test_bad_parameters_are_named(field, value):
    with pytest.raises(ValueError, match=field):
        sp(**{field: value})
