"""A recorded live run replays through the pure cores to exactly what the live nodes published."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run

# slow: records a live run over real DDS, then replays it
pytestmark = [pytest.mark.graph, pytest.mark.slow]


def _experiment(tmp_path_factory, name: str) -> Path:
    bag = tmp_path_factory.mktemp(name) / "bag"
    result = run([FLAAIR, "experiment", name, "--nominal", "--out", str(bag)], isolated_env(), 600)
    assert result.returncode == 0, result.stderr[-3000:]
    return bag


@pytest.fixture(scope="module")
def collision_bag(tmp_path_factory) -> Path:
    return _experiment(tmp_path_factory, "collision")


@pytest.fixture(scope="module")
def transition_bag(tmp_path_factory) -> Path:
    return _experiment(tmp_path_factory, "transition")


def test_collision_monitor_replays_to_the_live_statuses_and_events(collision_bag: Path) -> None:
    from flaair_tools import bagio
    from flaair_tools.analysis.replay import replay_monitor

    live = [m for _, _, m in bagio.iter_messages(collision_bag, ["/flaair/collision/status"])]
    events = [m for _, _, m in bagio.iter_messages(collision_bag, ["/flaair/collision/events"])]
    verdicts = replay_monitor(collision_bag)
    assert len(live) > 200 and len(verdicts) == len(live)
    assert [v.wingbeat_index for v in verdicts] == [m.wingbeat_index for m in live]
    assert [v.colliding for v in verdicts] == [m.colliding for m in live]
    assert np.array_equal(
        [v.frequency_hz for v in verdicts], [m.wingbeat_frequency_hz for m in live]
    )
    assert np.array_equal(
        [v.spectrum_rmse_deg for v in verdicts], [m.spectrum_rmse_deg for m in live], equal_nan=True
    )
    replayed = [(v.event, v.wingbeat_index) for v in verdicts if v.event is not None]
    assert replayed == [("onset" if e.kind == 1 else "clearance", e.wingbeat_index) for e in events]
    # the obstacle was seen and cleared
    assert [kind for kind, _ in replayed][:2] == ["onset", "clearance"]


def test_controller_replays_to_the_live_drive_and_states(transition_bag: Path) -> None:
    from flaair_model.model_io import load_model
    from flaair_tools import bagio
    from flaair_tools.analysis.replay import replay_controller

    states = [m for _, _, m in bagio.iter_messages(transition_bag, ["/flaair/controller/state"])]
    drive = bagio.read_blocks(transition_bag, "/flaair/drive")
    replayed = replay_controller(transition_bag, load_model())
    with_state = [b for b in replayed if b.with_state]
    fs = drive.sample_rate_hz
    # every state from the first block on is in the bag (the controller
    # waits for the recorder's state subscription); the replay adds
    # only the closing zero blocks the recorder did not wait for
    recorded_indices = [
        round((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9) * fs) for m in states
    ]
    assert len(states) > 5000 and recorded_indices == [
        b.first_sample_index for b in with_state[: len(states)]
    ]
    assert len(with_state) - len(states) <= 3
    by_index = {b.first_sample_index: b for b in with_state}
    for message in states:
        index = round((message.header.stamp.sec + message.header.stamp.nanosec * 1e-9) * fs)
        b = by_index[index]
        assert (
            b.k_r,
            b.async_drive_v,
            b.sync_drive_v,
            float(b.drive_v[-1]),
            b.stroke_frequency_hz,
            b.amplitude_scale,
        ) == (
            message.k_r,
            message.async_drive_v,
            message.sync_drive_v,
            message.drive_v,
            message.stroke_frequency_hz,
            message.amplitude_scale,
        ), index
    # the recorded drive ends on the controller's zero blocks (run complete, shutdown)
    n = int(np.flatnonzero(drive["drive_v"])[-1]) + 1
    assert drive.n_samples - n in (10, 20)
    offline = np.concatenate([b.drive_v for b in replayed])[:n]
    assert np.array_equal(offline, drive["drive_v"][:n])
