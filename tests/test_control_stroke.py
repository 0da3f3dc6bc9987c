"""Stroke-amplitude controller core (flaair_control.core.stroke):
design, tracker, law, safety chain; node over DDS.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_control.core import hopf, safety, stroke
from flaair_model.config import node_parameters
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm
from flaair_sim.core import plant
from flaair_sim.core.plant_params import P_CSTRUCT, coefficients

FS = 20000.0


# set a parameter of the running node through its parameter service (rclpy's own client)
@pytest.fixture(scope="module")
def nominal():
    model = load_model()
    return (
        model,
        stroke.StrokePlant.from_model(model),
        node_parameters("flaair.yaml", "stroke_controller_node"),
    )


def _sync_params(values, design_plant, setpoint=15.0, **over):
    return stroke.params_from_values(
        {**values, "mode": "sync", "setpoint_deg": setpoint, **over}, design_plant, FS, 0.0
    )


def test_sync_design_at_resonance_is_the_quadratic_damping_balance_and_the_plant_agrees(
    nominal,
) -> None:
    model, design_plant, _ = nominal
    u, slope = stroke.design(design_plant, "sync", 15.0, sync_frequency_hz=140.0)
    # on resonance K = I w^2: G_a V = A w (8/3pi) Gamma w A  ->  A ~ sqrt(V): slope exactly 1/2
    w = 2 * math.pi * 140.0
    a = math.radians(15.0)
    # (the design reads the kernel's torques by their describing function: 1e-6 of the closed form)
    assert u == pytest.approx(a * w * 8 / (3 * math.pi) * 4.0e-11 * w * a / 1.67e-7, rel=1e-6)
    assert slope == pytest.approx(0.5, abs=1e-6)
    t = np.arange(int(0.6 * FS)) / FS
    out = plant.simulate(u * np.sin(w * t), FS, model)
    tail = np.degrees(out.stroke_rad[-int(0.1 * FS) :])
    assert 0.5 * np.ptp(tail) == pytest.approx(15.0, rel=0.02)  # describing function vs RK4 plant


def _limit_cycle_deg(model, mu: float, values, damping: float = 0.0) -> float:
    """The closed-form limit cycle (`hopf.limit_cycle`: quadratic damping, linear spring)."""
    pl = model.plant
    lin = hopf.LinearStrokePlant(pl.stroke_inertia_kg_m2, pl.stroke_stiffness_nm_per_rad, damping)
    return math.degrees(
        hopf.limit_cycle(
            lin, pl.aero_damping_nm_s2, values["r3_rad_s"], values["kappa"], mu
        ).amplitude_rad
    )


def test_dsa_design_inverts_the_hopf_limit_cycle(nominal) -> None:
    model, design_plant, values = nominal
    mu, slope = stroke.design(
        design_plant, "dsa", 15.0, r3_rad_s=values["r3_rad_s"], kappa=values["kappa"]
    )
    assert _limit_cycle_deg(model, mu, values) == pytest.approx(15.0, rel=1e-6)
    assert _limit_cycle_deg(model, 1.1 * mu, values) > 15.0
    assert 0.5 < slope < 2.0


def test_a_structural_damping_in_the_model_reaches_the_dsa_design(nominal) -> None:
    model, _, values = nominal
    damped = with_effects(model, {"structural_damping": {"damping_ratio": 0.03}})
    c_s = float(coefficients(damped)[P_CSTRUCT])
    assert c_s > 0
    mu, _ = stroke.design(
        stroke.StrokePlant.from_model(damped),
        "dsa",
        15.0,
        r3_rad_s=values["r3_rad_s"],
        kappa=values["kappa"],
    )
    assert _limit_cycle_deg(damped, mu, values, c_s) == pytest.approx(15.0, rel=1e-6)
    assert _limit_cycle_deg(damped, mu, values) > 16.0  # the damping is not left out


@pytest.mark.timeout(120)
def test_a_stiffening_flexure_in_the_model_reaches_the_sync_design(nominal) -> None:
    # -kappa phi^3: at 30 deg and 160 Hz the nominal design overdrives the stiffened wing 15 %
    model, nominal_plant, _ = nominal
    term = DiscoveredTerm("cube_angle", "stroke_dynamics", -4e-5)
    stiffened = replace(model, discovered=(term,))
    w = 2 * math.pi * 160.0
    t = np.arange(int(0.6 * FS)) / FS
    amplitudes = []
    for design_plant in (stroke.StrokePlant.from_model(stiffened), nominal_plant):
        u, _ = stroke.design(design_plant, "sync", 30.0, sync_frequency_hz=160.0)
        out = plant.simulate(u * np.sin(w * t), FS, stiffened)
        amplitudes.append(0.5 * np.ptp(np.degrees(out.stroke_rad[-int(0.1 * FS) :])))
    assert amplitudes[0] == pytest.approx(30.0, rel=0.02)
    assert amplitudes[1] > 1.1 * 30.0


def test_tracker_measures_each_wingbeat_of_a_sine_and_block_splits_change_nothing(nominal) -> None:
    _, design_plant, values = nominal
    params = _sync_params(values, design_plant)
    t = np.arange(int(0.2 * FS)) / FS
    x = np.radians(12.0) * np.sin(2 * np.pi * 150.0 * t - 0.3)
    inputs = stroke.StrokeInputs(x, np.zeros_like(x), np.ones(x.size, bool), 10)
    whole_state, whole = stroke.step(stroke.initial_state(params), inputs, params)
    amps = whole.signals.wingbeat_amplitude_deg[np.isfinite(whole.signals.wingbeat_amplitude_deg)]
    assert amps.size == 29  # 30 cycles, the first crossing only starts the count
    assert np.allclose(amps[1:], 12.0, atol=0.02)
    state, drives = stroke.initial_state(params), []
    for k in range(0, x.size, 10):
        state, out = stroke.step(
            state,
            stroke.StrokeInputs(x[k : k + 10], np.zeros(10), np.ones(10, bool), 10 + k),
            params,
        )
        drives.append(out.drive_v)
    assert np.array_equal(state.tracker, whole_state.tracker)
    # the whole record holds the command of its end; blocks hold each block's: equal at the end
    assert np.array_equal(drives[-1], whole.drive_v[-10:])


def test_law_moves_the_command_by_lambda_over_the_slope_of_the_log_error(nominal) -> None:
    _, design_plant, values = nominal
    params = _sync_params(values, design_plant)
    t = np.arange(round(FS / 140.0) * 3) / FS
    # exactly 3 wingbeats of 10 deg, setpoint 15
    x = np.radians(10.0) * np.sin(2 * np.pi * 140.0 * t)
    state, out = stroke.step(
        stroke.initial_state(params), stroke.StrokeInputs(x, x, np.ones(x.size, bool), 0), params
    )
    beats = np.isfinite(out.signals.wingbeat_amplitude_deg).sum()
    expected = params.command_nominal * math.exp(beats * params.gain * math.log(15.0 / 10.0))
    assert stroke.command(state, params) == pytest.approx(expected, rel=1e-3)
    moved = stroke.retarget(
        params, 20.0, *stroke.design(design_plant, "sync", 20.0, sync_frequency_hz=140.0)
    )
    assert stroke.command(state, moved) / moved.command_nominal == pytest.approx(
        stroke.command(state, params) / params.command_nominal
    )


def test_command_is_clamped_and_the_safety_chain_zeroes_the_drive_when_the_estimate_turns_invalid(
    nominal,
) -> None:
    _, design_plant, values = nominal
    params = _sync_params(values, design_plant, drive_amplitude_max_v=12.0)
    guard = safety.SafetyParams(5.0, 1.0e6, 0.005, 0.01, FS)
    state, g = stroke.initial_state(params), safety.initial_state(guard)
    small = np.radians(1.0) * np.sin(2 * np.pi * 140.0 * np.arange(10) / FS)
    maxima, k = [], 0
    # wing stuck at 1 deg: the law pushes the command up to its ceiling
    for k in range(0, 4000, 10):
        state, out = stroke.step(
            state, stroke.StrokeInputs(np.roll(small, k), small, np.ones(10, bool), k + 10), params
        )
        g, o = safety.step(g, safety.SafetyInputs(out.drive_v, (k + 10) / FS, True), guard)
        maxima.append(np.abs(o.drive_v).max())
    assert stroke.command(state, params) == pytest.approx(12.0)
    assert max(maxima) <= 5.0 and max(maxima) == pytest.approx(5.0)
    nan = np.full(10, np.nan)
    # 30 ms of invalid blocks: trip after 5 ms, zero 10 ms later
    for j in range(k + 10, k + 10 + 600, 10):
        state, out = stroke.step(
            state, stroke.StrokeInputs(nan, nan, np.zeros(10, bool), j + 10), params
        )
        g, o = safety.step(g, safety.SafetyInputs(out.drive_v, (j + 10) / FS, False), guard)
    assert o.tripped and np.all(o.drive_v == 0.0)


def test_bad_parameters_are_named(nominal) -> None:
    _, design_plant, values = nominal
    params = _sync_params(values, design_plant)
    with pytest.raises(stroke.StrokeParameterError, match="error_fraction_per_wingbeat"):
        replace(params, error_fraction_per_wingbeat=1.5)
    with pytest.raises(stroke.StrokeParameterError, match="mode"):
        stroke.params_from_values({**values, "mode": "chaos"}, design_plant, FS, 0.0)
    with pytest.raises(stroke.StrokeParameterError, match="dsa_params"):
        replace(params, mode="dsa")


def test_node_holds_the_setpoint_and_retargets_at_run_time(monkeypatch, tmp_path) -> None:
    """Plant, front end and the stroke controller node composed in process (tests/composed.py):
    12 deg held, then 16 deg after a parameter change while running. The controller node talks
    plain rclpy messages; here they are handed to and from the bus.
    """
    from types import SimpleNamespace

    from rclpy.parameter import Parameter

    from composed import composed
    from flaair_common import topics
    from flaair_control.stroke_controller_node import StrokeControllerNode
    from flaair_sensors.frontend_node import FrontendNode
    from flaair_sim.plant_node import PlantNode

    params = {
        "plant_node": {"command_timeout_s": 0.0},
        "stroke_controller_node": {
            "mode": "sync",
            "setpoint_deg": 12.0,
            "watchdog_timeout_s": 30.0,
        },
    }
    with composed(
        monkeypatch, [PlantNode, FrontendNode, StrokeControllerNode], params, tmp_path
    ) as loop:
        node = loop.node("stroke_controller_node")
        states: list = []
        monkeypatch.setattr(
            node.drive_pub,
            "publish",
            lambda m: loop.post(
                topics.DRIVE,
                {
                    "sample_rate_hz": m.sample_rate_hz,
                    "first_sample_index": m.first_sample_index,
                    "sec": 0,
                    "nanosec": 0,
                    "frame_id": "",
                    "drive_v": np.asarray(m.drive_v),
                },
            ),
        )
        monkeypatch.setattr(node.drive_pub, "get_subscription_count", lambda: 1)
        monkeypatch.setattr(node.state_pub, "publish", states.append)
        loop.bus.subscribe(
            topics.WING_STATE, lambda fields: node.on_wing_state(SimpleNamespace(**fields))
        )
        wing = loop.sink(topics.WING_STATE)
        loop.run_until(lambda: len(wing) >= 1600)
        n_before = len(wing)
        assert node.set_parameters([Parameter("setpoint_deg", value=16.0)])[0].successful
        loop.run_until(lambda: len(wing) >= n_before + 1600)
    assert [b["first_sample_index"] for b in wing] == list(range(0, len(wing) * 10, 10))
    stroke_deg = np.concatenate([b["stroke_deg"] for b in wing])
    from flaair_analysis import wingbeat

    beats = wingbeat.summarize(
        stroke_deg,
        stroke_deg,
        np.ones(stroke_deg.size, bool),
        wingbeat.WingbeatParams(FS, 1.0, 30.0, 400.0),
    )
    split = n_before * 10  # the setpoint changed after this sample
    before = beats.amplitude_deg[(beats.end_sample > split - 0.1 * FS) & (beats.end_sample < split)]
    assert before.size >= 10
    after = beats.amplitude_deg[beats.end_sample > stroke_deg.size - 0.1 * FS]
    assert np.all(np.abs(before - 12.0) <= 0.5), before
    assert np.all(np.abs(after - 16.0) <= 0.5), after
    assert len(states) == len(wing) + 1 and all(
        s.watchdog == 0 and abs(s.drive_v) <= 150.0 for s in states
    )


def test_the_stroke_loop_starts_after_the_delay_retries_and_trips_on_the_wall_clock() -> None:
    from flaair_control.core import stroke_loop as sl

    p = sl.TimingParams(start_delay_s=0.5, start_retry_s=0.2, watchdog_timeout_s=1.0)
    t = sl.initial_state(p, t_wall=0.0)
    t, action = sl.on_timer(t, 1.0, True, p)
    assert (t.mode, t.peers_wall, action) == (sl.WAITING, 1.0, sl.NOTHING)
    t, action = sl.on_timer(t, 1.2, False, p)  # a peer left: the delay starts again
    assert (t.peers_wall, action) == (None, sl.NOTHING)
    t, _ = sl.on_timer(t, 2.0, True, p)
    t, action = sl.on_timer(t, 2.5, True, p)
    assert (t.mode, t.last_wall, action) == (sl.LOOP, 2.5, sl.START)
    t, action = sl.on_timer(t, 2.6, True, p)
    assert action == sl.NOTHING
    t, action = sl.on_timer(t, 2.75, True, p)
    assert (t.last_wall, action) == (2.75, sl.RETRY)
    t, answer = sl.on_wing_state(t, 2.8, True)
    assert answer and t.answered and t.last_wall == 2.8
    t, action = sl.on_timer(t, 3.7, True, p)
    assert action == sl.NOTHING  # answered: no retry; 0.9 s silent: no trip yet
    t, action = sl.on_timer(t, 3.85, True, p)
    assert (t.mode, action) == (sl.TRIPPED, sl.TRIP)
    t, answer = sl.on_wing_state(t, 3.9, True)
    assert not answer and t.mode == sl.TRIPPED
    waiting = sl.initial_state(p, t_wall=0.0)
    started, answer = sl.on_wing_state(waiting, 0.1, True)
    assert answer and started.mode == sl.LOOP
    assert sl.on_wing_state(waiting, 0.1, False) == (waiting, False)
