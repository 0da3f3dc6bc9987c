"""Replay a recorded bag through the live nodes' pure cores, offline.

The collision monitor node and the dSA controller node are thin shells over
`flaair_control.core.monitor` and `flaair_control.core.supervisor`; fed the recorded
blocks in the order the nodes saw them (in lockstep: drive block k, then wing-state block
k), decoded and mapped to the cores' inputs exactly as the nodes do it (`cdr.decode`, the
`dsa_io` adapters), the cores give back what the live nodes published: collision
statuses and events, drive blocks and controller states. `analyze` uses it to show what
the monitor decided; the tests use it to prove the live and offline paths identical.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from flaair_common import cdr, topics
from flaair_control.core import loop_state, monitor
from flaair_control.core import supervisor as sv
from flaair_control.dsa_io import (
    dsa_controller_values,
    supervisor_params_from_config,
    supervisor_wing_input,
)
from flaair_control.monitor_io import (
    collision_monitor_params_from_config,
    monitor_drive_input,
    monitor_wing_input,
)
from flaair_model.model import Model
from flaair_tools import bagio

LAYOUTS = {topics.DRIVE: cdr.DRIVE_COMMAND_BLOCK, topics.WING_STATE: cdr.WING_STATE_BLOCK}


def _blocks_in_loop_order(
    bag: Path, wanted: tuple[str, ...]
) -> Iterator[tuple[str, dict[str, Any]]]:
    """(topic, message fields) of the block topics, decoded as the nodes decode them, ordered by
    sample index; at one index drive first.
    """
    rank = {topics.DRIVE: 0, topics.WING_STATE: 1}
    messages = []
    for n, (topic, _, _, data) in enumerate(bagio.iter_raw(bag, list(wanted))):
        fields = cdr.decode(LAYOUTS[topic], data)
        messages.append((int(fields["first_sample_index"]), rank[topic], n, topic, fields))
    messages.sort(key=lambda item: item[:3])
    seen: set[tuple[str, int]] = set()
    for index, _, _, topic, fields in messages:
        if (topic, index) in seen:  # a retransmitted block: the node ignored it as stale
            continue
        seen.add((topic, index))
        yield topic, fields


def replay_monitor(bag: Path, values: dict[str, Any] | None = None) -> list[monitor.Verdict]:
    """The collision monitor's verdicts on a bag (``values``: collision_monitor_node parameters)."""
    params = collision_monitor_params_from_config(values)
    state = monitor.initial_state(params)
    wanted = (
        (topics.DRIVE, topics.WING_STATE) if params.estimates_frequency else (topics.WING_STATE,)
    )
    verdicts: list[monitor.Verdict] = []
    for topic, fields in _blocks_in_loop_order(bag, wanted):
        inputs = (
            monitor_drive_input(fields) if topic == topics.DRIVE else monitor_wing_input(fields)
        )
        state, out = monitor.step(state, inputs, params)
        verdicts.extend(out.verdicts)
    return verdicts


def replay_controller(
    bag: Path, model: Model, values: dict[str, Any] | None = None
) -> list[loop_state.DriveOut]:
    """The dSA controller's drive blocks on a bag of a closed loop it ran (lockstep plant).

    The start (peers seen, start delay passed) is replayed as two ticks; then every recorded
    wing-state block in order. Wall-clock watchdogs do not trip offline.
    """
    values = dict(dsa_controller_values() if values is None else values)
    params = replace(
        supervisor_params_from_config(values, model), run_time_s=0.0, watchdog_timeout_s=1e9
    )
    state = sv.initial_state(params)
    out: list[loop_state.DriveOut] = []
    for t_wall in (0.0, params.start_delay_s + 1.0):
        state, result = sv.step(state, loop_state.Tick(t_wall, 99, 1, 1), params)
        out.extend(result.blocks)
    for _, fields in _blocks_in_loop_order(bag, (topics.WING_STATE,)):
        state, result = sv.step(
            state, supervisor_wing_input(fields, params.start_delay_s + 1.0, 1), params
        )
        out.extend(result.blocks)
    return out
