"""Collision metric (paper) and per-wingbeat collision monitor (flaair_control.core.collision)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_control.core import collision as col
from flaair_control.core import spectral
from flaair_control.monitor_io import (
    monitor_windows_from_config,
    spectral_metric_params_from_config,
)

FS = 20000.0
BLOCK = 10
METRIC = spectral_metric_params_from_config()  # the paper metric as configured


# --------------------------------------------------------------------------- paper metric, pure


@pytest.mark.parametrize("f", [100.0, 70.0, 130.0])  # 70/130 Hz: non-integer samples per period
@pytest.mark.parametrize("reference", ["energy", "fundamental"])
def test_pure_sine_scores_zero(f, reference):
    t = np.arange(int(0.2 * FS)) / FS
    x = math.radians(20.0) * np.sin(2 * np.pi * f * t + 0.7) + 0.1
    r = spectral.spectral_metric(x, FS, f, replace(METRIC, reference=reference))
    assert r.spectral_rmse_deg < 0.01
    assert r.time_rmse_deg < 0.01
    assert not r.collision
    assert r.fundamental_amplitude_rad == pytest.approx(math.radians(20.0), rel=1e-3)


def test_harmonic_content_gives_the_expected_rmse():
    f, a1, h = 100.0, math.radians(20.0), math.radians(5.0)
    t = np.arange(int(0.1 * FS)) / FS  # exactly 10 periods
    x = a1 * np.cos(2 * np.pi * f * t + 0.3) + h * np.cos(2 * np.pi * 2 * f * t + 1.1)
    r = spectral.spectral_metric(x, FS, f, METRIC)
    n_bins = r.frequency_hz.size
    assert n_bins == 51  # 0..500 Hz at 10 Hz resolution
    a_ref = math.hypot(a1, h)  # energy-matched reference sine
    assert r.reference_amplitude_rad == pytest.approx(a_ref, rel=1e-9)
    assert r.spectral_rmse_rad == pytest.approx(
        math.sqrt(((a_ref - a1) ** 2 + h**2) / n_bins), rel=1e-6
    )
    assert r.time_rmse_rad == pytest.approx(math.sqrt(((a_ref - a1) ** 2 + h**2) / 2), rel=1e-6)
    k1, k2 = np.argmin(np.abs(r.frequency_hz - f)), np.argmin(np.abs(r.frequency_hz - 2 * f))
    assert r.signal_spectrum_rad[k1] < r.reference_spectrum_rad[k1]  # fundamental below the sine
    assert r.signal_spectrum_rad[k2] == pytest.approx(h, rel=1e-6)
    fund = spectral.spectral_metric(x, FS, f, replace(METRIC, reference="fundamental"))
    assert fund.spectral_rmse_rad == pytest.approx(h / math.sqrt(n_bins), rel=1e-6)


def test_metric_rejects_bad_input_by_name():
    with pytest.raises(ValueError, match="angle_rad"):
        spectral.spectral_metric(np.array([0.0, np.nan] * 200), FS, 100.0, METRIC)
    with pytest.raises(ValueError, match="drive_frequency_hz"):
        spectral.spectral_metric(np.zeros(400), FS, 0.0, METRIC)
    with pytest.raises(ValueError, match="drive period"):
        spectral.spectral_metric(np.zeros(100), FS, 100.0, METRIC)
    with pytest.raises(ValueError, match="reference"):
        replace(METRIC, reference="peak")


# --------------------------------------------------------------------------- monitor, pure


def _params(**kw) -> col.MonitorParams:
    """The configured monitor (config/flaair.yaml) at 100 Hz drive windows, overridden by ``kw``."""
    return replace(monitor_windows_from_config(100.0), **kw)


def _synthetic(
    n_periods: int, f: float = 100.0, distort_from: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(round(n_periods * FS / f)) / FS
    s = math.radians(25.0) * np.sin(2 * np.pi * f * t)
    p = math.radians(10.0) * np.sin(2 * np.pi * f * t + 0.5)
    if distort_from is not None:
        clip = math.radians(18.0)
        late = t >= distort_from / f
        s = np.where(late, np.minimum(s, clip), s)
    return s, p


def test_block_split_equals_whole_record_in_both_window_modes():
    s, p = _synthetic(60, distort_from=30)
    rng = np.random.default_rng(0)
    s = s + rng.standard_normal(s.size) * 1e-3
    for source in ("drive", "stroke"):
        prm = _params(window_source=source)
        _, whole, ev_whole = col.run(s, p, prm)
        state = col.initial_state(prm)
        reps, evs = [], []
        i = 0
        for size in rng.integers(1, 400, 10_000):
            if i >= s.size:
                break
            state, (rep, ev) = col.step(
                state, col.MonitorInputs(s[i : i + size], p[i : i + size]), prm
            )
            reps.append(rep)
            evs.extend(ev)
            i += size
        joined = col.concat_reports(reps)
        for a, b in zip(joined, whole, strict=True):
            np.testing.assert_array_equal(a, b)
        assert evs == ev_whole
        assert [e.kind for e in ev_whole] == [col.ONSET]


def test_hysteresis_onset_and_clearance():
    s1, p1 = _synthetic(40)
    s2, p2 = _synthetic(20, distort_from=0)
    s3, p3 = _synthetic(20)
    s, p = np.concatenate([s1, s2, s3]), np.concatenate([p1, p2, p3])
    prm = _params(n_on=2, n_off=3)
    _, rep, ev = col.run(s, p, prm)
    assert [e.kind for e in ev] == [col.ONSET, col.CLEARANCE]
    assert ev[0].wingbeat == 41  # second distorted wingbeat (n_on = 2)
    assert ev[1].wingbeat == 62  # third clean wingbeat (n_off = 3)
    assert np.all(rep.status[:10] == col.ARMING)
    assert np.all(rep.status[42:62] == col.COLLISION)
    assert np.all(rep.status[63:] == col.CLEAR)


def test_invalid_and_idle_windows_decide_nothing():
    s, p = _synthetic(30)
    s[int(15.5 * 200)] = np.nan
    s[20 * 200 :] *= 0.0  # wing stops at a wingbeat boundary: idle
    _, rep, ev = col.run(s, p, _params())
    assert rep.status[15] == col.INVALID
    assert np.all(rep.status[20:] == col.IDLE)
    assert ev == []
    # stopping mid-wingbeat is itself a distorted (truncated) wingbeat and is reported
    s2, p2 = _synthetic(30)
    s2[int(20.5 * 200) :] = 0.0
    _, rep2, ev2 = col.run(s2, p2, _params())
    assert rep2.status[20] == col.COLLISION and [e.kind for e in ev2] == [col.ONSET, col.CLEARANCE]


def test_monitor_parameters_are_validated_by_name():
    with pytest.raises(ValueError, match="drive_frequency_hz"):
        _params(drive_frequency_hz=None)
    with pytest.raises(ValueError, match="off_level"):
        _params(off_level=2.0)
    with pytest.raises(ValueError, match="window_source"):
        _params(window_source="video")
    with pytest.raises(ValueError, match="same length"):
        col.step(
            col.initial_state(_params()), col.MonitorInputs(np.zeros(3), np.zeros(4)), _params()
        )


# --------------------------------------------------------------------------- on the simulated robot

import flaair_model.model as sim_model
import flaair_model.model_io as sim_model_io
import flaair_sim.core.plant as plant_mod

LIMIT_DEG = 20.0  # obstacle below the 28.3 deg free stroke at 100 Hz, 75 V


@pytest.fixture(scope="module")
def model():
    return sim_model_io.load_model()


def sensor_angles(model, out) -> tuple[np.ndarray, np.ndarray]:
    """Linear inverse sensor model: angle = (V - V_HREF) / volts_per_rad."""
    vref = model.sensors.reference_voltage_v
    return (
        (out.stroke_sensor_v - vref) / model.stroke_volts_per_rad,
        (out.pitch_sensor_v - vref) / model.pitch_volts_per_rad,
    )


def test_paper_metric_separates_collision_from_free_flapping(model):
    """Paper experiment: 100 Hz, 150 V bias -> 75 V amplitude, obstacle struck every wingbeat."""
    t = np.arange(int(0.5 * FS)) / FS
    drive = 75.0 * np.sin(2 * np.pi * 100.0 * t)
    hit = sim_model.with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    free_out = plant_mod.simulate(drive, FS, model, noise=True, rng=np.random.default_rng(1))
    hit_out = plant_mod.simulate(drive, FS, hit, noise=True, rng=np.random.default_rng(2))
    # it would pass the stop
    assert np.degrees(free_out.stroke_rad[-2000:]).max() > LIMIT_DEG + 5
    assert np.degrees(hit_out.stroke_rad[-2000:]).max() < LIMIT_DEG + 2  # ... and is stopped
    free = spectral.spectral_metric(sensor_angles(model, free_out)[1], FS, 100.0, METRIC)
    coll = spectral.spectral_metric(sensor_angles(model, hit_out)[1], FS, 100.0, METRIC)
    assert coll.collision and not free.collision  # 1 deg threshold
    assert coll.spectral_rmse_deg > 5 * free.spectral_rmse_deg
    assert coll.time_rmse_deg > 5 * free.time_rmse_deg
    k1 = np.argmin(np.abs(coll.frequency_hz - 100.0))
    k2 = np.argmin(np.abs(coll.frequency_hz - 200.0))
    # paper: lower amplitude at 100 Hz, much higher at 200 Hz than the pure sine
    assert coll.signal_spectrum_rad[k1] < coll.reference_spectrum_rad[k1]
    assert coll.signal_spectrum_rad[k2] > 10 * coll.reference_spectrum_rad[k2]
    assert coll.signal_spectrum_rad[k2] > math.radians(1.0)


def _live_obstacle_run(
    model,
    source: str,
    t_in: float,
    t_out: float,
    duration: float,
    f: float = 100.0,
    amplitude_v: float = 75.0,
):
    """Block loop; the obstacle appears at ~t_in (first block boundary with the wing below it) and
    goes at t_out. Returns (first strike time, [(event, time the step returned it)], reports).
    """
    hit = sim_model.with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    limit = math.radians(LIMIT_DEG)
    rng = np.random.default_rng(11)
    prm = _params(
        window_source=source,
        drive_frequency_hz=f if source == "drive" else None,
        stroke_noise_rms_rad=model.noise.sensor_noise_v_rms / abs(model.stroke_volts_per_rad),
        pitch_noise_rms_rad=model.noise.sensor_noise_v_rms / abs(model.pitch_volts_per_rad),
    )
    mon = col.initial_state(prm)
    state = plant_mod.initial_state(plant_mod.PlantStepParams(model, FS))
    present = False
    first_strike = None
    events, reports = [], []
    last_phi = 0.0
    for k in range(int(duration * FS / BLOCK)):
        t0 = k * BLOCK / FS
        if not present and t_in <= t0 < t_out and last_phi < 0.5 * limit:
            present = True
        if present and t0 >= t_out:
            present = False
        drive = amplitude_v * np.sin(2 * np.pi * f * (t0 + np.arange(BLOCK) / FS))
        state, out = plant_mod.step(
            state,
            plant_mod.PlantInputs(drive, rng),
            plant_mod.PlantStepParams(hit if present else model, FS),
        )
        last_phi = out.stroke_rad[-1]
        if present and first_strike is None and np.any(out.stroke_rad >= limit):
            first_strike = t0 + np.argmax(out.stroke_rad >= limit) / FS
        s, p = sensor_angles(model, out)
        mon, (rep, ev) = col.step(mon, col.MonitorInputs(s, p), prm)
        reports.append(rep)
        events.extend((e, t0 + BLOCK / FS) for e in ev)
    return first_strike, events, col.concat_reports(reports)


@pytest.mark.parametrize("source", ["drive", "stroke"])
def test_detects_a_new_obstacle_within_two_wingbeats_and_clears_after_it_goes(model, source):
    f = 100.0
    strike, events, rep = _live_obstacle_run(model, source, t_in=0.3, t_out=0.6, duration=0.8, f=f)
    assert strike is not None and 0.3 <= strike < 0.32
    kinds = [e.kind for e, _ in events]
    assert kinds == [col.ONSET, col.CLEARANCE]
    onset_seen = events[0][1]  # end of the block that returned the event
    latency_beats = (onset_seen - strike) * f
    assert 0 < latency_beats <= 2.0
    clear_seen = events[1][1]
    # n_off = 3 clean wingbeats (+ partial, + ring-down)
    assert 0 < (clear_seen - 0.6) * f <= 3 + 2
    armed = rep.status != col.ARMING
    assert np.all(rep.status[armed & (rep.end_time_s < 0.3)] == col.CLEAR)


def test_obstacle_present_from_the_start_is_reported_every_wingbeat(model):
    t = np.arange(int(0.5 * FS)) / FS
    hit = sim_model.with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    out = plant_mod.simulate(
        75.0 * np.sin(2 * np.pi * 100.0 * t), FS, hit, noise=True, rng=np.random.default_rng(5)
    )
    s, p = sensor_angles(model, out)
    prm = _params()
    _, rep, ev = col.run(s, p, prm)
    armed = rep.status != col.ARMING
    assert np.all(rep.status[armed] == col.COLLISION)
    assert [e.kind for e in ev] == [col.ONSET] and ev[0].wingbeat == prm.arm_wingbeats
    assert np.min(rep.score[armed]) > 3.0


def _false_alarm_sweep(model, source: str, duration_s: float):
    t = np.arange(int(duration_s * FS)) / FS
    worst = 0.0
    alarms = []
    for f in range(60, 201, 10):
        for amp in (50.0, 100.0):  # 100 and 200 Vpp
            out = plant_mod.simulate(
                amp * np.sin(2 * np.pi * f * t),
                FS,
                model,
                noise=True,
                rng=np.random.default_rng(f * 7 + int(amp)),
            )
            s, p = sensor_angles(model, out)
            _, rep, ev = col.run(
                s,
                p,
                _params(
                    window_source=source, drive_frequency_hz=float(f) if source == "drive" else None
                ),
            )
            armed = rep.status != col.ARMING
            assert np.all(rep.status[armed] == col.CLEAR), (f, amp)
            worst = max(worst, float(rep.score[armed].max()))
            alarms += [(f, amp, e) for e in ev]
    return alarms, worst


def test_no_false_alarm_in_10_s_of_free_flapping_60_to_200_hz(model):
    alarms, worst = _false_alarm_sweep(model, "drive", 10.0)
    assert alarms == []
    assert worst < 0.5  # margin: the onset level is 1.0


def test_no_false_alarm_with_stroke_locked_windows(model):
    alarms, worst = _false_alarm_sweep(model, "stroke", 2.0)
    assert alarms == []
    assert worst < 0.5
