"""The wing_damage experiment over the real graph (dSA flapping, K_r ramped 1 -> 0, the wing
damaged mid-run), recorded once for two checks of what the live nodes published against the same
pure cores offline: the health node's records against `bin/flaair health` rerun on the bag (the
damage reported once), and the dSA controller's drive and states against its replay.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run, run_offline

# ROS 2 processes exchanging data in real time: run after the others
pytestmark = pytest.mark.graph


@pytest.fixture(scope="module")
def wing_damage_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("wing_damage") / "bag"
    result = run([FLAAIR, "experiment", "wing_damage", "--out", str(bag)], isolated_env(), 300)
    assert result.returncode == 0, result.stderr[-3000:]
    return bag


@pytest.mark.timeout(400)  # the first to use it records the experiment
def test_wing_damage_experiment_live_health_equals_the_rerun(
    wing_damage_bag: Path, tmp_path: Path
) -> None:
    from flaair_tools import bagio

    bag = wing_damage_bag
    contents = bagio.read_bag(bag, ["/flaair/health", "/flaair/health/events"])
    live = contents.messages("/flaair/health")
    events = contents.messages("/flaair/health/events")
    assert [e.parameter for e in events] == ["wing_inertia"]
    assert events[0].ratio == pytest.approx(0.8, abs=0.04)
    assert 2.5 < events[0].time_s < 2.5 + 20 / 160.0  # damage at 2.5 s (experiments.yaml)
    out = tmp_path / "health"
    rerun = run_offline([FLAAIR, "health", str(bag), "--out", str(out)], isolated_env())
    assert rerun.returncode == 0, rerun.stderr
    doc = json.loads((out / "health.json").read_text())
    series = doc["bags"][0]["wingbeats"]
    assert [int(m.sample_index) for m in live] == series["sample_index"]
    offline = np.array([np.nan if v is None else v for v in series["wing_inertia"]])
    np.testing.assert_array_equal([m.wing_inertia_ratio for m in live], offline)
    assert [(e["parameter"], e["sample_index"]) for e in doc["events"]] == [
        (events[0].parameter, int(events[0].sample_index))
    ]


@pytest.mark.timeout(400)  # the first to use it records the experiment
def test_controller_replays_to_the_live_drive_and_states(wing_damage_bag: Path) -> None:
    from flaair_model.model_io import load_model
    from flaair_tools import bagio
    from flaair_tools.analysis.replay import replay_controller

    states = [m for _, _, m in bagio.iter_messages(wing_damage_bag, ["/flaair/controller/state"])]
    drive = bagio.read_blocks(wing_damage_bag, "/flaair/drive")
    replayed = replay_controller(wing_damage_bag, load_model())
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
