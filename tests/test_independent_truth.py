"""The benchmark's independent truth (bench/independent_truth.py) against the spec and against
FLAAIR's own simulator: two codes that share nothing agree on the nominal robot, so either one
checks the other; a stop holds the stroke where a contact of its stiffness can.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm
from flaair_sim.core.drive import chirp
from flaair_sim.core.hysteresis_kernel import hysteretic_voltage
from flaair_sim.core.plant import simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import independent_truth as truth  # the benchmark's module, beside its scripts

FS_HZ = 20000.0
pytestmark = pytest.mark.timeout(60)


def test_the_films_angle_per_volt_is_the_specs() -> None:
    """model-spec.md: 25.39 deg/V (stroke) and 24.87 deg/V (pitch), from Table 1's constants."""
    r = truth.Robot()
    stroke = r.transmission_rad_per_m / (r.stroke_amp_per_f * r.stroke_film_c_per_m)
    pitch = 2.0 / (r.pitch_amp_per_f * r.pitch_film_c_per_m * r.hinge_length_m)
    assert math.degrees(stroke) == pytest.approx(25.39, abs=0.005)
    assert math.degrees(pitch) == pytest.approx(24.87, abs=0.005)


def test_the_nominal_robot_agrees_with_flaairs_simulator_within_the_specs_005_deg() -> None:
    t = np.arange(3000) / FS_HZ
    drive = chirp(t, 90.0, 60.0, 260.0, t[-1])
    ours = truth.simulate(truth.Robot(), drive, FS_HZ)
    theirs = simulate(drive, FS_HZ, load_model())
    assert np.abs(ours["stroke_deg"]).max() > 10.0  # a response worth comparing
    assert np.abs(ours["stroke_deg"] - np.degrees(theirs.stroke_rad)).max() < 0.05
    assert np.abs(ours["pitch_deg"] - np.degrees(theirs.pitch_rad)).max() < 0.05
    for name in ("stroke_sensor_v", "pitch_sensor_v"):
        # 0.05 deg through 25 deg/V
        assert np.abs(ours[name] - getattr(theirs, name)).max() < 0.05 / 24.0


@pytest.mark.slow  # the independent truth at tight tolerances, a held sample at a time
def test_a_stop_holds_the_stroke_within_what_its_stiffness_lets_through() -> None:
    """A stop at 10 deg of 100 x the stroke stiffness K: the stroke passes it by at most
    sqrt((phi_free^2 - stop^2) / 100) (the energy K (phi_free^2 - stop^2) / 2 the free swing
    has left at the stop, all stored in the stop's spring: an upper bound); before the first
    contact the two runs are the same.
    """
    t = np.arange(1200) / FS_HZ
    drive = 60.0 * np.sin(2.0 * math.pi * 140.0 * t)
    free = truth.simulate(truth.Robot(), drive, FS_HZ)["stroke_deg"]
    r = truth.Robot()
    stopped = truth.simulate(
        replace(
            r, stop_rad=math.radians(10.0), stop_stiffness_nm_per_rad=100.0 * r.stroke_stiffness
        ),
        drive,
        FS_HZ,
    )["stroke_deg"]
    assert free.max() > 20.0
    bound = math.sqrt((free.max() ** 2 - 10.0**2) / 100.0)
    assert 10.0 < stopped.max() <= 10.0 + bound
    first = int(np.argmax(free > 10.0))
    np.testing.assert_allclose(stopped[:first], free[:first], atol=1e-9)


# the truth's own terms against FLAAIR's discovered term of the same physics: -k3 phi^3,
# -d psi'|psi'|, c x the stroke amplifier's output, c x the drive, -K d t phi (the coefficient's
# sign is the model's: a torque added, a voltage added)
_INSIDE = (
    ("cubic_nm_per_rad3", 2.0e-5, "cube_angle", "stroke_dynamics", -1.0),
    ("hinge_drag_nm_s2", 2.0e-12, "dpsi*abs(dpsi)", "pitch_dynamics", -1.0),
    ("crosstalk", 0.03, "crosstalk", "pitch_sensor_v", 1.0),
    ("drive_leak_v_per_v", 3e-4, "drive_leak", "pitch_sensor_v", 1.0),
    # K (1 + d t): a drift fast enough to show within the test's 0.15 s
    ("stiffness_drift_per_s", 2.0, "t*phi", "stroke_dynamics", -truth.Robot().stroke_stiffness),
)


@pytest.mark.parametrize(("field", "value", "kind", "site", "sign"), _INSIDE)
def test_the_truths_physics_inside_the_grammar_is_flaairs_term_of_that_form(
    field: str, value: float, kind: str, site: str, sign: float
) -> None:
    t = np.arange(3000) / FS_HZ
    drive = chirp(t, 90.0, 60.0, 260.0, t[-1])
    plain = truth.simulate(truth.Robot(), drive, FS_HZ)
    ours = truth.simulate(replace(truth.Robot(), **{field: value}), drive, FS_HZ)
    model = load_model()
    theirs = simulate(
        drive, FS_HZ, replace(model, discovered=(DiscoveredTerm(kind, site, sign * value),))
    )
    channel = {"stroke_dynamics": "stroke_deg", "pitch_dynamics": "pitch_deg"}.get(site, site)
    moved = np.abs(ours[channel] - plain[channel]).max()
    if channel.endswith("_deg"):
        assert moved > 0.5  # the physics shows, well above the two codes' 0.05 deg
        theirs_deg = np.degrees(getattr(theirs, channel.replace("_deg", "_rad")))
        assert np.abs(ours[channel] - theirs_deg).max() < 0.05
    else:
        assert moved > 0.02  # 10 x the amplifier noise
        assert np.abs(ours[channel] - getattr(theirs, channel)).max() < 0.05 / 24.0


def test_the_truths_bouc_wen_actuator_is_flaairs_actuator_hysteresis() -> None:
    """The textbook Bouc-Wen law (alpha, beta, gamma; gamma = beta) integrated by DOP853 along
    each drive jump, against FLAAIR's effect of loop fraction alpha and saturation alpha / 2 beta:
    the same hysteretic voltage to 1e-7 V, the same stroke within 0.05 deg.
    """
    t = np.arange(3000) / FS_HZ
    drive = chirp(t, 90.0, 60.0, 260.0, t[-1])
    alpha, saturation_v = 0.35, 8.0
    beta = alpha / (2.0 * saturation_v)
    robot = replace(
        truth.Robot(),
        hysteresis_alpha=alpha,
        hysteresis_beta_per_v=beta,
        hysteresis_gamma_per_v=beta,
    )
    ours = truth.simulate(robot, drive, FS_HZ)
    plain = simulate(drive, FS_HZ, load_model())
    model = with_effects(
        load_model(),
        {"actuator_hysteresis": {"loop_fraction": alpha, "saturation_v": saturation_v}},
    )
    theirs = simulate(drive, FS_HZ, model)
    lag = np.empty(drive.size)
    hysteretic_voltage(drive, alpha, saturation_v, np.zeros(2), lag)
    np.testing.assert_allclose(truth.hysteretic_voltage(robot, drive), lag, rtol=0, atol=1e-7)
    assert np.abs(ours["stroke_deg"] - np.degrees(plain.stroke_rad)).max() > 0.5  # it shows
    assert np.abs(ours["stroke_deg"] - np.degrees(theirs.stroke_rad)).max() < 0.05


def test_the_truths_viscoelastic_flexure_is_flaairs_stroke_low_pass() -> None:
    """The truth's Maxwell arm, -k_r (phi - z) with z' = 2 pi f_r (phi - z), is FLAAIR's
    k_r lowpass(phi) at the stroke, corner f_r, beside a stiffness K + k_r: FLAAIR filters the
    stroke at each sample and holds the output over it, the truth integrates z with the rest.
    """
    k_r, f_r = 0.1 * truth.Robot().stroke_stiffness, 150.0
    t = np.arange(3000) / FS_HZ
    drive = chirp(t, 90.0, 60.0, 260.0, t[-1])
    plain = truth.simulate(truth.Robot(), drive, FS_HZ)
    ours = truth.simulate(
        replace(truth.Robot(), relaxation_nm_per_rad=k_r, relaxation_hz=f_r), drive, FS_HZ
    )
    model = load_model()
    stiffer = model.plant.stroke_natural_frequency_hz * math.sqrt(
        1.0 + k_r / model.plant.stroke_stiffness_nm_per_rad
    )
    term = DiscoveredTerm("lowpass(phi)", "stroke_dynamics", k_r, (("corner_hz", f_r),))
    theirs = simulate(
        drive,
        FS_HZ,
        replace(
            model,
            plant=replace(model.plant, stroke_natural_frequency_hz=stiffer),
            discovered=(term,),
        ),
    )
    assert np.abs(ours["stroke_deg"] - plain["stroke_deg"]).max() > 0.5
    assert np.abs(ours["stroke_deg"] - np.degrees(theirs.stroke_rad)).max() < 0.05
