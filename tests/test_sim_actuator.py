"""The plant's actuator driver core (flaair_sim.core.actuator), lockstep drive watchdog: exact, on a
fake wall clock. Over DDS, the same ring-down after a kill -9 of the controller is test_faults'.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from flaair_sim.core import actuator, scene

FS_HZ, BLOCK = 20000.0, 10
PARAMS = actuator.ActuatorParams(
    sample_rate_hz=FS_HZ,
    block_size=BLOCK,
    mode="lockstep",
    command_timeout_s=0.3,
    ring_down_s=0.1,
    arm_s=0.01,
)


def _command(t_wall: float, index: int, volts: float) -> actuator.Command:
    return actuator.Command(t_wall, index, FS_HZ, np.full(BLOCK, volts))


def _drive(state: actuator.ActuatorState, t_wall: float, n_blocks: int, volts: float = 50.0):
    for _ in range(n_blocks):
        state, out = actuator.step(state, _command(t_wall, state.next_index, volts), PARAMS)
        assert len(out.drive_blocks) == 1
    return state


def test_a_silent_driving_source_is_zeroed_and_the_wing_rings_down_for_ring_down_s() -> None:
    # 50 ms of commands: armed
    state = _drive(actuator.initial_state(PARAMS, t_wall=0.0), 0.0, 100)
    # not yet silent for > 0.3 s
    assert actuator.step(state, actuator.Tick(0.3), PARAMS)[1] == actuator.Outputs()
    # silent 310 ms: trip, ring-down starts
    state, out = actuator.step(state, actuator.Tick(0.31), PARAMS)
    assert out.drive_blocks == () and [n.level for n in out.notes] == ["error"]
    assert (
        "DRIVE WATCHDOG: no command block for 310.0 ms (> command_timeout_s 0.3 s) after block "
        "990" in out.notes[0].text
    )
    steps = []
    # a 10 ms timer, on the wall clock
    for t in np.arange(0.32, 0.45, 0.01):
        state, out = actuator.step(state, actuator.Tick(float(t)), PARAMS)
        steps.append((len(out.drive_blocks), [n.text for n in out.notes]))
    blocks_per_tick = [n for n, _ in steps]
    # 0.1 s of zero drive = 200 blocks at the real-time rate (20 per 10 ms), then nothing
    assert (
        sum(blocks_per_tick) == 200
        and blocks_per_tick[:10] == [20] * 10
        and set(blocks_per_tick[10:]) == {0}
    )
    assert steps[9][1] == [
        "ring-down done at sample 3000: zero drive held until a command block comes"
    ]
    assert all(notes == [] for _, notes in steps[:9] + steps[10:])
    assert state.next_index == 1000 + 2000
    # a command for the next block is in order again, and re-arms the watchdog
    state, out = actuator.step(state, _command(0.5, 3000, 10.0), PARAMS)
    assert (
        len(out.drive_blocks) == 1 and "drive commands resumed at block 3000" in out.notes[0].text
    )


def test_a_zero_driving_source_that_falls_silent_is_left_alone() -> None:
    """A source whose last block was zero drive (a controller's goodbye) leaves nothing to zero."""
    state = _drive(actuator.initial_state(PARAMS, t_wall=0.0), 0.0, 100)
    state = _drive(state, 0.0, 1, volts=0.0)
    assert actuator.step(state, actuator.Tick(5.0), PARAMS)[1] == actuator.Outputs()


def test_the_watchdog_waits_until_commands_have_flowed_for_arm_s() -> None:
    """A controller's start-up (its first blocks unanswered until a retry) is not a dead source."""
    # 5 ms of commands < arm_s 10 ms
    state = _drive(actuator.initial_state(PARAMS, t_wall=0.0), 0.0, 10)
    assert actuator.step(state, actuator.Tick(5.0), PARAMS)[1] == actuator.Outputs()


def test_the_drive_clamp_and_the_tick_rules_live_in_the_core() -> None:
    drive = np.array([-300.0, -12.5, 0.0, 99.0, 101.0, np.inf])
    np.testing.assert_array_equal(
        actuator.clamp_drive(drive, 100.0), [-100.0, -12.5, 0.0, 99.0, 100.0, 100.0]
    )
    base = actuator.ActuatorParams(20000.0, 10, "lockstep", 0.0, 0.1, 0.05)
    assert actuator.tick_period_s(base) is None
    assert actuator.tick_period_s(dataclasses.replace(base, command_timeout_s=0.02)) == 0.005
    assert actuator.tick_period_s(dataclasses.replace(base, command_timeout_s=1.0)) == 0.01
    assert actuator.tick_period_s(dataclasses.replace(base, mode="realtime")) == 0.005
    assert actuator.blocks_per_tick(base) == 40


def test_the_camera_sees_one_frame_in_n_with_tracking_noise_split_independent() -> None:
    stroke, pitch = np.radians(np.arange(12.0)), np.radians(-np.arange(12.0))
    camera = scene.CameraParams(frame_every=4, tracking_noise_deg_rms=0.5)
    whole = scene.tracked_angles(0, stroke, pitch, camera, scene.tracking_generator(True, 7, 4))
    rng = scene.tracking_generator(True, 7, 4)
    parts = [
        scene.tracked_angles(i, stroke[i : i + 6], pitch[i : i + 6], camera, rng) for i in (0, 6)
    ]
    for k in range(3):
        np.testing.assert_array_equal(whole[k], np.concatenate([p[k] for p in parts]))
    assert whole[2].tolist() == [i % 4 == 0 for i in range(12)]
    assert 0.0 < np.std(whole[0] - np.arange(12.0)) < 2.0
    assert scene.tracking_generator(True, 7, 1) is None
    assert scene.tracking_generator(False, 7, 4) is None
    clean = scene.tracked_angles(3, stroke, pitch, scene.CameraParams(1, 0.5), None)
    np.testing.assert_allclose(clean[0], np.arange(12.0))
    assert clean[2] is None
