"""flaair_sim.core.drive_pacing: the drive node's decisions, event by event, without ROS."""

from __future__ import annotations

import numpy as np
import pytest

from flaair_model.schema import ParameterError
from flaair_sim.core import drive_pacing as pacing
from flaair_sim.core.drive import DriveError, DriveParams, drive_record
from flaair_sim.drive_io import DRIVE_NODE_PARAMS, pacing_params_from_config

FS_HZ, BLOCK = 20_000.0, 10
SINE = DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=140.0)


def params(**changes) -> pacing.PacingParams:
    values = dict(
        sample_rate_hz=FS_HZ,
        block_size=BLOCK,
        pacing="lockstep",
        lockstep_window_blocks=4,
        min_subscribers=1,
        first_sample_index=0,
        run_time_s=0.0,
        ack_retry_s=0.5,
        drive=SINE,
    )
    values.update(changes)
    return pacing.PacingParams(**values)


def run(p: pacing.PacingParams, events, t0: float = 0.0):
    state = pacing.initial_state(p, t_wall=t0)
    blocks, logs = [], []
    for event in events:
        state, out = pacing.step(state, event, p)
        blocks += out.blocks
        logs += [(note.level, note.text) for note in out.notes]
    return state, blocks, logs


def test_lockstep_waits_for_both_ends_then_keeps_the_window_ahead_of_the_acknowledgements():
    p = params()
    state, blocks, _ = run(p, [pacing.Tick(0.001, 0, 1, 150.0), pacing.Tick(0.002, 1, 0, 150.0)])
    # no subscriber, then no acknowledging publisher
    assert blocks == []
    state, out = pacing.step(state, pacing.Tick(0.003, 1, 1, 150.0), p)
    assert [b.first_sample_index for b in out.blocks] == [0, 10, 20, 30]  # 4 blocks = the window
    state, out = pacing.step(state, pacing.Ack(0.004, 10, 1, 1, 150.0), p)
    assert [b.first_sample_index for b in out.blocks] == [40]  # one answered: one more
    state, out = pacing.step(state, pacing.Ack(0.005, 30, 1, 1, 150.0), p)
    assert [b.first_sample_index for b in out.blocks] == [50, 60]
    assert state.next_index == 70 and state.acknowledged_index == 30


def test_blocks_are_the_whole_record_split_and_clamped_to_the_live_limit():
    p = params(lockstep_window_blocks=1000)
    _, blocks, _ = run(p, [pacing.Tick(0.0, 1, 1, 60.0)])
    whole = drive_record(SINE, FS_HZ, 1000 * BLOCK)
    assert np.array_equal(np.concatenate([b.drive_v for b in blocks]), np.clip(whole, -60.0, 60.0))
    assert np.max(np.abs(blocks[3].drive_v)) == 60.0


def test_lockstep_sends_one_more_block_when_no_acknowledgement_comes():
    p = params(lockstep_window_blocks=2, ack_retry_s=0.5)
    events = [pacing.Tick(t, 1, 1, 150.0) for t in (0.1, 0.4, 0.61, 0.9, 1.2)]
    state, blocks, logs = run(p, events, t0=0.0)
    # window of 2 at 0.1 s (the acknowledgement clock
    # starts there); retry at 0.61 s, the next at 1.2 s
    assert [b.first_sample_index for b in blocks] == [0, 10, 20, 30]
    assert state.retries == 2
    assert [level for level, _ in logs] == ["warning", "warning"] and "block 20" in logs[0][1]


def test_run_time_ends_on_a_zero_block_and_close_adds_none_after_it():
    p = params(run_time_s=50 / FS_HZ, lockstep_window_blocks=100)
    _state, blocks, logs = run(
        p, [pacing.Tick(0.0, 1, 1, 150.0), pacing.Tick(0.01, 1, 1, 150.0), pacing.Close(150.0)]
    )
    assert [b.first_sample_index for b in blocks] == [0, 10, 20, 30, 40, 50]
    assert not np.any(blocks[-1].drive_v) and np.any(blocks[-2].drive_v)
    assert logs == [("info", "run complete at sample 50; zero drive sent")]


def test_close_zeroes_a_running_drive_but_not_an_idle_one():
    p = params()
    _, blocks, _ = run(p, [pacing.Close(150.0)])
    assert blocks == []  # nothing sent: nothing to zero
    _, blocks, _ = run(p, [pacing.Tick(0.0, 1, 1, 150.0), pacing.Close(150.0)])
    assert (
        len(blocks) == 5 and blocks[-1].first_sample_index == 40 and not np.any(blocks[-1].drive_v)
    )
    quiet = params(
        drive=DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=140.0, lead_in_s=1.0)
    )
    _, blocks, _ = run(quiet, [pacing.Tick(0.0, 1, 1, 150.0), pacing.Close(150.0)])
    # the lead-in's zeros already leave it at zero
    assert len(blocks) == 4


def test_realtime_sends_what_the_wall_clock_has_made_due():
    p = params(pacing="realtime", min_subscribers=2)
    state, blocks, _ = run(p, [pacing.Tick(5.0, 1, 0, 150.0)])
    assert blocks == [] and state.wall_start is None  # too few subscribers: not started
    state, blocks, _ = run(
        p,
        [
            pacing.Tick(5.0, 2, 0, 150.0),
            pacing.Tick(5.0 + 0.00249, 2, 0, 150.0),
            pacing.Tick(5.0 + 0.0100001, 2, 0, 150.0),
        ],
    )
    # 0.00249 s = 49 samples due: 4 whole blocks; 0.01 s = 200 samples: 20 blocks in all
    assert [b.first_sample_index for b in blocks] == list(range(0, 200, 10))


def test_acknowledgements_do_not_pace_realtime():
    p = params(pacing="realtime")
    state, blocks, _ = run(p, [pacing.Ack(1.0, 1000, 1, 1, 150.0)])
    assert blocks == [] and state.acknowledged_index == 1000


def test_params_from_config_match_the_node_declaration_and_name_bad_values():
    config = pacing_params_from_config()
    assert config.pacing in pacing.PACINGS and config.ack_retry_s > 0
    values = {spec.name: getattr(config, spec.name, None) for spec in DRIVE_NODE_PARAMS}
    values.update(
        waveform="chirp",
        amplitude_v=10.0,
        bias_v=0.0,
        frequency_hz=0.0,
        start_hz=20.0,
        stop_hz=200.0,
        duration_s=0.0,
        step_hz=1.0,
        dwell_s=0.1,
        lead_in_s=0.0,
        drive_limit_v=150.0,
        pace_on_wing_state=False,
        multisine_lines=[1.0],
        multisine_phases_rad=[0.0],
    )
    with pytest.raises(ParameterError, match="duration_s"):
        pacing_params_from_config(values)
    with pytest.raises(ParameterError, match=r"missing parameter.*ack_retry_s"):
        pacing_params_from_config({k: v for k, v in values.items() if k != "ack_retry_s"})
    with pytest.raises(DriveError, match="pacing"):
        params(pacing="fast")
