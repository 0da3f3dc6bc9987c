"""Collision detection during self-excited (dSA) flapping, where no drive frequency is fixed.

The pure cores in lockstep, as the composed loop runs them: plant -> front end -> loop
supervisor (dSA) -> plant, the collision monitor on the front end's output with its default
settings (per-wingbeat decision) on stroke-locked windows. An obstacle is put in the stroke's
way once the wing flaps by itself, then taken away.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_control.core import loop_state, monitor
from flaair_control.core import supervisor as sv
from flaair_control.dsa_io import supervisor_params_from_config
from flaair_control.monitor_io import collision_monitor_params_from_config
from flaair_model.config import node_parameters
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_sensors.core import frontend
from flaair_sensors.frontend_io import frontend_params_from_config
from flaair_sim.core import plant

FS = 20000.0
OBSTACLE_S = (1.6, 2.1)
LIMIT_DEG = 15.0  # the free self-excited stroke reaches 20.6 deg


def closed_loop(duration_s: float, respond: bool = False):
    """(sample time, stroke truth deg, monitor verdicts, the monitor's input blocks) of the dSA loop
    with the obstacle window; respond: the monitor's events go to the supervisor (as the controller
    node passes them on), and the fourth item also holds the (sample index, amplitude scale) of
    every drive block.
    """
    model = load_model()
    hit = with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    values = dict(node_parameters("flaair.yaml", "dsa_controller_node"))
    loop = supervisor_params_from_config(values, model)
    fe_params = frontend_params_from_config(node_parameters("flaair.yaml", "frontend_node"), FS)
    mon_params = replace(collision_monitor_params_from_config(), window_source="stroke")
    ctrl, plant_state, fe_state = (
        sv.initial_state(loop),
        plant.initial_state(plant.PlantStepParams(model, FS)),
        frontend.initial_state(fe_params),
    )
    mon = monitor.initial_state(mon_params)
    ctrl, out = sv.step(ctrl, loop_state.Tick(0.0, 1, 1, 1), loop)
    ctrl, out = sv.step(ctrl, loop_state.Tick(10.0, 1, 1, 1), loop)
    queue, strokes, verdicts, wing_blocks, scales = list(out.blocks), [], [], [], []
    while queue and len(strokes) * loop.block_size < duration_s * FS:
        block = queue.pop(0)
        t = block.first_sample_index / FS
        m = hit if OBSTACLE_S[0] <= t < OBSTACLE_S[1] else model
        plant_state, sim = plant.step(
            plant_state, plant.PlantInputs(block.drive_v), plant.PlantStepParams(m, FS)
        )
        fe_state, est = frontend.step(
            fe_state, frontend.FrontendInputs(sim.stroke_sensor_v, sim.pitch_sensor_v), fe_params
        )
        strokes.append(np.degrees(sim.stroke_rad))
        wing_blocks.append(
            monitor.WingBlock(
                block.first_sample_index,
                np.where(est.stroke_valid, est.stroke_rad, np.nan),
                np.where(est.pitch_valid, est.pitch_rad, np.nan),
            )
        )
        mon, result = monitor.step(mon, wing_blocks[-1], mon_params)
        verdicts += result.verdicts
        for v in result.verdicts if respond else ():
            if v.event is not None:
                ctrl, out = sv.step(
                    ctrl,
                    loop_state.Collision(
                        10.0, v.event == monitor.ONSET, v.wingbeat_index, v.spectrum_rmse_deg
                    ),
                    loop,
                )
                queue += out.blocks
        scales.append((block.first_sample_index, ctrl.amplitude_scale))
        ctrl, out = sv.step(
            ctrl,
            loop_state.WingBlock(
                10.0,
                block.first_sample_index,
                FS,
                np.degrees(est.stroke_velocity_rad_s),
                np.degrees(est.stroke_rad),
                est.stroke_valid,
                1,
            ),
            loop,
        )
        queue += out.blocks
    stroke = np.concatenate(strokes)
    return (
        np.arange(stroke.size) / FS,
        stroke,
        verdicts,
        (wing_blocks, mon_params, np.array(scales)),
    )


@pytest.fixture(scope="module")
def run():
    return closed_loop(2.6)


def test_the_default_decision_is_the_per_wingbeat_one():
    assert collision_monitor_params_from_config().decision == "distortion"


@pytest.mark.slow  # simulates self-excited flapping until a collision
def test_collision_is_detected_within_two_wingbeats_while_flapping_by_itself(run):
    t, stroke, verdicts, _ = run
    free = (t > 1.3) & (t < OBSTACLE_S[0])
    assert 19.0 < np.ptp(stroke[free]) / 2 < 22.0  # self-excited, 20.6 deg
    first_strike_s = t[(t >= OBSTACLE_S[0]) & (stroke >= LIMIT_DEG - 0.01)][0]
    # During the K_r ramp (0.5-1.0 s) the stroke turns from the 90 Hz sine into the 144 Hz
    # self-excited one by design, and the per-wingbeat monitor reports that change as distortion:
    # judged here from the settled self-excited flapping on.
    settled = [v for v in verdicts if v.end_index / FS > 1.0]
    assert settled[0].colliding is False
    onsets = [v for v in settled if v.event == monitor.ONSET]
    clearances = [v for v in settled if v.event == monitor.CLEARANCE]
    assert onsets, "no onset while the wing struck the obstacle"
    onset = onsets[0]
    period_s = 1.0 / 144.0
    latency_wingbeats = (onset.end_index / FS - first_strike_s) / period_s
    assert 0.0 < latency_wingbeats <= 2.0, latency_wingbeats
    assert onset.end_index / FS >= OBSTACLE_S[0], "false alarm before the obstacle"
    assert (
        clearances and OBSTACLE_S[1] < clearances[-1].end_index / FS < OBSTACLE_S[1] + 10 * period_s
    )
    # while flapping freely the windows follow the emergent frequency, not a drive's
    free_verdicts = [v for v in verdicts if 1.3 < v.end_index / FS < OBSTACLE_S[0]]
    assert free_verdicts and all(
        math.isclose(v.frequency_hz, 144.1, rel_tol=0.02) for v in free_verdicts
    )


def test_the_monitor_decides_the_same_on_joined_blocks(run):
    """Composed beside the loop, the monitor gets each run of contiguous blocks that queued up
    while it was busy as one block (flaair_common.intra.join_contiguous): same verdicts.
    """
    from flaair_common.intra import join_contiguous

    _, _, verdicts, (blocks, params, _) = run
    as_fields = [
        {
            "first_sample_index": b.first_sample_index,
            "stroke_rad": b.stroke_rad,
            "pitch_rad": b.pitch_rad,
            "sec": 0,
        }
        for b in blocks
    ]
    rng = np.random.default_rng(3)
    state, joined_verdicts, k, joins = monitor.initial_state(params), [], 0, 0
    while k < len(as_fields):
        n = int(rng.integers(1, 25))
        for fields in join_contiguous(as_fields[k : k + n]):
            joins += 1
            state, out = monitor.step(
                state,
                monitor.WingBlock(
                    fields["first_sample_index"], fields["stroke_rad"], fields["pitch_rad"]
                ),
                params,
            )
            joined_verdicts += out.verdicts
        k += n
    assert joins < len(blocks) / 5
    assert [(v.wingbeat_index, v.end_index, v.colliding, v.event) for v in joined_verdicts] == [
        (v.wingbeat_index, v.end_index, v.colliding, v.event) for v in verdicts
    ]
    assert len(verdicts) > 300


def test_join_contiguous_joins_runs_and_keeps_gaps():
    from flaair_common.intra import join_contiguous

    def block(first: int, n: int = 10) -> dict:
        return {
            "first_sample_index": first,
            "x": np.arange(first, first + n, dtype=float),
            "sec": first,
        }

    out = join_contiguous([block(0), block(10), block(20, 5), block(40), block(50)])
    assert [(b["first_sample_index"], len(b["x"]), b["sec"]) for b in out] == [
        (0, 25, 0),
        (40, 20, 40),
    ]
    np.testing.assert_array_equal(out[0]["x"], np.arange(25.0))
    assert join_contiguous([]) == []


def test_the_controller_does_not_take_the_k_r_ramp_for_a_collision_and_does_take_the_obstacle():
    """collision_response reduce_amplitude (the default), the monitor's events passed on: the
    waveform change of the K_r ramp reads as distortion (an onset), and the controller leaves
    the drive alone then (collision_ramp_guard_s); at the obstacle it halves the drive.
    """
    t, stroke, verdicts, (_, _, scales) = closed_loop(2.0, respond=True)
    ramp = [v for v in verdicts if v.event == monitor.ONSET and 0.5 <= v.end_index / FS < 1.1]
    assert ramp, "no onset during the K_r ramp: this test would not see the guard work"
    before = scales[scales[:, 0] < OBSTACLE_S[0] * FS]
    assert np.all(before[:, 1] == 1.0)
    first_strike_s = t[(t >= OBSTACLE_S[0]) & (stroke >= LIMIT_DEG - 0.01)][0]
    reduced = scales[(scales[:, 0] >= OBSTACLE_S[0] * FS) & (scales[:, 1] == 0.5)]
    # within 3 wingbeats
    assert reduced.size and (reduced[0, 0] / FS - first_strike_s) * 144.0 <= 3.0
