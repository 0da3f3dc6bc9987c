"""Property tests (hypothesis) on the cores the nodes step block by block: any finite input
block gives finite output, or a documented error (a ValueError subclass naming the input).

The front end, the safety core and the CDR codec have their own property tests
(test_sensors_frontend.py, test_control_safety.py, test_cdr.py).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from flaair_control.core import collision, dsa, spectral
from flaair_control.monitor_io import monitor_windows_from_config
from flaair_model.model_io import load_model
from flaair_sim.core import drive, plant

FS_HZ = 20000.0
LIMIT_V = 150.0
MODEL = load_model()
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def blocks(bound: float, max_blocks: int = 6):
    """A few 10-sample blocks of finite floats within +-bound."""
    element = st.floats(-bound, bound, allow_nan=False, allow_infinity=False, width=64)
    return st.lists(arrays(np.float64, 10, elements=element), min_size=1, max_size=max_blocks)


@SETTINGS
@given(sequence=blocks(LIMIT_V, max_blocks=20))
def test_plant_step_in_the_actuator_range_stays_finite(sequence) -> None:
    state = plant.initial_state(plant.PlantStepParams(MODEL, FS_HZ))
    for drive_v in sequence:
        state, out = plant.step(
            state, plant.PlantInputs(drive_v), plant.PlantStepParams(MODEL, FS_HZ)
        )
        for name in ("stroke_rad", "pitch_rad", "stroke_sensor_v", "pitch_sensor_v"):
            assert np.isfinite(getattr(out, name)).all(), name


@SETTINGS
@given(sequence=blocks(1e300, max_blocks=3))
def test_plant_step_any_finite_drive_is_finite_or_refused(sequence) -> None:
    """The nodes clamp to drive_limit_v first; the core itself either stays finite or refuses."""
    state = plant.initial_state(plant.PlantStepParams(MODEL, FS_HZ))
    for drive_v in sequence:
        try:
            state, out = plant.step(
                state, plant.PlantInputs(drive_v), plant.PlantStepParams(MODEL, FS_HZ)
            )
        except ValueError as exc:
            assert "drive" in str(exc)
            return
        assert np.isfinite(out.stroke_rad).all() and np.isfinite(out.stroke_sensor_v).all()


def _dsa_params() -> dsa.DsaParams:
    return dsa.DsaParams(
        r3_rad_s=180.0,
        kappa=0.5,
        mu_nm_s_per_rad=1e-3,
        actuator_gain_nm_per_v=1.67e-7,
        sample_rate_hz=FS_HZ,
        drive_limit_v=LIMIT_V,
        sync_amplitude_v=20.0,
        sync_frequency_hz=90.0,
        sync_phase_rad=0.0,
        kr_schedule=dsa.KrSchedule(1.0, 0.0, 0.0, 0.001),
        loop_delay_s=0.00075,
        compensation_frequency_hz=145.0,
    )


@SETTINGS
@given(sequence=blocks(1e6, max_blocks=40), nan_at=st.one_of(st.none(), st.integers(0, 9)))
def test_dsa_step_output_is_finite_and_within_the_limit(sequence, nan_at) -> None:
    """Any finite velocity (and NaN samples, which drive
    the filter as 0): drive finite, |drive| <= limit.
    """
    params = _dsa_params()
    state = dsa.initial_state(params)
    t_s = 0.0
    for velocity in sequence:
        if nan_at is not None:
            velocity = velocity.copy()
            velocity[nan_at] = math.nan
        state, (drive_v, _) = dsa.step(state, dsa.DsaInputs(velocity, t_s), params)
        assert np.isfinite(drive_v).all() and np.abs(drive_v).max() <= LIMIT_V
        t_s += velocity.size / FS_HZ


@SETTINGS
@given(
    stroke=blocks(math.pi, max_blocks=30),
    pitch=blocks(math.pi, max_blocks=30),
    source=st.sampled_from(["drive", "stroke"]),
)
def test_collision_monitor_reports_finite_verdicts(stroke, pitch, source) -> None:
    params = replace(monitor_windows_from_config(100.0), window_source=source, arm_wingbeats=0)
    state = collision.initial_state(params)
    n = min(len(stroke), len(pitch))
    for s, p in zip(stroke[:n], pitch[:n], strict=True):
        state, (report, events) = collision.step(state, collision.MonitorInputs(s, p), params)
        for field in report._fields:
            values = np.asarray(getattr(report, field))
            if values.dtype.kind == "f":
                # a window may be judged unusable (NaN score
                # is documented as "no verdict"), never inf
                assert not np.isinf(values).any(), field
        assert all(e.kind in ("onset", "clearance") or isinstance(e.kind, int) for e in events)


def test_collision_monitor_refuses_mismatched_blocks_by_name() -> None:
    params = monitor_windows_from_config(100.0)
    with pytest.raises(spectral.CollisionParameterError, match="stroke_rad and pitch_rad"):
        collision.step(
            collision.initial_state(params),
            collision.MonitorInputs(np.zeros(10), np.zeros(9)),
            params,
        )


@SETTINGS
@given(
    amplitude_v=st.floats(0, 300),
    frequency_hz=st.floats(0.1, 5000),
    lead_in_s=st.floats(0, 0.01),
    n=st.integers(0, 500),
)
def test_drive_blocks_are_finite_and_bounded_by_amplitude(
    amplitude_v, frequency_hz, lead_in_s, n
) -> None:
    params = drive.DriveParams("sine", amplitude_v, frequency_hz=frequency_hz, lead_in_s=lead_in_s)
    _, block = drive.drive_step(drive.DriveState(), n, FS_HZ, params)
    assert (
        block.shape == (n,)
        and np.isfinite(block).all()
        and np.all(np.abs(block) <= amplitude_v + 1e-9)
    )
