"""The actuator's hysteresis (`actuator_hysteresis`, a Bouc-Wen operator on the drive): its
closed form, the textbook ODE integrated by scipy, the plant's torque and state across blocks,
and bad parameters refused by name.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from flaair_model.effects import ActuatorHysteresis
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.validation import ModelError
from flaair_sim.core.hysteresis_kernel import hysteretic_voltage
from flaair_sim.core.plant import PlantInputs, PlantStepParams, initial_state, simulate, step

FS_HZ = 20000.0
ALPHA, SATURATION_V = 0.3, 10.0
BETA = ALPHA / (2.0 * SATURATION_V)  # gamma = beta


def _lag(drive: np.ndarray, alpha: float = ALPHA, saturation_v: float = SATURATION_V):
    out = np.empty(drive.shape[0])
    hysteretic_voltage(np.ascontiguousarray(drive, float), alpha, saturation_v, np.zeros(2), out)
    return out


@pytest.fixture(scope="module")
def nominal():
    return load_model()


def _hysteretic(model, alpha: float = ALPHA, saturation_v: float = SATURATION_V):
    return with_effects(
        model, {"actuator_hysteresis": {"loop_fraction": alpha, "saturation_v": saturation_v}}
    )


@pytest.mark.parametrize("samples", [1, 7, 1000])
def test_a_rise_from_rest_follows_the_closed_form_whatever_the_steps(samples: int) -> None:
    amplitude = 40.0
    h = _lag(np.linspace(0.0, amplitude, samples + 1))
    expected = SATURATION_V * (1.0 - math.exp(-2.0 * BETA * amplitude))
    assert h[-1] == pytest.approx(expected, rel=1e-12)
    assert 0.0 < h[-1] < SATURATION_V


def test_after_a_reversal_the_lag_falls_at_the_loop_fraction_until_zero() -> None:
    top = SATURATION_V * (1.0 - math.exp(-2.0 * BETA * 40.0))
    down = np.concatenate([np.linspace(0.0, 40.0, 50), 40.0 - np.linspace(0.0, 60.0, 200)[1:]])
    h = _lag(down)
    fell = 40.0 - down[50:]
    linear = fell <= top / ALPHA
    np.testing.assert_allclose(h[50:][linear], top - ALPHA * fell[linear], rtol=0, atol=1e-12)
    past = fell[~linear] - top / ALPHA  # then it saturates towards -SATURATION_V
    np.testing.assert_allclose(
        h[50:][~linear], -SATURATION_V * (1.0 - np.exp(-2.0 * BETA * past)), rtol=0, atol=1e-12
    )


def test_the_operator_equals_the_textbook_bouc_wen_ode_integrated_by_scipy() -> None:
    """dh/dt = alpha v' - beta |v'| h - gamma v' |h| along the drive's samples joined by straight
    lines (the path the kernel takes between samples), by an adaptive integrator segment by
    segment: the kernel's exact jumps agree at every sample, across each reversal.
    """
    t = np.arange(int(0.012 * FS_HZ)) / FS_HZ
    v = 80.0 * np.sin(2 * np.pi * 100.0 * t) + 30.0 * np.sin(2 * np.pi * 270.0 * t)
    h, ode = 0.0, [0.0]
    for k in range(1, t.shape[0]):
        slope = (v[k] - v[k - 1]) * FS_HZ

        def rhs(_t, y, rate=slope):
            return [ALPHA * rate - BETA * abs(rate) * y[0] - BETA * rate * abs(y[0])]

        seg = solve_ivp(rhs, (0.0, 1.0 / FS_HZ), [h], method="DOP853", rtol=1e-12, atol=1e-13)
        assert seg.success
        h = float(seg.y[0, -1])
        ode.append(h)
    np.testing.assert_allclose(_lag(v), ode, rtol=0, atol=1e-9 * SATURATION_V)


def test_the_plant_sees_the_drive_less_the_lag_quasi_statically(nominal) -> None:
    """A 2 Hz drive, far below resonance: the stroke is G_a / K (V - h), so the loop's width at
    zero drive is G_a / K times the closed form's lag there, up and down.
    """
    model = _hysteretic(nominal)
    t = np.arange(int(1.0 * FS_HZ)) / FS_HZ
    drive = 60.0 * np.sin(2 * np.pi * 2.0 * t)
    stroke = simulate(drive, FS_HZ, model).stroke_rad
    static = model.plant.actuator_gain_nm_per_v / model.plant.stroke_stiffness_nm_per_rad
    h = _lag(drive)
    second = t >= 0.5  # the second cycle, on the major loop
    np.testing.assert_allclose(
        stroke[second], static * (drive - h)[second], rtol=0, atol=0.01 * static * 60.0
    )
    rising = second & (np.abs(drive) < 0.5) & (np.gradient(drive) > 0)
    falling = second & (np.abs(drive) < 0.5) & (np.gradient(drive) < 0)
    width = stroke[falling].mean() - stroke[rising].mean()
    assert width == pytest.approx(static * (h[rising].mean() - h[falling].mean()), rel=0.02)
    assert width > 0.1 * static * 60.0  # a loop of >5 % of the stroke's span


def test_block_by_block_equals_the_whole_record_and_the_state_carries_the_lag(nominal) -> None:
    model = _hysteretic(nominal)
    t = np.arange(4000) / FS_HZ
    drive = 90.0 * np.sin(2 * np.pi * 130.0 * t)
    whole = simulate(drive, FS_HZ, model)
    params = PlantStepParams(model, FS_HZ)
    state, parts = initial_state(params), []
    for i in range(0, drive.shape[0], 10):
        state, out = step(state, PlantInputs(drive[i : i + 10]), params)
        parts.append(out.stroke_rad)
    np.testing.assert_array_equal(np.concatenate(parts), whole.stroke_rad)
    assert state.actuator is not None
    assert state.actuator[0] == pytest.approx(_lag(drive)[-1], rel=1e-12)
    assert state.actuator[1] == drive[-1]


def test_the_feedthrough_sees_the_drive_itself(nominal) -> None:
    t = np.arange(2000) / FS_HZ
    drive = 100.0 * np.sin(2 * np.pi * 120.0 * t)
    feed = {"feedthrough": {"gain_v_per_v": 0.004}}
    both = simulate(drive, FS_HZ, with_effects(_hysteretic(nominal), feed))
    alone = simulate(drive, FS_HZ, _hysteretic(nominal))
    np.testing.assert_allclose(
        both.stroke_sensor_v - alone.stroke_sensor_v, 0.004 * drive, rtol=0, atol=1e-12
    )


def test_without_the_effect_the_plant_is_unchanged_bit_for_bit(nominal) -> None:
    t = np.arange(2000) / FS_HZ
    drive = 100.0 * np.sin(2 * np.pi * 120.0 * t)
    off = _hysteretic(nominal, alpha=0.0)
    np.testing.assert_array_equal(
        simulate(drive, FS_HZ, off).stroke_rad, simulate(drive, FS_HZ, nominal).stroke_rad
    )


@pytest.mark.parametrize(
    "params,named",
    [
        ({"loop_fraction": 1.0, "saturation_v": 10.0}, "loop_fraction must be below 1"),
        ({"loop_fraction": -0.1, "saturation_v": 10.0}, "loop_fraction"),
        ({"loop_fraction": 0.3, "saturation_v": 0.0}, "saturation_v"),
        ({"loop_fraction": math.nan, "saturation_v": 10.0}, "loop_fraction"),
    ],
)
def test_bad_parameters_are_refused_by_name(params: dict, named: str) -> None:
    with pytest.raises(ModelError, match=named):
        ActuatorHysteresis(**params)
