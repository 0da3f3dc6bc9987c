"""The supervisor's drive block (one compiled call) against the two public cores it composes:
`dsa.step`, the amplitude scale, `safety.step`. The drive, the filter and guard states and the
reported K_r, sync, async and clamp must be those of the cores, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_control.core import dsa, safety
from flaair_control.core import supervisor as sv
from flaair_control.dsa_io import supervisor_params_from_config
from flaair_model.config import node_parameters
from flaair_model.model_io import load_model

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def params():
    values = dict(node_parameters("flaair.yaml", "dsa_controller_node"))
    return supervisor_params_from_config(values, load_model())


def _cores(ctrl, guard, velocity, t_start, scale, p):
    """The reference: the two cores' public steps, as the supervisor composed them before."""
    ctrl, out = dsa.step(ctrl, dsa.DsaInputs(velocity, t_start), p.dsa)
    guard, guarded = safety.step(guard, safety.SafetyInputs(out.drive_v * scale, t_start), p.safety)
    unclipped = out.signals.drive_unclipped_v
    clamped = not np.isnan(unclipped).any() and np.abs(unclipped).max() * scale > p.drive_limit_v
    sig = out.signals
    return ctrl, guard, guarded.drive_v, (sig.kr[-1], sig.async_v[-1], sig.sync_v[-1], clamped)


@pytest.mark.parametrize(
    "scale, slew_v_per_s, trip_at_block, nan_every",
    [
        (1.0, math.inf, None, 0),  # the healthy loop
        (0.4, math.inf, None, 0),  # a collision's reduced amplitude
        (1.0, 2e4, None, 3),  # slew-limited, NaN velocities in every third block
        (1.0, math.inf, 20, 0),  # tripped mid-run: the ramp down
    ],
)
def test_the_drive_block_is_the_cores_composed(
    params, scale, slew_v_per_s, trip_at_block, nan_every
) -> None:
    # a gain that drives the blend past the limit in some blocks, so the clamp is exercised
    p = replace(
        params,
        drive_limit_v=15.0,
        safety=replace(params.safety, slew_limit_v_per_s=slew_v_per_s, drive_limit_v=15.0),
        dsa=replace(params.dsa, kr_schedule=dsa.KrSchedule(1.0, 0.0, 0.002, 0.004)),
    )
    n, fs = p.block_size, p.sample_rate_hz
    rng = np.random.default_rng(7)
    ctrl_a = ctrl_b = dsa.initial_state(p.dsa)
    guard_a = guard_b = safety.initial_state(p.safety)
    clamps = 0
    for k in range(60):
        t_start = k * n / fs
        velocity = rng.normal(0.0, 3e3, n)
        if nan_every and k % nan_every == 0:
            velocity[rng.integers(0, n)] = math.nan
        valid = k != trip_at_block  # the sensor block that trips the watchdog
        guard_a = safety.note_sensor_block(guard_a, t_start, valid, p.safety)
        guard_b = safety.note_sensor_block(guard_b, t_start, valid, p.safety)
        ctrl_a, guard_a, drive_a, reported_a = _cores(ctrl_a, guard_a, velocity, t_start, scale, p)
        guard_b, guard_args = safety.guard_arguments(guard_b, t_start, n, p.safety)
        drive_b, z, *reported_b = sv.drive_block(
            velocity, t_start, ctrl_b.zi_advanced, ctrl_b.zi_raw, *p.dsa.kernel_args,
            scale, p.drive_limit_v, guard_args,
        )  # fmt: skip
        ctrl_b = dsa.DsaState(z[0], z[1])
        guard_b = guard_b._replace(last_drive_v=float(drive_b[-1]))
        np.testing.assert_array_equal(drive_b, drive_a)
        np.testing.assert_array_equal(ctrl_b.zi_advanced, ctrl_a.zi_advanced)
        np.testing.assert_array_equal(ctrl_b.zi_raw, ctrl_a.zi_raw)
        np.testing.assert_equal(tuple(guard_b), tuple(guard_a))  # NaN trip time while ok
        assert tuple(reported_b) == tuple(reported_a)
        clamps += bool(reported_a[3])
    assert 0 < clamps < 60  # some blocks clamped, some not
    tripped = guard_a.status == safety.TRIPPED
    assert tripped == (trip_at_block is not None)
