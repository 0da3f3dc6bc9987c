"""The wing_damage experiment over the real graph: the health node's live records in the bag, and
`bin/flaair health` rerunning the same core on that bag, agree; the damage is reported once.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run, run_offline


@pytest.mark.graph  # ROS 2 processes exchanging data in real time: run after the others
@pytest.mark.timeout(400)
def test_wing_damage_experiment_live_health_equals_the_rerun(tmp_path: Path) -> None:
    from flaair_tools import bagio

    bag = tmp_path / "wing_damage"
    result = run([FLAAIR, "experiment", "wing_damage", "--out", str(bag)], isolated_env(), 300)
    assert result.returncode == 0, result.stderr[-3000:]
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
