"""ControllerState thinning (state_every_blocks): `flaair live` sends one ControllerState per
DDS batch; the drive itself must not change, and no clamp may go unreported.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from flaair_control.core import loop_state
from flaair_control.core import supervisor as sv
from flaair_control.dsa_io import supervisor_params_from_config
from flaair_model.config import node_parameters
from flaair_model.model_io import load_model

FS = 20000.0


def drive_blocks(every: int, drive_limit_v: float | None = None) -> list[loop_state.DriveOut]:
    """40 blocks of the controller answering a 140 Hz, 20 deg stroke (fixed wing-state input)."""
    params = supervisor_params_from_config(
        dict(node_parameters("flaair.yaml", "dsa_controller_node")), load_model()
    )
    params = replace(params, state_every_blocks=every, min_drive_subscribers=1)
    if drive_limit_v is not None:
        params = replace(params, drive_limit_v=drive_limit_v)
    state = sv.initial_state(params)
    state, out = sv.step(state, loop_state.Tick(0.0, 1, 1, 1), params)
    state, out = sv.step(state, loop_state.Tick(10.0, 1, 1, 1), params)
    blocks, queue = [], list(out.blocks)
    n = params.block_size
    while queue and len(blocks) < 40:
        b = queue.pop(0)
        blocks.append(b)
        t = (b.first_sample_index + np.arange(n)) / FS
        stroke_deg = 20.0 * np.sin(2 * np.pi * 140.0 * t)
        velocity_deg_s = 20.0 * 2 * np.pi * 140.0 * np.cos(2 * np.pi * 140.0 * t)
        state, out = sv.step(
            state,
            loop_state.WingBlock(
                10.0, b.first_sample_index, FS, velocity_deg_s, stroke_deg, np.ones(n, bool), 1
            ),
            params,
        )
        queue += out.blocks
    return blocks


def test_every_nth_block_carries_the_state_and_the_drive_is_unchanged() -> None:
    every_block, thinned = drive_blocks(1), drive_blocks(5)
    assert all(b.with_state for b in every_block)
    with_state = [k for k, b in enumerate(thinned) if b.with_state]
    assert with_state == list(range(4, 40, 5))
    for a, b in zip(every_block, thinned, strict=True):
        np.testing.assert_array_equal(a.drive_v, b.drive_v)
        assert (a.k_r, a.first_sample_index) == (b.k_r, b.first_sample_index)


def test_a_clamp_in_a_block_without_state_is_reported_by_the_next_state() -> None:
    # a limit the sync sine (20 V) crosses in some blocks, not in others
    clamped = [b.drive_clamped for b in drive_blocks(1, drive_limit_v=19.0)]
    assert any(clamped) and not all(clamped)
    thinned = drive_blocks(5, drive_limit_v=19.0)
    for k in range(4, 40, 5):
        assert thinned[k].drive_clamped == any(clamped[k - 4 : k + 1])
