"""Sync -> async transition: Hilbert analysis (pure)
and the closed loop over DDS (plant lockstep).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_control.core import transition as tr

FS = 20000.0
# 4th-order 40-400 Hz band-pass, 20 ms 2nd-order Savitzky-Golay, 20 ms edges
HILBERT = tr.HilbertParams(
    band_hz=(40.0, 400.0), band_order=4, savgol_window_s=0.02, savgol_order=2, edge_s=0.02
)


# --------------------------------------------------------------------------- analysis, pure


def test_hilbert_recovers_frequency_and_amplitude_of_a_stepped_sine():
    t = np.arange(int(1.0 * FS)) / FS
    x = np.where(
        t < 0.5, 6.0 * np.sin(2 * np.pi * 90.0 * t), 20.0 * np.sin(2 * np.pi * 144.0 * t + 0.3)
    )
    x = x + 3.0  # offset: removed by the band-pass
    r = tr.hilbert_analysis(x, FS, HILBERT)
    assert np.isnan(r.frequency_hz[:10]).all() and np.isnan(r.amplitude[-10:]).all()  # edges
    f1, a1 = (
        tr.window_stats(r.time_s, r.frequency_hz, 0.1, 0.45),
        tr.window_stats(r.time_s, r.amplitude, 0.1, 0.45),
    )
    f2, a2 = (
        tr.window_stats(r.time_s, r.frequency_hz, 0.65, 0.9),
        tr.window_stats(r.time_s, r.amplitude, 0.65, 0.9),
    )
    assert f1.mean == pytest.approx(90.0, abs=0.05) and a1.mean == pytest.approx(6.0, rel=2e-3)
    assert f2.mean == pytest.approx(144.0, abs=0.05) and a2.mean == pytest.approx(20.0, rel=2e-3)
    assert f2.ptp < 1.0 and a2.ptp < 0.1  # after the step's ringing through the band-pass


def test_savitzky_golay_removes_the_harmonic_ripple_of_a_non_sinusoidal_stroke():
    t = np.arange(int(0.6 * FS)) / FS
    # 3rd harmonic
    x = 20.0 * np.sin(2 * np.pi * 144.0 * t) + 3.0 * np.sin(2 * np.pi * 432.0 * t + 1.0)
    # the band-pass removes the 432 Hz harmonic
    params = replace(HILBERT, band_hz=(40.0, 300.0))
    r = tr.hilbert_analysis(x, FS, params)
    f = tr.window_stats(r.time_s, r.frequency_hz, 0.1, 0.5)
    assert f.mean == pytest.approx(144.0, abs=0.1) and f.ptp < 1.0
    raw = tr.hilbert_analysis(
        x, FS, replace(HILBERT, band_hz=(40.0, 1000.0), savgol_window_s=1e-4, savgol_order=0)
    )
    # unsmoothed: ripples
    assert tr.window_stats(raw.time_s, raw.frequency_hz, 0.1, 0.5).ptp > 20 * f.ptp


def test_nan_samples_are_filled_and_counted():
    t = np.arange(int(0.4 * FS)) / FS
    x = 10.0 * np.sin(2 * np.pi * 120.0 * t)
    x[3000:3005] = np.nan
    r = tr.hilbert_analysis(x, FS, HILBERT)
    assert r.filled_samples == 5
    assert tr.window_stats(r.time_s, r.frequency_hz, 0.05, 0.35).mean == pytest.approx(
        120.0, abs=0.2
    )


def test_crossing_frequency_streams_like_the_whole_record():
    t = np.arange(int(0.3 * FS)) / FS
    x = 15.0 * np.sin(2 * np.pi * 141.3 * t) + np.random.default_rng(0).normal(0, 0.2, t.size)
    est = tr.CrossingFrequency(FS, 1.0)
    for k in range(0, x.size, 10):
        est.update(x[k : k + 10])
    assert est.frequency_hz == pytest.approx(141.3, rel=2e-3)
    times = tr.crossing_times(x, FS, 1.0)
    assert np.allclose(1 / np.diff(times), 141.3, rtol=0.02)
    est.update(np.zeros(int(0.06 * FS)))  # stopped for longer than max_period_s
    assert est.frequency_hz == 0.0
    nan_est = tr.CrossingFrequency(FS, 1.0)
    nan_est.update([math.nan] * 10)
    assert nan_est.frequency_hz == 0.0


def test_join_blocks_marks_invalid_and_missing_samples():
    blocks = [
        {"first_sample_index": 20, "stroke_deg": [1.0, 2.0], "stroke_valid": [True, False]},
        {"first_sample_index": 16, "stroke_deg": [3.0, 4.0], "stroke_valid": [True, True]},
        # duplicate
        {"first_sample_index": 16, "stroke_deg": [9.0, 9.0], "stroke_valid": [True, True]},
    ]
    rec = tr.join_blocks(blocks, ["stroke_deg"], 4.0, valid_field="stroke_valid")
    assert rec.first_sample_index == 16 and rec.missing_blocks == 1
    np.testing.assert_array_equal(rec.time_s, [4.0, 4.25, 4.5, 4.75, 5.0, 5.25])
    np.testing.assert_array_equal(rec.values["stroke_deg"], [3.0, 4.0, np.nan, np.nan, 1.0, np.nan])


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="band_hz"):
        replace(HILBERT, band_hz=(300.0, 40.0))
    with pytest.raises(ValueError, match="fs/2"):
        tr.hilbert_analysis(np.zeros(4000), 600.0, HILBERT)
    with pytest.raises(ValueError, match="too short"):
        tr.hilbert_analysis(np.zeros(50), FS, HILBERT)


# ---------------------------------------------------------------------------
# the closed loop, composed


def _with_header(block: dict) -> dict:
    """An in-process block as an echoed message dict (the stamp under header)."""
    return {**block, "header": {"stamp": {"sec": block["sec"], "nanosec": block["nanosec"]}}}


def test_sync_to_async_transition_in_the_composed_closed_loop(monkeypatch, tmp_path):
    """Plant (lockstep) -> front end -> dSA controller -> plant, the node classes
    composed on one bus (tests/composed.py): 90 Hz synchronous start, K_r 1 -> 0 over
    0.5 s, self-excited slightly above the 140 Hz stroke resonance, steady amplitude.
    """
    from composed import composed
    from flaair_common import topics
    from flaair_control.dsa_controller_node import DsaControllerNode
    from flaair_model.config import node_parameters
    from flaair_model.model_io import load_model
    from flaair_sensors.frontend_node import FrontendNode
    from flaair_sim.plant_node import PlantNode
    from flaair_tools.analysis.transition import (
        plot_transition,
        predicted_limit_cycle,
        transition_record,
    )

    duration, ramp_start, ramp = 1.5, 0.3, 0.5
    params = {
        "plant_node": {"command_timeout_s": 0.0},
        "dsa_controller_node": {
            "kr_ramp_start_s": ramp_start,
            "kr_ramp_duration_s": ramp,
            "watchdog_timeout_s": 30.0,
            "run_time_s": duration,
        },
    }
    with composed(
        monkeypatch, [PlantNode, FrontendNode, DsaControllerNode], params, tmp_path
    ) as loop:
        wing, states = loop.sink(topics.WING_STATE), loop.sink(topics.CONTROLLER_STATE)
        loop.run_until(
            lambda: len(wing) >= duration * FS / 10 and len(states) >= duration * FS / 10
        )
        loop.run_for(0.1)  # the run ends: nothing more comes
    ws, cs = [_with_header(b) for b in wing], [_with_header(s) for s in states]
    # 1.5 s of blocks, and the closing zero block (run_time_s reached) stepped by the plant too
    assert [b["first_sample_index"] for b in ws] == list(range(0, 30010, 10))
    # a ControllerState with every drive block of the run (the closing zero block carries none)
    assert sorted(round(tr.stamp_s(c) * FS) for c in cs) == list(range(0, 30000, 10))
    rec = transition_record(ws, cs, FS)
    assert rec.missing_blocks == 0 and np.isfinite(rec.stroke_deg).all()
    assert rec.kr[0] == 1.0 and rec.kr[-1] == 0.0
    r = tr.hilbert_analysis(rec.stroke_deg, FS, HILBERT)
    f_n = load_model().plant.stroke_natural_frequency_hz
    config = node_parameters("flaair.yaml", "dsa_controller_node")
    f_lc, a_lc = predicted_limit_cycle(config, FS, 10)

    f_sync = tr.window_stats(r.time_s, r.frequency_hz, 0.1, 0.3)
    f_end = tr.window_stats(r.time_s, r.frequency_hz, 1.1, 1.45)
    a_end = tr.window_stats(r.time_s, r.amplitude, 1.1, 1.45)
    a_mid = tr.window_stats(r.time_s, r.amplitude, 0.9, 1.1)
    # synchronous, well below resonance
    assert f_sync.mean == pytest.approx(90.0, abs=0.5)
    # slightly above the resonance
    assert 1.01 * f_n < f_end.mean < 1.06 * f_n
    # where the loop theory puts it
    assert f_end.mean == pytest.approx(f_lc, rel=0.01)
    assert f_end.std < 0.2  # settled
    assert a_end.mean == pytest.approx(a_lc, rel=0.03)
    # stable
    assert a_end.std < 0.01 * a_end.mean and abs(a_end.mean - a_mid.mean) < 0.01 * a_end.mean
    # grew from sync
    assert a_end.mean > 2.5 * tr.window_stats(r.time_s, r.amplitude, 0.1, 0.3).mean
    # the controller's live crossing estimate agrees
    live = rec.controller_frequency_hz[rec.kr_time_s > 1.1]
    assert np.allclose(live, f_end.mean, rtol=0.005)
    png = plot_transition(
        rec, r, tmp_path / "transition.png", resonance_hz=f_n, predicted=(f_lc, a_lc)
    )
    assert png.stat().st_size > 20_000
