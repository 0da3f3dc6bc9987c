"""What /diagnostics says, decided by pure functions of a node's state (exact levels and texts)."""

from __future__ import annotations

from flaair_common.diagnostics import ERROR, OK, WARN, health, loss_percent


def test_the_worst_problem_sets_the_level_and_every_problem_is_named() -> None:
    found = health("x", [(OK, ""), (WARN, "a"), (ERROR, "b")], "fine", {"f": 0.123456, "n": 3})
    assert (found.level, found.message, found.values) == (
        ERROR,
        "a; b",
        (("f", "0.1235"), ("n", "3")),
    )
    assert health("x", [], "fine", {}).message == "fine" and loss_percent(0, 0) == 0.0


def test_bridge_health_speaks_of_the_last_period_and_of_both_watchdogs() -> None:
    from flaair_bridge.bridge_io import bridge_health
    from flaair_bridge.core import bridge_state

    def state(silent: bool = False, **counts: int) -> bridge_state.BridgeState:
        return bridge_state.BridgeState(silent=silent, counters=bridge_state.Counters(**counts))

    waiting = bridge_health(state(), None)
    assert (waiting.level, waiting.message) == (OK, "waiting for the target's first packet")
    before = state(sensor_packets=1000, lost_packets=5)
    lossy = bridge_health(state(sensor_packets=2990, lost_packets=15, drive_late_blocks=2), before)
    assert (lossy.level, lossy.message) == (
        WARN,
        "10 sensor packet(s) lost (0.50 % of the period); 2 drive block(s) late for the "
        "target: dropped",
    )
    assert dict(lossy.values)["loss_percent"] == f"{100 * 15 / 3005:.4g}"
    quiet = bridge_health(
        state(sensor_packets=2990, lost_packets=15), state(sensor_packets=2990, lost_packets=15)
    )
    assert (quiet.level, quiet.message) == (OK, "streaming")
    tripped = bridge_health(
        state(True, sensor_packets=3000, target_watchdog_packets=1, watchdog_stops=1),
        state(sensor_packets=3000),
    )
    assert (tripped.level, tripped.message) == (
        ERROR,
        "target silent: no sensor packet; the target's watchdog is tripped; the drive "
        "stream fell silent: stop packet sent",
    )


def test_monitor_health_warns_while_colliding() -> None:
    from flaair_control.core import monitor
    from flaair_control.monitor_io import (
        collision_monitor_params_from_config,
        collision_monitor_values,
        monitor_health,
    )

    state = monitor.initial_state(collision_monitor_params_from_config(collision_monitor_values()))
    assert monitor_health((state, 0, 0), None).message == "waiting for the first wingbeat"
    colliding = state._replace(colliding=True, wingbeats=40)
    found = monitor_health((colliding, 3, 1), (state, 1, 0))
    assert (found.level, found.message) == (
        WARN,
        "COLLISION: the pitch spectrum left the free-flapping one; 3 wing-state block(s) dropped",
    )
    assert dict(found.values)["colliding"] == "True"
    assert monitor_health((state._replace(wingbeats=40), 3, 1), (colliding, 3, 1)).level == OK
