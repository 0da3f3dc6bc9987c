"""flaair_model.settings: the typed accessors tools use for sections not their own."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from flaair_model import settings
from flaair_model.config import ConfigError, config_dir


def test_each_accessor_reads_its_section_with_types() -> None:
    document = yaml.safe_load((config_dir() / "flaair.yaml").read_text())
    shared = document["/**"]["ros__parameters"]
    assert settings.stream() == settings.StreamSettings(
        float(shared["sample_rate_hz"]), shared["block_size"], float(shared["drive_limit_v"])
    )
    live = document["live"]["ros__parameters"]
    assert settings.live().dds_batch_blocks == live["dds_batch_blocks"]
    assert isinstance(settings.live().first_packet_timeout_s, float)
    assert (
        settings.bridge().lead_samples == document["bridge_node"]["ros__parameters"]["lead_samples"]
    )
    # from /** under its own section
    assert settings.controller().block_size == shared["block_size"]
    # the analysis' rules, as the tables': a list read as a tuple of floats
    rules = document["discrepancy"]["ros__parameters"]
    found = settings.discrepancy()
    assert found.band_edges_hz == tuple(float(v) for v in rules["band_edges_hz"])
    assert found.identify is rules["identify"]
    # the judging rules: one section, the same values for runs and tables
    judging = document["judging"]["ros__parameters"]
    assert found.rules == settings.tables().rules == settings.judging()
    assert found.rules.min_z == judging["min_z"]
    assert found.rules.min_heldout_drop == judging["min_heldout_drop"]
    assert "min_z" not in rules and "min_z" not in document["tables"]["ros__parameters"]


@pytest.mark.parametrize(
    "value, message",
    [
        (40.0, "discrepancy.band_edges_hz: must be a list of numbers, got 40.0"),
        ([0.0, "forty"], "discrepancy.band_edges_hz: must be float, got 'forty'"),
    ],
)
def test_a_list_setting_that_is_not_a_list_of_numbers_is_named(
    tmp_path: Path, monkeypatch, value, message
) -> None:
    shutil.copytree(config_dir(), tmp_path / "config")
    path = tmp_path / "config" / "flaair.yaml"
    document = yaml.safe_load(path.read_text())
    document["discrepancy"]["ros__parameters"]["band_edges_hz"] = value
    path.write_text(yaml.safe_dump(document))
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(tmp_path / "config"))
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        settings.discrepancy()


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d["live"]["ros__parameters"].pop("dds_batch_blocks"),
            "live.dds_batch_blocks: missing",
        ),
        (
            lambda d: d["live"]["ros__parameters"].update(dds_batch_blocks="20"),
            "live.dds_batch_blocks: must be int, got '20'",
        ),
        (
            lambda d: d["bridge_node"]["ros__parameters"].update(lead_samples=True),
            "bridge_node.lead_samples: must be int",
        ),
        (
            lambda d: d["live"]["ros__parameters"].update(first_packet_timeout_s=None),
            "first_packet_timeout_s: must be float",
        ),
    ],
)
def test_a_missing_or_mistyped_key_is_named(tmp_path: Path, monkeypatch, edit, message) -> None:
    shutil.copytree(config_dir(), tmp_path / "config")
    path = tmp_path / "config" / "flaair.yaml"
    document = yaml.safe_load(path.read_text())
    edit(document)
    path.write_text(yaml.safe_dump(document))
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(tmp_path / "config"))
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")) as error:
        settings.live()
        settings.bridge()
    assert str(path) in str(error.value)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: s.pop("kr_target"), "dsa_controller_node.kr_target: missing"),
        (
            lambda s: s.update(kr_target="fast"),
            "dsa_controller_node.kr_target: must be float, got 'fast'",
        ),
        (
            lambda s: s.update(collision_response="panic"),
            "collision_response: 'panic' is not one of",
        ),
    ],
)
def test_a_node_section_is_checked_against_the_node_schema(
    tmp_path: Path, monkeypatch, edit, message
) -> None:
    from flaair_control.dsa_io import DSA_CONTROLLER_PARAMS, dsa_controller_values
    from flaair_model.schema import ParameterError

    assert (
        dsa_controller_values()["kr_target"]
        == settings.node_section(DSA_CONTROLLER_PARAMS, "dsa_controller_node")["kr_target"]
    )
    shutil.copytree(config_dir(), tmp_path / "config")
    path = tmp_path / "config" / "flaair.yaml"
    document = yaml.safe_load(path.read_text())
    edit(document["dsa_controller_node"]["ros__parameters"])
    path.write_text(yaml.safe_dump(document))
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(tmp_path / "config"))
    with pytest.raises(ParameterError, match=message):
        dsa_controller_values()


def test_a_value_outside_its_range_is_refused_with_the_range(tmp_path: Path, monkeypatch) -> None:
    from flaair_control.monitor_io import COLLISION_MONITOR_PARAMS, collision_monitor_values
    from flaair_model.schema import ParameterError

    spec = next(s for s in COLLISION_MONITOR_PARAMS if s.type is float and s.max_value is not None)
    shutil.copytree(config_dir(), tmp_path / "config")
    path = tmp_path / "config" / "flaair.yaml"
    document = yaml.safe_load(path.read_text())
    document["collision_monitor_node"]["ros__parameters"][spec.name] = spec.max_value * 2 + 1
    path.write_text(yaml.safe_dump(document))
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(tmp_path / "config"))
    with pytest.raises(ParameterError, match=f"collision_monitor_node.{spec.name}: .* is outside"):
        collision_monitor_values()
