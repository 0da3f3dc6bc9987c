"""Composed forms, at the dynamics (over the drive, time and the states) and at the drive and the
sensors (over their signals, and their low-passes): parsed, named canonically, generated without
the table's rows, carried by a model file, evaluated by the kernel's generic monomial and the
plant's signal terms, ranked, and refused by name when an expression is not built from them.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from flaair_analysis.discrepancy.datasets import make_run, make_runs, run_set_drives, true_model
from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.discovery import SAME_ERROR, rank_passing
from flaair_analysis.discrepancy.discovery_uncertainty import (
    SETTLE_S,
    suggest_experiment,
    suggested_drive,
)
from flaair_analysis.discrepancy.effect_judging import AnalysisContext
from flaair_analysis.discrepancy.fitting import with_terms
from flaair_analysis.discrepancy.offnominal import random_robot
from flaair_analysis.discrepancy.runs import sensor_gain_v_per_deg, simulate_runs
from flaair_analysis.discrepancy.term_candidates import candidates, is_degenerate, one_column_rss
from flaair_model.model import with_effects
from flaair_model.model_io import load_model, model_from_dict, model_to_dict
from flaair_model.settings import discrepancy as discrepancy_settings
from flaair_model.term_forms import (
    canonical,
    composed_forms,
    form_key,
    parse_form,
    parse_signal_form,
    signal_forms,
    signal_name,
)
from flaair_model.terms import (
    PRIMITIVES,
    TERM_KINDS,
    DiscoveredTerm,
    TermSignals,
    composed_kinds,
    monomial,
    row_of,
)
from flaair_model.validation import ModelError
from flaair_sim.core.plant import simulate


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.mark.parametrize(
    "expression,name",
    [
        ("phi*abs(dphi)", "phi*abs(dphi)"),
        ("abs(dphi)*phi", "phi*abs(dphi)"),
        ("dphi**2*sign(dphi)", "dphi*abs(dphi)"),  # v^2 sgn v = v |v|
        ("phi**2*sign(phi)", "phi*abs(phi)"),  # an angle's classes as a rate's
        ("phi*sign(phi)*psi", "abs(phi)*psi"),
        ("sign(dpsi)*abs(psi)*phi", "phi*abs(psi)*sign(dpsi)"),
        ("dphi*sign(dphi)", "abs(dphi)"),
        ("abs(dpsi)**2", "dpsi**2"),
        ("sign(dpsi)*psi**2", "psi**2*sign(dpsi)"),
        ("sign(dphi)**2", "1"),
    ],
)
def test_a_form_is_named_by_what_it_computes(expression: str, name: str) -> None:
    assert canonical(parse_form(expression)) == name


def test_equal_forms_compute_equal_values() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(7, 200))  # phi, dphi, psi, dpsi, the drive, the time, the drive's rate
    x[5] = np.abs(x[5])
    for expression in (
        "dphi**2*sign(dphi)",
        "abs(dpsi)**3",
        "psi*dphi*sign(dphi)",
        "phi*abs(phi)*sign(dpsi)",
        "abs(psi)*sign(phi)*dphi",
        "drive_v**2*sign(drive_v)*phi",
        "abs(drive_v)*sign(dpsi)",
        "t**2*phi",
        "t*drive_v*abs(dphi)",
        "ddrive_v*phi",
        "abs(ddrive_v)*sign(ddrive_v)**3*dpsi",
        "t*ddrive_v**2*sign(ddrive_v)",
    ):
        a = DiscoveredTerm(expression, "stroke_dynamics", 1.0).monomial_value(*x)
        mono = parse_form(expression)
        f = (x[0], x[1], x[2], x[3], np.sign(x[1]), np.sign(x[3]), np.abs(x[1]), np.abs(x[3]))
        f += (np.sign(x[0]), np.sign(x[2]), np.abs(x[0]), np.abs(x[2]))
        f += (x[4], np.sign(x[4]), np.abs(x[4]), x[5], x[6], np.sign(x[6]), np.abs(x[6]))
        b = np.prod([fi**e for fi, e in zip(f, mono, strict=True)], axis=0)
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_a_monomial_is_its_factors_multiplied_in_order_and_a_new_array() -> None:
    rng = np.random.default_rng(5)
    prims = [rng.normal(size=50) for _ in PRIMITIVES]
    for exponents in ([0] * len(PRIMITIVES), [1] + [0] * (len(PRIMITIVES) - 1)):
        out = monomial(prims, exponents)
        assert all(out is not p for p in prims) and out.flags.writeable
    for _ in range(20):
        exponents = list(rng.integers(0, 4, len(PRIMITIVES)) * (rng.random(len(PRIMITIVES)) < 0.3))
        written = np.ones(50)  # the product as written out: from 1, factor by factor
        for x, e in zip(prims, exponents, strict=True):
            if e:
                written = written * (x if e == 1 else x**e)
        np.testing.assert_array_equal(monomial(prims, exponents), written)  # bit for bit


def test_the_composed_library_is_bounded_and_each_form_is_listed_once() -> None:
    """Each of the six signed variables (the drive, its rate and the four states) has seven
    classes (its sign, each power of it and of its abs), time its three powers: 6 x 7 + 3
    one-variable forms; two signed variables: 15 pairs x 25 class pairs of degree <= 3 (the 49
    less those of degree 4 to 6), one with time: 6 x 9; three signed: 20 triples x 63, two with
    time: 15 x 19; 2019 in all, each computing a different value.
    """
    forms = composed_forms()
    keys = [form_key(m) for _n, m in forms]
    assert len(forms) == 45 + 15 * 25 + 6 * 9 + 20 * 63 + 15 * 19 == 2019
    assert len(set(keys)) == 2019
    names = [n for n, _m in forms]
    simplest = ["sign(drive_v)", "sign(ddrive_v)", "sign(phi)", "sign(psi)", "sign(dphi)"]
    assert names[:5] == simplest
    assert {"abs(phi)", "phi*abs(phi)", "abs(psi)*sign(dphi)", "phi*psi*dphi"} <= set(names)
    assert {"drive_v*phi", "abs(drive_v)*dphi", "drive_v**2*psi", "t*phi", "t**2*dpsi"} <= set(
        names
    )
    assert {"ddrive_v*phi", "drive_v*ddrive_v", "abs(ddrive_v)*dphi", "ddrive_v*t"} <= set(names)
    assert not any("abs(t)" in n or "sign(t)" in n for n in names)
    for name, mono in forms:
        assert parse_form(name) == mono and max(mono) <= 3 and canonical(mono) == name


def test_composed_candidates_leave_out_what_a_row_computes_at_the_site() -> None:
    stroke = {k.name for k in composed_kinds("stroke_dynamics")}
    pitch = {k.name for k in composed_kinds("pitch_dynamics")}
    # phi**3 is cube_angle on stroke; on pitch the rows' own angle is psi, so phi**3 is composed
    assert "phi**3" not in stroke and "phi**3" in pitch
    assert "psi**3" in stroke and "psi**3" not in pitch
    assert "dphi" not in stroke and "dphi" in pitch  # linear_velocity is a stroke row only
    assert {"phi*psi", "dphi*dpsi", "sign(dphi)", "abs(dphi)"}.isdisjoint(stroke)
    assert "phi*abs(dphi)" in stroke and "dpsi*abs(dpsi)" in pitch
    # nor what the plant carries: the stiffnesses, the hinge damping, the aerodynamic drag
    assert {"phi", "dphi*abs(dphi)"}.isdisjoint(stroke)
    assert {"psi", "dpsi", "dphi*abs(dphi)"}.isdisjoint(pitch)
    # the actuator's torque is the plant's on the stroke; a drive torque on the hinge is not
    assert "drive_v" not in stroke and "drive_v" in pitch
    assert {"drive_v*phi", "drive_v*dphi", "abs(drive_v)*phi"} <= stroke
    assert {"ddrive_v", "ddrive_v*phi", "abs(ddrive_v)*dphi"} <= stroke
    # memory: a low-pass of each variable but time; at the stroke, lowpass(drive_v) is the
    # drive's drive_lag row with the actuator's gain refitted
    lowpasses = {f"lowpass({x})" for x in ("drive_v", "ddrive_v", "phi", "psi", "dphi", "dpsi")}
    assert lowpasses - {"lowpass(drive_v)"} <= stroke and "lowpass(drive_v)" not in stroke
    assert lowpasses <= pitch and "lowpass(t)" not in pitch
    assert len(stroke) == 2019 - 12 + 5 and len(pitch) == 2019 - 11 + 6
    assert all(
        k.composed and (k.name == k.form or k.form == f"{k.name[:-1]}, {{corner_hz}})")
        for k in composed_kinds("stroke_dynamics")
    )


def test_the_drive_and_the_sensors_take_forms_over_their_signals() -> None:
    """The drive: 79 forms over the drive, its rate and time, less the actuator's gain and the
    rows drive_rate, drive_square, drive_cube, drive_drift; a sensor: 2589 over the drive, its
    rate, time, the angles, their rates and its own voltage (never that voltage times the angle
    its film reads or that angle's rate: one signal seen twice), less the film's gain and strain
    transfer, the feedthrough and transmission (stroke) and the rows (a drive or rate leak, gain
    drift, the angle squared); never a time's abs() or sign(), nor a voltage a site cannot read.
    The count is the enumeration's: 8 signals, t unsigned, at most 3 in a product, total degree
    at most 3, less the voltage with the angle or its rate. Beside the products, a low-pass of
    each signal a site reads but time, less what a row low-passes (the drive, at every site).
    """
    drive = {k.name for k in composed_kinds("drive")}
    stroke = {k.name for k in composed_kinds("stroke_sensor_v")}
    pitch = {k.name for k in composed_kinds("pitch_sensor_v")}
    assert len(signal_forms("drive")) == 79 and len(drive) == 74 + 1
    assert len(signal_forms("stroke_sensor_v")) == 2589 == len(signal_forms("pitch_sensor_v"))
    assert len(stroke) == 2582 + 6 and len(pitch) == 2583 + 6
    lowpasses = ["lowpass(ddrive_v)", "lowpass(phi)", "lowpass(psi)", "lowpass(dphi)"]
    assert {"lowpass(ddrive_v)"} == {n for n in drive if n.startswith("lowpass")}
    assert {*lowpasses, "lowpass(dpsi)", "lowpass(stroke_sensor_v)"} == {
        n for n in stroke if n.startswith("lowpass")
    }
    assert "lowpass(drive_v)" not in stroke | pitch | drive  # drive_lowpass_leak, drive_lag
    assert {"phi*abs(dphi)", "dpsi*stroke_sensor_v", "drive_v*sign(dphi)"} <= stroke
    assert {"dphi*stroke_sensor_v", "dpsi*pitch_sensor_v"}.isdisjoint(stroke | pitch)
    assert {"drive_v", "ddrive_v", "drive_v**2", "drive_v**3", "drive_v*t"}.isdisjoint(drive)
    assert {"drive_v*abs(drive_v)", "sign(ddrive_v)", "drive_v*t**2", "t"} <= drive
    assert {"phi", "phi**3", "stroke_sensor_v", "drive_v", "ddrive_v", "phi**2"}.isdisjoint(stroke)
    assert {"stroke_sensor_v*t"}.isdisjoint(stroke) and "pitch_sensor_v*t" not in pitch
    assert "psi*stroke_sensor_v" in stroke and "phi*pitch_sensor_v" in pitch
    factors = {x for n in stroke for x in n.split("*")}
    assert "pitch_sensor_v" not in factors
    assert not any("phi" in n and "stroke_sensor_v" in n for n in stroke)
    assert "psi**3" in pitch and "phi**3" in pitch
    assert signal_name(parse_signal_form("t*drive_v")) == "drive_v*t"
    assert signal_name(parse_signal_form("drive_v**2*sign(drive_v)")) == "drive_v*abs(drive_v)"
    with pytest.raises(ValueError, match="t is never negative"):
        parse_signal_form("abs(t)")
    with pytest.raises(ValueError, match="more than 3 signals"):
        parse_signal_form("drive_v*t*phi*psi")
    with pytest.raises(ModelError, match="not lowpass"):
        row_of("lowpass(t)")


def test_a_signal_form_acts_where_the_plant_applies_its_terms(model) -> None:
    """drive_v*t**2 at the drive: the actuator sees the drive plus 1e-3 t^2 times it;
    psi*stroke_sensor_v at the stroke sensor adds c psi dev to its output; dphi at the pitch
    sensor adds c times the stroke's backward difference.
    """
    fs = 20_000.0
    t = np.arange(4000) / fs
    drive = 60.0 * np.sin(2 * np.pi * 120.0 * t)
    warm = DiscoveredTerm("t**2*drive_v", "drive", 1e-3)
    assert warm.kind == "drive_v*t**2" and row_of("drive_v*t**2").sites == (
        "stroke_dynamics",  # a torque in the drive and time too
        "pitch_dynamics",
        "drive",
        "stroke_sensor_v",
        "pitch_sensor_v",
    )
    by_hand = simulate(drive * (1.0 + 1e-3 * t**2), fs, model)
    with_term = simulate(drive, fs, replace(model, discovered=(warm,)))
    np.testing.assert_allclose(with_term.stroke_rad, by_hand.stroke_rad, rtol=0, atol=1e-12)
    base = simulate(drive, fs, model)
    film = DiscoveredTerm("psi*stroke_sensor_v", "stroke_sensor_v", 0.5)
    out = simulate(drive, fs, replace(model, discovered=(film,)))
    vref = model.sensors.reference_voltage_v
    expected = base.stroke_sensor_v + 0.5 * base.pitch_rad * (base.stroke_sensor_v - vref)
    np.testing.assert_allclose(out.stroke_sensor_v, expected, rtol=0, atol=1e-12)
    # a low-pass of the pitch at the stroke sensor: scipy's bilinear first order, from rest
    memory = DiscoveredTerm("lowpass(psi)", "stroke_sensor_v", 0.2, (("corner_hz", 300.0),))
    assert memory.expression == "0.2 * lowpass(psi, 300)"
    out = simulate(drive, fs, replace(model, discovered=(memory,)))
    k = np.tan(np.pi * 300.0 / fs)
    filtered = signal.lfilter([k / (1 + k), k / (1 + k)], [1.0, (k - 1) / (k + 1)], base.pitch_rad)
    np.testing.assert_allclose(
        out.stroke_sensor_v, base.stroke_sensor_v + 0.2 * filtered, atol=1e-12
    )
    # a rate at a sensor: the angle's backward difference, 0 at the record's first sample
    rate = DiscoveredTerm("dphi", "pitch_sensor_v", 2e-5)
    out = simulate(drive, fs, replace(model, discovered=(rate,)))
    dphi = np.diff(base.stroke_rad, prepend=base.stroke_rad[0]) * fs
    np.testing.assert_allclose(out.pitch_sensor_v, base.pitch_sensor_v + 2e-5 * dphi, atol=1e-12)
    assert np.abs(2e-5 * dphi).max() > 1e-3  # the rate moves the output
    with pytest.raises(ModelError, match="acts_on must be one of"):
        DiscoveredTerm("psi*stroke_sensor_v", "pitch_sensor_v", 0.5)


def test_a_composed_term_round_trips_through_the_model_file(model) -> None:
    term = DiscoveredTerm("abs(dphi)*phi", "stroke_dynamics", -5e-9)
    assert term.kind == "phi*abs(dphi)" and term.expression == "-5e-09 * phi*abs(dphi)"
    doc = model_to_dict(model) | {
        "discovered": [
            {
                "kind": "phi*abs(dphi)",
                "acts_on": "stroke_dynamics",
                "parameters": {"coefficient": -5e-9},
            }
        ]
    }
    assert model_from_dict(doc).discovered == (term,)


@pytest.mark.parametrize(
    "kind,why",
    [
        ("exp(phi)", "'exp(phi)' is not a primitive"),
        ("phi*psi*dphi*dpsi", "more than 3 variables"),
        ("phi**4", "powers are 1 to 3"),
        ("sqrt(abs(dphi))", "not a primitive"),
    ],
)
def test_a_model_file_term_not_built_from_the_primitives_is_refused_by_name(
    model, kind: str, why: str
) -> None:
    doc = model_to_dict(model) | {
        "discovered": [
            {"kind": kind, "acts_on": "stroke_dynamics", "parameters": {"coefficient": 1}}
        ]
    }
    with pytest.raises(ModelError) as err:
        model_from_dict(doc)
    message = str(err.value)
    assert f"unknown term {kind!r}" in message and why in message
    assert "cannot be built from the primitives" in message
    assert row_of("phi*abs(dphi)").composed


def test_the_kernel_evaluates_a_composed_form_as_the_row_with_the_same_monomial(model) -> None:
    """psi**3 composed equals the cube_angle row on the pitch (bit for bit); phi*abs(dphi) acts."""
    fs = 20_000.0
    t = np.arange(6000) / fs
    drive = 60.0 * np.sin(2 * np.pi * 120.0 * t) * np.minimum(t / 0.05, 1.0)

    def run(*terms: DiscoveredTerm) -> np.ndarray:
        out = simulate(drive, fs, replace(model, discovered=terms))
        return np.degrees(np.stack([out.stroke_rad, out.pitch_rad]))

    row = run(DiscoveredTerm("cube_angle", "pitch_dynamics", 2e-6))
    composed = run(DiscoveredTerm("psi**3", "pitch_dynamics", 2e-6))
    np.testing.assert_array_equal(row, composed)
    base = run()
    assert np.max(np.abs(row - base)) > 0.05
    drag = run(DiscoveredTerm("phi*abs(dphi)", "stroke_dynamics", -5e-9))
    assert np.max(np.abs(drag[0] - base[0])) > 0.5
    np.testing.assert_array_equal(
        drag, run(DiscoveredTerm("abs(dphi)*phi", "stroke_dynamics", -5e-9))
    )


# ------------------------------------------------------------------ the suggested experiment


def test_the_suggested_sine_sits_where_two_models_differ_most(model) -> None:
    """Two stroke resonances 4 % apart differ most near them and at full drive (a linear plant:
    the difference scales with the level), far above the noise: that run tells them apart;
    identical models do not differ at all, and no run does.
    """
    other = replace(model, plant=replace(model.plant, stroke_natural_frequency_hz=145.6))
    freqs = [50.0, 90.0, 130.0, 150.0, 190.0]
    s = suggest_experiment([model, other], "stroke_deg", 20_000.0, 80.0, freqs, 0.05)
    assert s["level"] == 1.0 and s["drive_amplitude_v"] == 80.0
    assert s["frequency_hz"] in (130.0, 150.0)
    assert s["over_noise"] == pytest.approx(s["rms_difference"] / 0.05) and s["over_noise"] > 20
    assert s["separates"] is True
    assert (s["waveform"], s["duration_s"]) == ("sine", 0.5)  # the run the report names
    same = suggest_experiment([model, model], "stroke_deg", 20_000.0, 80.0, freqs, 0.05)
    assert same["rms_difference"] == 0.0 and same["separates"] is False


def test_the_suggested_run_is_the_suggested_sine_measured_on_the_same_robot(model) -> None:
    """The sine a suggestion names, as a run of the case's robot: ramped as the suggestion
    simulated it, then the amplitude asked; a run made with the first standard drive and the
    case's seed is the standard set's first run, sample for sample (video gaps included).
    """
    drive = suggested_drive(60.0, 150.0, 20_000.0, 0.5)
    assert drive.shape == (10_000,) and np.max(np.abs(drive)) == pytest.approx(60.0, rel=1e-3)
    assert np.max(np.abs(drive[: round(0.25 * SETTLE_S * 20_000.0)])) < 31.0  # still ramping
    case = random_robot("offnominal_discover", 1)
    assert case.video_every == 10
    name, first = run_set_drives()[0]
    run = make_run(case, model, name, first, seed=case.seed)
    standard = make_runs(case, model)[0]
    for column in ("drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg"):
        np.testing.assert_array_equal(getattr(run, column), getattr(standard, column))
    with pytest.raises(ValueError, match="second_resonance"):
        make_run(random_robot("offnominal_outside", 1), model, "x", drive, seed=1)


def test_a_composed_form_zero_or_constant_on_the_motion_is_degenerate() -> None:
    """A locked hinge (psi = dpsi = 0) makes every pitch form zero; a stroke rate that never
    changes sign makes sign(dphi) constant; a drive that never changes sign makes sign(drive_v)
    constant; the same forms on a full motion are not degenerate.
    """
    t = np.arange(4000) / 20_000.0
    phi = 0.4 * np.sin(2 * np.pi * 120.0 * t)
    zero = np.zeros_like(t)
    drive = TermSignals.of_block(20_000.0, 50.0 * np.sin(2 * np.pi * 120.0 * t))
    positive = TermSignals.of_block(20_000.0, 50.0 + 0.0 * t)
    states = {"phi": phi, "dphi": np.gradient(phi) * 20_000.0, "psi": zero, "dpsi": zero}
    locked = [{**states, "signals": drive}]
    one_way = [{"phi": t, "dphi": np.ones_like(t), "psi": phi, "dpsi": phi, "signals": positive}]
    full = [dict(locked[0], psi=0.3 * np.cos(2 * np.pi * 120.0 * t), dpsi=locked[0]["dphi"])]
    site = "stroke_dynamics"
    for name, motion, expected in [
        ("psi*abs(dphi)", locked, True),
        ("dphi*sign(dpsi)", locked, True),
        ("phi*abs(dphi)", locked, False),
        ("sign(dphi)*sign(dpsi)", one_way, False),
        ("abs(dphi)**3", one_way, True),  # 1 everywhere
        ("psi*abs(dphi)", full, False),
        ("drive_v*psi", locked, True),
        ("abs(drive_v)*phi", locked, False),
        ("sign(drive_v)", one_way, True),
        ("sign(drive_v)", locked, False),
    ]:
        assert is_degenerate(row_of(name), site, motion) is expected, name


@pytest.mark.parametrize("truth_referenced", [False, True])
def test_a_sensor_forms_change_to_the_residual_is_its_feature_along_the_model(
    model, truth_referenced: bool
) -> None:
    """A sensor term adds to the chain's output after its high-pass and delay, so the residual
    moves by the coefficient times the term's feature: the ranking's column
    (`ResidualProblem.output_columns` along `term_signals`) equals the change a simulated probe
    makes, to rounding, through a delayed, high-passed chain that already carries a term, with
    the judged angle measured or simulated.
    """
    case = random_robot("offnominal_null", 1)
    t = np.arange(6000) / 20_000.0
    drive = 40.0 * np.sin(2 * np.pi * (60.0 + 300.0 * t) * t)
    runs = [make_run(case, model, "chirp", drive, seed=3)]
    current = with_effects(
        model, {"sensor_delay": {"delay_s": 40e-6}, "charge_amp_highpass": {"corner_hz": 3.0}}
    )
    current = with_terms(current, [DiscoveredTerm("crosstalk", "pitch_sensor_v", 0.02)])
    noise = noise_estimates(runs, simulate_runs([current], runs)[0], model)
    ctx = AnalysisContext(runs, noise, discrepancy_settings())
    site = "pitch_sensor_v"
    problem = ctx.problem(site, ctx.folds, truth_referenced, current)
    r0 = np.concatenate(problem.residuals([current])[0])
    signals = problem.term_signals(current)
    for form in ("drive_v*abs(phi)", "pitch_sensor_v**2", "t*psi", "sign(ddrive_v)*psi**2"):
        coefficient = 1e-3
        probe = with_terms(current, [DiscoveredTerm(form, site, coefficient)])
        change = np.concatenate(problem.residuals([probe])[0]) - r0
        term = DiscoveredTerm(form, site, 1.0)
        column = problem.output_columns({j: term.feature(s) for j, s in signals.items()})
        assert np.abs(change).max() > 1e-3, form  # the probe moves the residual
        np.testing.assert_allclose(change, coefficient * column, rtol=0, atol=1e-9, err_msg=form)


@pytest.mark.timeout(60)
def test_a_films_memory_is_ranked_first_and_fitted_with_its_corner(model) -> None:
    """A pitch film that also reads the stroke through a 250 Hz first-order path (3 % of its own
    gain): among the pitch sensor's ~2,600 forms the low-pass of phi ranks first, and its fit
    from the corner grid's starts finds the coefficient within 0.5 % and the corner within 2 %.
    """
    case = random_robot("offnominal_null", 1)
    gain_v_per_rad = np.degrees(sensor_gain_v_per_deg(true_model(case, model), "pitch_sensor_v"))
    memory = DiscoveredTerm(
        "lowpass(phi)", "pitch_sensor_v", 0.03 * gain_v_per_rad, (("corner_hz", 250.0),)
    )
    case = replace(case, terms=(memory,))
    truth = replace(true_model(case, model), noise=model.noise)
    runs = make_runs(case, model)[:2]  # the two chirps
    noise = noise_estimates(runs, simulate_runs([truth], runs)[0], model)
    ctx = AnalysisContext(runs, noise, discrepancy_settings())
    found = candidates(ctx, replace(truth, discovered=()), "pitch_sensor_v", False)
    assert found.composed_ranked[0][:2] == ("lowpass(phi)", "pitch_sensor_v")
    _rss, kind, _site, specs, x = found.fitted[0]
    values = {s.key: s.from_fit(u) for s, u in zip(specs, x, strict=True)}
    assert kind.name == "lowpass(phi)"
    assert values["coefficient"] == pytest.approx(memory.coefficient, rel=0.005)
    assert values["corner_hz"] == pytest.approx(250.0, rel=0.02)


def test_a_huge_ranking_column_leaves_the_rss_its_direction_does() -> None:
    """A form whose RMS along the motion is tiny gets a huge probe scale: its column's square
    would overflow, but the rss a least-squares step leaves depends on its direction only.
    """
    rng = np.random.default_rng(1)
    r0, column = rng.standard_normal(500), rng.standard_normal(500)
    r0_ss = float(r0 @ r0)
    expected = r0_ss - float(column @ r0) ** 2 / float(column @ column)
    assert one_column_rss(1e200 * column, r0, r0_ss) == pytest.approx(expected, rel=1e-12)
    assert one_column_rss(column, r0, r0_ss) == pytest.approx(expected, rel=1e-12)
    assert one_column_rss(np.zeros(500), r0, r0_ss) == r0_ss
    assert one_column_rss(np.full(500, np.inf), r0, r0_ss) == r0_ss


def test_a_drive_factor_at_the_stroke_is_a_stiffness_that_follows_the_field(model) -> None:
    """drive_v*phi at the stroke with coefficient c: under a held drive V the stroke rests where
    G_a V = (K - c V) phi, the closed form of a flexure whose stiffness follows the field; the
    plant without the term rests at G_a V / K. The pitch has no term, so its rest is the
    plant's own.
    """
    fs, volts = 20_000.0, 40.0
    plant = model.plant
    k, gain = plant.stroke_stiffness_nm_per_rad, plant.actuator_gain_nm_per_v
    c = 0.2 * k / volts  # the stiffness 20 % lower at the held drive
    term = DiscoveredTerm("phi*drive_v", "stroke_dynamics", c)
    assert term.kind == "drive_v*phi" and "stroke_dynamics" in term.row.sites
    t = np.arange(int(0.5 * fs)) / fs  # a slow raised-cosine rise: the light damping rings little
    drive = volts * 0.5 * (1.0 - np.cos(np.pi * np.minimum(t / 0.4, 1.0)))
    held = simulate(drive, fs, replace(model, discovered=(term,)))
    plain = simulate(drive, fs, model)
    rest = held.stroke_rad[-200:].mean()
    assert rest == pytest.approx(gain * volts / (k - c * volts), rel=1e-3)
    assert plain.stroke_rad[-200:].mean() == pytest.approx(gain * volts / k, rel=1e-3)


def test_a_time_factor_at_the_stroke_is_a_stiffness_that_drifts(model) -> None:
    """t*phi at the stroke with coefficient -K d: under a held drive the stroke follows the
    quasi-static rest G_a V / (K (1 + d t)) of a flexure drifting in time, t from the run's
    first sample.
    """
    fs, volts, drift_per_s = 20_000.0, 40.0, 0.5
    plant = model.plant
    k, gain = plant.stroke_stiffness_nm_per_rad, plant.actuator_gain_nm_per_v
    term = DiscoveredTerm("phi*t", "stroke_dynamics", -k * drift_per_s)
    assert term.kind == "t*phi"
    t = np.arange(int(1.0 * fs)) / fs
    drive = volts * 0.5 * (1.0 - np.cos(np.pi * np.minimum(t / 0.4, 1.0)))
    out = simulate(drive, fs, replace(model, discovered=(term,)))
    for at_s in (0.6, 0.95):
        i = int(at_s * fs)
        rest = out.stroke_rad[i - 100 : i + 100].mean()
        assert rest == pytest.approx(gain * volts / (k * (1 + drift_per_s * at_s)), rel=2e-3)


def test_a_drive_rate_factor_at_the_stroke_adds_its_torque_under_a_ramp(model) -> None:
    """ddrive_v at the stroke with coefficient c: under a drive ramping at r V/s the term is a
    constant torque c r, so the stroke sits c r / K above the plant's without it (the drive's
    backward difference, held over a sample). The ramp's rate rises as a raised cosine, so the
    term's torque rises slowly and rings little.
    """
    fs, rate_v_per_s = 20_000.0, 200.0
    k = model.plant.stroke_stiffness_nm_per_rad
    c = 0.1 * k * math.radians(1.0) / rate_v_per_s  # 0.1 deg of offset
    term = DiscoveredTerm("ddrive_v", "stroke_dynamics", c)
    assert term.kind == "ddrive_v" and term.monomial[PRIMITIVES.index("ddrive_v")] == 1
    t = np.arange(int(0.4 * fs)) / fs
    drive = np.cumsum(rate_v_per_s * 0.5 * (1.0 - np.cos(np.pi * np.minimum(t / 0.2, 1.0)))) / fs
    with_rate = simulate(drive, fs, replace(model, discovered=(term,)))
    plain = simulate(drive, fs, model)
    offset = (with_rate.stroke_rad - plain.stroke_rad)[-400:]
    assert offset.mean() == pytest.approx(c * rate_v_per_s / k, rel=1e-3)
    assert np.ptp(offset) < 1e-3 * offset.mean()


@pytest.mark.timeout(30)
def test_a_composed_form_equal_to_a_row_loses_to_the_row_whatever_the_last_bits() -> None:
    # the square of a film's voltage where the film is a pure gain on its angle is the row
    # square_angle_sensor; their held-out errors differ in the last bits, which differ between
    # processors (one machine named the composed form, another the row)
    row = next(k for k in TERM_KINDS if k.name == "square_angle_sensor")
    composed = SimpleNamespace(name="pitch_sensor_v**2", composed=True)
    error = 0.005203763535574992

    def judged(kind, err, n_specs=1):
        return (SimpleNamespace(accepted=True, heldout_nrmse_after=err), kind, "pitch_sensor_v",
                [None] * n_specs, None)  # fmt: skip

    for below in (math.nextafter(error, 0.0), error * (1 - 0.5 * SAME_ERROR)):
        ranked = rank_passing([judged(composed, below), judged(row, error)])
        assert ranked[0][1] is row
    # a form really better (beyond SAME_ERROR) still wins, and within PARSIMONY fewer
    # parameters first
    better = error * (1 - 10 * SAME_ERROR)
    assert rank_passing([judged(row, error), judged(composed, better)])[0][1] is composed
    two = judged(composed, 0.99 * error, n_specs=2)
    assert rank_passing([two, judged(row, error)])[0][1] is row
