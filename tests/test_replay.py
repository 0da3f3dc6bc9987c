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
