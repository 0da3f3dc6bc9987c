"""Stroke experiments: lockstep loop of the cores -> rosbag2 MCAP bag -> analysis from the bag."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from flaair_analysis import wingbeat
from flaair_model.config import config_dir, load_yaml, node_parameters
from flaair_model.model_io import load_model
from flaair_tools.sweeps import stroke_experiments as se

TOPICS = {
    "/flaair/drive",
    "/flaair/sensor_v",
    "/flaair/wing_state",
    "/flaair/wing_state/truth",
    "/flaair/controller/state",
    "/flaair/run_marker",
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    section = load_yaml(config_dir() / "sweeps.yaml")["stroke_experiments"]
    values = node_parameters("flaair.yaml", "stroke_controller_node")
    frontend = node_parameters("flaair.yaml", "frontend_node")
    model = load_model()
    beats = wingbeat.WingbeatParams(
        20000.0,
        values["crossing_hysteresis_deg"],
        values["min_wingbeat_hz"],
        values["max_wingbeat_hz"],
    )
    out = {}
    for exp in se.experiments_from_config(section):
        if exp.name not in ("setpoint_step_dsa", "wing_damage_sync", "obstacle_dsa"):
            continue
        bag = tmp_path_factory.mktemp("bags") / exp.name
        run = se.run_closed_loop(exp, model, values, frontend)
        se.write_bag(bag, exp, run)
        out[exp.name] = (
            exp,
            run,
            bag,
            se.analyse_bag(bag, section["settle_band_deg"], section["steady_wingbeats"], beats),
        )
    return out


@pytest.mark.slow  # simulates and records the stroke experiments' bags
def test_bags_hold_the_recorder_topics_and_the_run_as_an_independent_reader_sees_it(runs) -> None:
    _exp, run, bag, _ = runs["setpoint_step_dsa"]
    with open(next(Path(bag).glob("*.mcap")), "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert {c.topic for c in summary.channels.values()} == TOPICS
    blocks = run["drive_v"].size // 10
    counts = {
        summary.channels[k].topic: v for k, v in summary.statistics.channel_message_counts.items()
    }
    assert counts["/flaair/wing_state"] == counts["/flaair/drive"] == blocks
    with AnyReader([Path(bag)]) as reader:
        conns = [c for c in reader.connections if c.topic == "/flaair/wing_state"]
        stroke = np.concatenate(
            [reader.deserialize(raw, c.msgtype).stroke_deg for c, _, raw in reader.messages(conns)]
        )
    assert np.array_equal(stroke, run["stroke_deg"])
    metadata = yaml.safe_load((Path(bag) / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"
    ]
    assert json.loads(metadata["custom_data"][se.CUSTOM_KEY])["setpoint_after_deg"] == 20.0


def test_each_experiment_settles_within_20_wingbeats_to_half_a_degree(runs) -> None:
    for name, (*_, result) in runs.items():
        for key in ("estimate", "truth"):
            assert (
                result[key]["settling_wingbeats"] is not None
                and result[key]["settling_wingbeats"] <= 20
            ), (name, key)
            assert abs(result[key]["steady_error_deg"]) <= 0.5, (name, key)
        assert result["max_abs_drive_v"] <= 150.0


def test_the_dsa_frequency_follows_the_damage_and_the_obstacle_while_sync_stays(runs) -> None:
    sync = runs["wing_damage_sync"][3]["estimate"]["steady_frequency_hz"]
    assert sync == pytest.approx(140.0, rel=1e-3)
    obstacle = runs["obstacle_dsa"][3]
    t = np.array(obstacle["estimate"]["wingbeat_time_s"])
    a = np.array(obstacle["estimate"]["wingbeat_amplitude_deg"])
    # the obstacle first clips the stroke (amplitude drops), then the controller restores it
    first_after = a[np.argmax(t > obstacle["event_s"]) + 1]
    assert first_after < 14.0 and abs(obstacle["estimate"]["steady_error_deg"]) <= 0.5
    true_stroke = runs["obstacle_dsa"][1]["true_stroke_deg"]
    # the wing now lives against the 13 deg stop (a stiff spring: a little penetration) and
    # makes up the amplitude on the other side
    assert 13.0 < true_stroke[-4000:].max() < 14.5 and true_stroke[-4000:].min() < -15.5
